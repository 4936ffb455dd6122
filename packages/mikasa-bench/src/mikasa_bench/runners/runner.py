"""Running evaluations: the parallel, resumable runner and the in-process reference API.

`execute_runs` drives one or more runs (run directory + policy + tasks) through an
`Executor`: it turns every missing episode into a job, records outcomes as they arrive
(journal, then per-task file + summary when a task completes) and shows progress with an
ETA. Several runs can share one pool, and runs that evaluate the same task share that
task's env in each worker (the quickstart's oracle and zero policies do).

`evaluate_task` / `evaluate_benchmark` are the sequential library API of the spec
(benchmark.md §6.3, §7.3) for callers that already hold a policy object.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

from mikasa_bench.errors import EpisodeFailedError
from mikasa_bench.media.video import EpisodeVideo
from mikasa_bench.policies.base import policy_chunk_size
from mikasa_bench.protocol import BenchmarkConfig, package_versions, protocol_settings, starts_scene
from mikasa_bench.protocol.tasks import BenchmarkTask, benchmark_commit
from mikasa_bench.results.files import atomic_write_bytes
from mikasa_bench.results.store import RunStore
from mikasa_bench.results.summary import (
    build_summary,
    build_task_result,
    write_benchmark_results,
)
from mikasa_bench.runners.episode import EpisodeResult, make_benchmark_env, run_episode
from mikasa_bench.runners.jobs import EpisodeJob, Executor

__all__ = ["execute_runs", "evaluate_task", "evaluate_benchmark"]


def _jobs_for(stores: Sequence[RunStore]) -> list[EpisodeJob]:
    # Task-major across runs: every worker finishes a task (for all runs) before the
    # next, so per-task files appear early and an env is built once per task and worker.
    order: dict[str, int] = {}
    for store in stores:
        for task in store.tasks:
            order.setdefault(task.env_id, len(order))
    jobs = [
        EpisodeJob(ri, task, i, store.config.start_seed + i, store.config, store.policy)
        for ri, store in enumerate(stores)
        for task, i in store.pending()
    ]
    jobs.sort(key=lambda j: (order[j.task.env_id], j.run_index, j.episode))
    return jobs


def _progress_bar(total: int, initial: int, enabled: bool, stream: TextIO) -> Any:
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        initial=initial,
        unit="ep",
        desc="episodes",
        disable=not enabled,
        file=stream,
        dynamic_ncols=True,
        smoothing=0.1,
    )


def execute_runs(
    stores: Sequence[RunStore],
    executor: Executor,
    *,
    progress: bool = True,
    stream: TextIO | None = None,
) -> list[dict[str, Any] | None]:
    """Run every missing episode of ``stores`` on ``executor``; return their summaries.

    An episode that raises stops the whole evaluation with `EpisodeFailedError` (naming
    task, episode, seed and policy); everything recorded before stays on disk and
    ``--resume`` continues from there. Ctrl-C behaves the same way.
    """
    stream = stream or sys.stderr
    jobs = _jobs_for(stores)
    total = sum(s.config.n_episodes * len(s.tasks) for s in stores)
    done = sum(s.n_done_episodes for s in stores)
    execution = executor.describe()
    for store in stores:
        store.begin_session(execution)
    multi = len(stores) > 1
    bar = _progress_bar(total, done, progress, stream)
    try:
        outcomes = executor.run(jobs)
        try:
            for outcome in outcomes:
                if outcome.error is not None:
                    msg = outcome.describe_failure()
                    if not outcome.user_error and outcome.traceback:
                        msg += "\n\nworker traceback:\n" + outcome.traceback.rstrip()
                    raise EpisodeFailedError(msg)
                job = outcome.job
                store = stores[job.run_index]
                assert outcome.result is not None
                video = None
                if outcome.video is not None:
                    # Before the journal line: a recorded episode always has its video.
                    video = store.save_video(job.task.env_id, job.episode, outcome.video)
                finished = store.record_episode(
                    job.task.env_id,
                    job.episode,
                    outcome.result,
                    action_chunk_size=outcome.action_chunk_size,
                    wall_s=outcome.wall_s,
                    video=video,
                    render=outcome.render,
                    restarts=outcome.restarts,
                )
                bar.update(1)
                if finished is not None:
                    prefix = f"[{store.policy.label}] " if multi else ""
                    n_ok = sum(finished["successes"])
                    bar.write(
                        f"{prefix}{job.task.env_id}: SR {finished['sr']:.0%} "
                        f"({n_ok}/{finished['n_episodes']}), mean return "
                        f"{finished['mean_return']:.2f}",
                        file=stream,
                    )
        finally:
            # Stops the workers at once on an error or Ctrl-C.
            outcomes.close()
    finally:
        bar.close()
        for store in stores:
            # Also on failure: records this session's wall time; the summary keeps
            # covering exactly the finished tasks.
            store.write_summary()
    return [store.summary() for store in stores]


# ------------------------------------------------------------------------------------
# sequential reference API (benchmark.md §6.3, §7.3)
# ------------------------------------------------------------------------------------


def evaluate_task(
    task: BenchmarkTask,
    policy: Any,
    config: BenchmarkConfig,
    *,
    model: Mapping[str, Any] | None = None,
    commit: str | None = None,
    video_dir: str | Path | None = None,
    episode_callback: Callable[[int, EpisodeResult], None] | None = None,
    env_factory: Callable[[str, BenchmarkConfig], Any] | None = None,
) -> dict[str, Any]:
    """Evaluate ``policy`` (an object, in this process) on one task; returns the task
    result dict. ``env_factory`` replaces `make_benchmark_env` (tests, custom envs).

    ``video_dir``: write ``episode_<i:04d>.mp4`` per episode there (benchmark.md §8); the
    env should be made with ``save_videos=True`` (scene view with overlays)."""
    chunk = policy_chunk_size(policy)
    env = (env_factory or make_benchmark_env)(task.env_id, config)
    try:
        episodes = []
        for i, seed in enumerate(config.episode_seeds()):
            if video_dir is not None:
                with EpisodeVideo() as recorder:
                    result, _ = run_episode(
                        env, policy, seed, frame_sink=recorder.add, fresh_scene=starts_scene(i)
                    )
                    data = recorder.finish()
                atomic_write_bytes(Path(video_dir) / f"episode_{i:04d}.mp4", data)
            else:
                result, _ = run_episode(env, policy, seed, fresh_scene=starts_scene(i))
            episodes.append(result)
            if episode_callback is not None:
                episode_callback(i, result)
    finally:
        env.close()
    return build_task_result(
        task, config, episodes, action_chunk_size=chunk, model=model, commit=commit
    )


def evaluate_benchmark(
    tasks: Sequence[BenchmarkTask],
    policy: Any,
    config: BenchmarkConfig | None = None,
    *,
    output_dir: str | Path | None = None,
    model: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
    task_start_callback: Callable[[int, BenchmarkTask], None] | None = None,
    episode_callback: Callable[[int, EpisodeResult], None] | None = None,
    task_done_callback: Callable[[int, dict[str, Any]], None] | None = None,
    initial_results: Sequence[Mapping[str, Any]] | None = None,
    env_factory: Callable[[str, BenchmarkConfig], Any] | None = None,
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Evaluate ``policy`` on ``tasks`` one after another in this process.

    Mirrors the upstream library: ``initial_results`` (resume) are merged into every
    summary; with ``output_dir`` each finished task's file and the summary of all results
    so far are written at once. Returns ``(results, summary)``.
    """
    if not tasks:
        raise ValueError("no tasks to evaluate")
    config = config or BenchmarkConfig()
    commit = benchmark_commit()
    results: list[dict[str, Any]] = [dict(r) for r in initial_results or ()]
    extensions = {
        "protocol": protocol_settings(config),
        "versions": package_versions(),
        "benchmark_commit": commit,
        "model": dict(model or {}),
    }
    summary: dict[str, Any] | None = None
    n = len(tasks)
    for idx, task in enumerate(tasks, start=1):
        if progress is not None:
            progress(f"[{idx}/{n}] {task.env_id}  ({config.n_episodes} episodes)")
        if task_start_callback is not None:
            task_start_callback(idx - 1, task)
        video_dir = (
            Path(output_dir) / "videos" / task.env_id
            if config.save_videos and output_dir is not None
            else None
        )
        result = evaluate_task(
            task,
            policy,
            config,
            model=model,
            commit=commit,
            video_dir=video_dir,
            episode_callback=episode_callback,
            env_factory=env_factory,
        )
        results.append(result)
        if task_done_callback is not None:
            task_done_callback(idx - 1, result)
        if output_dir is not None:
            summary = build_summary(results, **extensions)
            write_benchmark_results(output_dir, [result], summary)
    if summary is None:
        summary = build_summary(results, **extensions)
    return results, summary
