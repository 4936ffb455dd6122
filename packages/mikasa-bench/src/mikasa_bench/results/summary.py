"""The result files' contents: the per-task result (benchmark.md §7.1) and the summary
(§7.2), built from episode results; `write_benchmark_results` writes both."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mikasa_bench.protocol import NUM_ENVS, BenchmarkConfig, protocol_settings
from mikasa_bench.protocol.tasks import BenchmarkTask
from mikasa_bench.results.files import SUMMARY_FILENAME, atomic_write_json
from mikasa_bench.results.metrics import aggregate_by, summarize_task_results, wilson_interval
from mikasa_bench.runners.episode import EpisodeResult

__all__ = ["build_task_result", "build_summary", "write_benchmark_results"]


def build_task_result(
    task: BenchmarkTask,
    config: BenchmarkConfig,
    episodes: Sequence[EpisodeResult],
    *,
    action_chunk_size: int = 1,
    model: Mapping[str, Any] | None = None,
    commit: str | None = None,
    wall_time_s: float | None = None,
    videos: Sequence[str | None] | None = None,
    restarts: Sequence[int] | None = None,
) -> dict[str, Any]:
    """The per-task result dict: the keys of benchmark.md §7.1 in order, then extensions
    (``sr_ci95``, ``mean_episode_length``, the remaining protocol settings, wall time,
    ``action_chunk_size_varied`` (whether the policy's chunks had more than one length K;
    ``action_chunk_size`` is the largest), ``episode_restarts`` (how often each episode was
    played again from its reset after its policy lost it, e.g. a dropped server
    connection) and, with videos, each episode's video path relative to the run
    directory)."""
    if len(episodes) != config.n_episodes:
        raise ValueError(f"{task.env_id}: {len(episodes)} episodes, expected {config.n_episodes}")
    successes = [bool(e.success_once) for e in episodes]
    returns = [float(e.episode_return) for e in episodes]
    lengths = [int(e.n_steps) for e in episodes]
    n = len(successes)
    chunk_sizes = {k for e in episodes for k in e.chunk_sizes}
    lo, hi = wilson_interval(sum(successes), n)
    settings = protocol_settings(config)
    out = {
        "env_id": task.env_id,
        "split": task.split.title(),
        "memory_type": task.memory_type,
        "start_seed": config.start_seed,
        "n_episodes": config.n_episodes,
        "successes": successes,
        "returns": returns,
        "sr": sum(successes) / n,
        "mean_return": sum(returns) / n,
        "benchmark_commit": commit,
        "control_mode": config.control_mode,
        "obs_mode": config.obs_mode,
        "wrapper_chain": config.wrapper_chain,
        "action_chunk_size": max(chunk_sizes | {int(action_chunk_size)}),
        "model": dict(model or {}),
        "episode_lengths": lengths,
        "episode_seeds": [int(e.seed) for e in episodes],
        # --- extensions (extra keys only, see benchmark.md §10) ---
        "sr_ci95": [lo, hi],
        "mean_episode_length": sum(lengths) / n,
        "reward_mode": config.reward_mode,
        "sim_backend": config.sim_backend,
        "include_overlays": config.include_overlays,
        "num_envs": NUM_ENVS,
        "render_device": settings["render_device"],
        "policy_batch": config.policy_batch,
        "canonical": settings["canonical"],
        "wall_time_s": wall_time_s,
        "action_chunk_size_varied": len(chunk_sizes) > 1,
        "episode_restarts": [int(r) for r in restarts] if restarts is not None else [0] * n,
    }
    if videos is not None:
        out["videos"] = list(videos)
    return out


def build_summary(results: Sequence[Mapping[str, Any]], **extensions: Any) -> dict[str, Any]:
    """`summarize_task_results` plus per-task CIs, per-split and per-split-per-memory-type
    success rates, then ``extensions`` (protocol, versions, wall time, ...) in order."""
    summary = summarize_task_results(results)
    per_task = {r["env_id"]: r for r in results}
    summary["per_task_sr_ci95"] = {
        k: list(wilson_interval(sum(bool(s) for s in r["successes"]), len(r["successes"])))
        for k, r in per_task.items()
    }
    uniq = list(per_task.values())
    summary["sr_per_split"] = aggregate_by(uniq, "split")
    summary["sr_per_split_memory_type"] = {
        s: dict(sorted(d.items())) for s, d in aggregate_by(uniq, "split", "memory_type").items()
    }
    summary["n_tasks"] = len(uniq)
    summary["n_episodes_total"] = sum(len(r["successes"]) for r in uniq)
    summary.update(extensions)
    return summary


def write_benchmark_results(
    output_dir: str | Path,
    task_results: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
) -> None:
    """Write every ``<env_id>.json`` and ``summary.json`` into ``output_dir``."""
    out = Path(output_dir)
    for r in task_results:
        atomic_write_json(out / f"{r['env_id']}.json", r)
    atomic_write_json(out / SUMMARY_FILENAME, summary)
