"""The measurements of ``bench_throughput.py``: the serial loop its child interpreter runs,
the parallel runner it times, and the figures it derives (machine, rates, projection).

A helper module of that script (``python benchmarks/bench_throughput.py``), not a script.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

FULL_RUN_EPISODES = 50


# ------------------------------------------------------------------------------------
# serial reference loop (runs in a child interpreter)
# ------------------------------------------------------------------------------------


def serial_child(spec: dict[str, Any]) -> dict[str, Any]:
    """The reference runner's loop: one env per task, episodes in order, in this process."""
    t_start = time.perf_counter()
    import logging

    import mikasa_envs  # noqa: F401  (torch, ManiSkill, the envs: as the workers at start)

    logging.getLogger("mani_skill ").setLevel(logging.ERROR)  # ManiSkill's logger name
    from mikasa_bench.media.render import check_render_device
    from mikasa_bench.policies import ZeroPolicy
    from mikasa_bench.protocol import BenchmarkConfig, starts_scene
    from mikasa_bench.runners.episode import make_benchmark_env, run_episode

    import_s = time.perf_counter() - t_start
    config = BenchmarkConfig(
        n_episodes=spec["episodes"],
        obs_mode=spec["obs_mode"],
        sim_backend="cpu",
        render_device=spec["render_device"],
    )
    policy = ZeroPolicy()
    episodes, make_s, render = [], 0.0, None
    t0 = time.perf_counter()
    for env_id in spec["tasks"]:
        tm = time.perf_counter()
        env = make_benchmark_env(env_id, config)
        make_s += time.perf_counter() - tm
        render = render or check_render_device(env, spec["render_device"])
        try:
            for i, seed in enumerate(config.episode_seeds()):
                te, ce = time.perf_counter(), time.process_time()
                r, _ = run_episode(env, policy, seed, fresh_scene=starts_scene(i))
                wall, cpu = time.perf_counter() - te, time.process_time() - ce
                episodes.append(_episode_record(env_id, i, r, wall, cpu_s=cpu))
        finally:
            env.close()
    loop_s = time.perf_counter() - t0
    return {
        "import_s": import_s,
        "loop_s": loop_s,
        "env_build_s": make_s,
        "render": render,
        "lp_num_threads": os.environ.get("LP_NUM_THREADS", "default (all cores)"),
        "episodes": episodes,
    }


def _episode_record(env_id: str, i: int, r: Any, wall_s: float, **extra: Any) -> dict[str, Any]:
    return {
        "env_id": env_id,
        "episode": i,
        "seed": r.seed,
        "success_once": r.success_once,
        "episode_return": r.episode_return,
        "n_steps": r.n_steps,
        "wall_s": wall_s,
        **extra,
    }


def _cpu_s(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


# ------------------------------------------------------------------------------------
# parallel runner
# ------------------------------------------------------------------------------------


def run_parallel(spec: dict[str, Any], args: argparse.Namespace) -> dict[str, Any]:
    """`execute_runs` on a fresh run directory with the chosen executor; every outcome is
    recorded on the way through."""
    from mikasa_bench.policies import resolve_policy
    from mikasa_bench.protocol import BenchmarkConfig
    from mikasa_bench.protocol.tasks import resolve_tasks
    from mikasa_bench.results.store import RunStore
    from mikasa_bench.runners.executor import make_executor
    from mikasa_bench.runners.jobs import EpisodeOutcome, Executor
    from mikasa_bench.runners.runner import execute_runs

    class Recording(Executor):
        """Passes jobs through and keeps each outcome with its arrival time."""

        def __init__(self, inner: Executor) -> None:
            self.inner = inner
            self.name = inner.name
            self.outcomes: list[tuple[float, EpisodeOutcome]] = []

        def describe(self) -> dict[str, Any]:
            return self.inner.describe()

        def run(self, jobs: Sequence[Any]) -> Iterator[EpisodeOutcome]:
            for outcome in self.inner.run(jobs):
                self.outcomes.append((time.perf_counter(), outcome))
                yield outcome

    config = BenchmarkConfig(
        n_episodes=spec["episodes"],
        obs_mode=spec["obs_mode"],
        sim_backend="cpu",
        render_device=args.render_device,
        gpu_render_workers=args.gpu_render_workers,
    )
    selection = resolve_tasks(env_ids=list(spec["tasks"]))
    tmp = Path(tempfile.mkdtemp(prefix="bench_throughput_"))
    try:
        store = RunStore.create(
            tmp / "run",
            tasks=selection.tasks,
            policy=resolve_policy("zero"),
            config=config,
            selection=selection.to_dict(),
            commit=None,
        )
        executor = Recording(
            make_executor(args.executor, args.workers, address=args.address, envs_per_worker=args.envs_per_worker)
        )
        cpu0 = _cpu_s(resource.RUSAGE_SELF) + _cpu_s(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        execute_runs([store], executor, progress=False)
        wall_s = time.perf_counter() - t0
        # Local workers are joined when the run ends, so their CPU time is counted here;
        # Ray actors are not our children (None).
        cpu_s = _cpu_s(resource.RUSAGE_SELF) + _cpu_s(resource.RUSAGE_CHILDREN) - cpu0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    episodes = [
        _episode_record(
            o.job.task.env_id,
            o.job.episode,
            o.result,
            o.wall_s,
            worker=o.worker,
            setup_s=o.setup_s,
            cpu_s=o.cpu_s,
            render=o.render,
            done_at_s=t - t0,
        )
        for t, o in executor.outcomes
    ]
    episodes.sort(key=lambda e: (spec["tasks"].index(e["env_id"]), e["episode"]))
    return {
        "wall_s": wall_s,
        "startup_s": getattr(executor.inner, "startup_s", None),
        "envs_per_process": getattr(executor.inner, "envs", None),
        "executor": executor.describe(),
        "render": sorted({e["render"] for e in episodes if e["render"]}),
        "cpu_s": cpu_s if args.executor == "local" else None,
        "episodes": episodes,
    }


# ------------------------------------------------------------------------------------
# figures
# ------------------------------------------------------------------------------------


def machine_info() -> dict[str, Any]:
    """Cores, CPU model, GPUs and package versions: what the numbers depend on."""
    from mikasa_bench.protocol import package_versions
    from mikasa_bench.runners.worker import available_cores

    cpu = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    gpus: list[str] = []
    if shutil.which("nvidia-smi"):
        try:
            out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20)
            gpus = [x for x in out.stdout.splitlines() if x.strip()]
        except (OSError, subprocess.SubprocessError):
            pass
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    versions = package_versions()
    return {
        "host": platform.node(),
        "cores_available": available_cores(),
        "cpu_count": os.cpu_count(),
        "cpu_model": cpu,
        "gpus": gpus,
        "load_average_at_start": load,
        "versions": {k: versions.get(k) for k in ("python", "mani-skill", "sapien", "torch")},
    }


def rates(episodes: list[dict[str, Any]], wall_s: float, setup_s: float) -> dict[str, Any]:
    """End-to-end and steady-state steps/s.

    Steady state: per worker, its steps over the time its episodes took without env
    builds; summed over workers (they run concurrently). For the serial loop this is its
    steps over the wall time minus ``setup_s`` (imports and env builds).
    """
    steps = sum(e["n_steps"] for e in episodes)
    by_worker: dict[Any, list[dict[str, Any]]] = {}
    for e in episodes:
        by_worker.setdefault(e.get("worker", 0), []).append(e)
    out: dict[str, Any] = {"steps": steps, "end_to_end_steps_per_s": steps / wall_s}
    # CPU seconds per step inside episodes (process time, all threads): the cost of a step
    # independent of how much of a shared machine the run got.
    out["cpu_ms_per_step"] = 1000 * sum(e.get("cpu_s", 0.0) for e in episodes) / max(1, steps)
    if len(by_worker) == 1 and "worker" not in episodes[0]:
        out["steady_steps_per_s"] = steps / max(1e-9, wall_s - setup_s)
        return out
    # Per render device kind ("gpu"/"cpu"): how a mixed pool's two halves perform.
    kinds: dict[str, list[float]] = {}
    for eps in by_worker.values():
        busy = sum(e["wall_s"] - e.get("setup_s", 0.0) for e in eps)
        rate = sum(e["n_steps"] for e in eps) / max(1e-9, busy)
        kind = str(eps[0].get("render") or "?").split(":")[0]
        kinds.setdefault(kind, []).append(rate)
    out["steady_steps_per_s"] = sum(sum(v) for v in kinds.values())
    # Cross-check from completion times alone: steps of the episodes that finished while
    # the middle 80 % of episodes finished, over that time (no per-worker bookkeeping).
    done = sorted((e["done_at_s"], e["n_steps"]) for e in episodes if "done_at_s" in e)
    if len(done) >= 10:
        lo, hi = len(done) // 10, len(done) - len(done) // 10 - 1
        span = done[hi][0] - done[lo][0]
        if span > 0:
            out["window_steps_per_s"] = sum(n for _, n in done[lo + 1 : hi + 1]) / span
    out["per_render_kind"] = {
        k: {"workers": len(v), "steady_steps_per_s": sum(v), "per_worker": sum(v) / len(v)}
        for k, v in sorted(kinds.items())
    }
    return out


def full_run_steps() -> tuple[int, int]:
    """(tasks, env steps) of the full canonical run: every manifest task, 50 episodes, at
    the manifest's full horizons (episodes of a failing policy run to the horizon)."""
    from mikasa_bench.protocol.tasks import select_benchmark_tasks

    tasks = select_benchmark_tasks(split="all")
    return len(tasks), FULL_RUN_EPISODES * sum(t.max_episode_steps for t in tasks)


def _cpu_line(mode: dict[str, Any]) -> str:
    """CPU use of a mode (start-up included): on a shared machine wall-clock rates depend
    on what others run, and the average number of busy cores shows how much of the
    machine the mode actually got."""
    cpu = mode.get("cpu_s")
    if cpu is None:
        return "CPU time n/a"
    wall = mode["wall_s"]
    return f"CPU {cpu:.0f} s in all, {cpu / wall:.2f} cores busy on average"


def _load() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def _hms(seconds: float) -> str:
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m{s:02d}s"
