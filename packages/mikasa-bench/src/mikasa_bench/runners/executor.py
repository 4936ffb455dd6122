"""Executors: where episodes run (the job and executor types: `mikasa_bench.runners.jobs`).

* `LocalExecutor` (default): a pool of spawn-started worker processes (SAPIEN is not
  fork-safe once imported). Each worker owns at most one CPU-simulated env; it builds the
  env for a task once and reuses it for every episode (and policy) of that task it gets.
  Jobs are handed out one at a time, preferring the task the worker already has an env
  for, so each worker moves through the task list in order (`Scheduler`).
* `InlineExecutor`: the same worker logic (`EpisodeWorker`) in the calling process
  (``--workers 0``; debugging, tests with fake envs).
* `mikasa_bench.runners.ray_executor.RayExecutor` (``--executor ray``): Ray actors running
  the same worker logic, spread over a cluster.

With ``save_videos`` a worker sends each episode's mp4 bytes back with the result: the
runner writes the file before it journals the episode, so a recorded episode always has its
video, also with Ray workers on other machines.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.media.render import apply_environment, worker_environment
from mikasa_bench.protocol import BenchmarkConfig
from mikasa_bench.runners.jobs import EpisodeJob, EpisodeOutcome, Executor, render_config
from mikasa_bench.runners.scheduler import Scheduler
from mikasa_bench.runners.worker import EpisodeWorker, available_cores, worker_env_vars

__all__ = [
    "InlineExecutor",
    "LocalExecutor",
    "EXECUTORS",
    "GPU_ENVS_PER_WORKER",
    "envs_per_process",
    "gpu_visible",
    "make_executor",
]


class InlineExecutor(Executor):
    """Runs every job in the calling process, in order."""

    name = "inline"

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Yield outcomes one by one; the env cache lives for this call."""
        if jobs:
            # Best effort: effective only if this process has not initialised Vulkan yet
            # (the render check of the first env says so if it had).
            device = render_config(jobs).render_device_for(0)
            apply_environment(worker_environment(device))
        worker = EpisodeWorker(0)
        try:
            for job in jobs:
                yield worker.run(job)
        finally:
            worker.close()


def _start_worker(process_index: int, threaded: bool, worker_id: int) -> EpisodeWorker:
    from mikasa_envs.workers import quiet_worker

    # Rendering workers keep Mesa's threads: the bench's render path was measured with them.
    quiet_worker(one_raster_thread=False)
    return EpisodeWorker(worker_id, process_index, threaded)


def _worker_main(
    process_index: int, worker_ids: list[int], inboxes: list[Any], outbox: Any, env_vars: dict[str, str]
) -> None:
    """Entry point of a `LocalExecutor` worker process (one or more workers, a thread each)."""
    # Before anything can initialise Vulkan: the render device's driver restriction.
    apply_environment(env_vars)
    # imported lazily: mikasa_envs loads ManiSkill
    from mikasa_envs.workers import serve_job_slots, use_one_gpu

    use_one_gpu(process_index)  # a CUDA context on one GPU, not on each; spreads GPU rendering
    start = partial(_start_worker, process_index, len(worker_ids) > 1)
    serve_job_slots(worker_ids, inboxes, outbox, start)


@dataclass
class _Handle:
    process: Any
    inbox: Any
    job: EpisodeJob | None = None
    last: EpisodeJob | None = None


GPU_ENVS_PER_WORKER = 4
"""Default envs per GPU-rendering worker process. Measured on an H200 (16 processes): the
GPU's graphics units are the limit, ~0.35 ms per 128x128 camera however many processes
submit; a pass of 4 scenes instead of 1 rendered ~1.5x the scenes per second."""


def gpu_visible() -> bool:
    """Whether an NVIDIA GPU is visible to this process (decides ``auto`` rendering's
    default envs per worker; the workers check where they really render)."""
    if os.environ.get("CUDA_VISIBLE_DEVICES", None) in ("", "-1"):
        return False
    return os.path.exists("/dev/nvidiactl")


def envs_per_process(config: BenchmarkConfig, process_index: int, envs_per_worker: int | None) -> int:
    """Envs (threads) of pool process ``process_index``: ``envs_per_worker`` if given, else
    `GPU_ENVS_PER_WORKER` for a process rendering on the GPU and 1 for one rendering on the
    CPU (lavapipe gains nothing from sharing passes, and threads share one core)."""
    if envs_per_worker is not None:
        return envs_per_worker
    device = config.render_device_for(process_index)
    on_gpu = device == "gpu" or (device == "auto" and gpu_visible())
    return GPU_ENVS_PER_WORKER if on_gpu else 1


class LocalExecutor(Executor):
    """A pool of ``workers`` spawn-started processes on this machine, each running one or
    more envs (`envs_per_process`: one thread each; on a GPU their cameras render in shared
    passes, `mikasa_envs.render_batcher`)."""

    name = "local"

    def __init__(self, workers: int | None = None, envs_per_worker: int | None = None) -> None:
        n = workers if workers is not None else available_cores()
        if n < 1:
            raise BenchError(f"--workers must be >= 1 for the local executor, got {n}")
        if envs_per_worker is not None and envs_per_worker < 1:
            raise BenchError(f"--envs-per-worker must be >= 1, got {envs_per_worker}")
        self.workers = int(n)
        self.envs_per_worker = envs_per_worker
        """Envs per process as asked (None: `envs_per_process` decides per process)."""
        self.envs: list[int] = []
        """Envs of each process of the last `run`."""
        self.startup_s: float | None = None
        """Seconds until every worker had imported the simulator (set by `run`)."""

    def describe(self) -> dict[str, Any]:
        """Name, process count and envs per process (``"auto"``: by render device)."""
        return {
            "name": self.name,
            "workers": self.workers,
            "envs_per_worker": self.envs_per_worker or "auto",
        }

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Start the pool, feed it, yield outcomes; always stops the workers."""
        jobs = list(jobs)
        if not jobs:
            return
        ctx = mp.get_context("spawn")
        outbox = ctx.Queue()
        handles: list[_Handle] = []
        scheduler = Scheduler(jobs)
        clean = False
        config = render_config(jobs)
        n = min(self.workers, len(jobs))
        self.envs = [envs_per_process(config, index, self.envs_per_worker) for index in range(n)]
        t_start = time.perf_counter()
        not_ready = sum(self.envs)
        try:
            for index, k in enumerate(self.envs):
                ids = list(range(len(handles), len(handles) + k))
                inboxes = [ctx.Queue() for _ in ids]
                p = ctx.Process(
                    target=_worker_main,
                    args=(index, ids, inboxes, outbox, worker_env_vars(config, index, n)),
                    daemon=True,
                    name=f"mikasa-bench-worker-{index}",
                )
                p.start()
                handles.extend(_Handle(p, inbox) for inbox in inboxes)
            for h in handles:
                self._assign(h, scheduler)
            remaining = len(jobs)
            while remaining:
                try:
                    kind, wid, payload = outbox.get(timeout=1.0)
                except queue.Empty:
                    self._check_alive(handles)
                    continue
                if kind == "fatal":
                    raise BenchError(f"worker {wid} failed to start:\n{payload}")
                if kind == "ready":
                    not_ready -= 1
                    if not not_ready:
                        self.startup_s = time.perf_counter() - t_start
                    continue
                h = handles[wid]
                h.job, h.last = None, payload.job
                remaining -= 1
                self._assign(h, scheduler)
                yield payload
            clean = True
        finally:
            self._shutdown(handles, graceful=clean)

    @staticmethod
    def _assign(h: _Handle, scheduler: Scheduler) -> None:
        job = scheduler.next_for(h.last)
        if job is not None:
            h.job = job
            h.inbox.put(job)

    @staticmethod
    def _check_alive(handles: Sequence[_Handle]) -> None:
        for wid, h in enumerate(handles):
            if h.job is not None and not h.process.is_alive():
                j = h.job
                raise BenchError(
                    f"worker {wid} died (exit code {h.process.exitcode}) while running "
                    f"{j.task.env_id} episode {j.episode} (seed {j.seed}); finished episodes "
                    f"are saved — rerun with --resume to continue"
                )

    @staticmethod
    def _shutdown(handles: Sequence[_Handle], graceful: bool) -> None:
        if graceful:
            for h in handles:
                try:
                    h.inbox.put(None)
                except Exception:
                    pass
        # Error / interrupt (or a worker that did not exit): stop now; the episodes they
        # were running are not recorded and will be rerun by --resume.
        from mikasa_envs.workers import stop_processes

        processes = list({id(h.process): h.process for h in handles}.values())
        stop_processes(processes, wait_s=30 if graceful else 0)


def _ray_executor(workers: int | None = None, address: str | None = None) -> Executor:
    # Imported on demand: the optional extra's executor (mikasa-bench[ray]); its module
    # loads mikasa_envs (ManiSkill) through mikasa_envs.ray_actors, which a local run skips.
    from mikasa_bench.runners.ray_executor import RayExecutor

    return RayExecutor(workers=workers, address=address)


EXECUTORS: dict[str, Any] = {
    "local": LocalExecutor,
    "inline": InlineExecutor,
    "ray": _ray_executor,
}
"""Executor name -> class or factory."""


def make_executor(
    name: str = "local",
    workers: int | None = None,
    *,
    address: str | None = None,
    envs_per_worker: int | None = None,
) -> Executor:
    """Build an executor by name (``workers == 0`` selects `InlineExecutor`; ``address``
    is the Ray cluster to join, default: ``RAY_ADDRESS`` or a new local instance;
    ``envs_per_worker`` is the local pool's envs per process, default by render device)."""
    if name not in EXECUTORS:
        raise BenchError(f"unknown executor {name!r}; expected one of {', '.join(EXECUTORS)}")
    if address is not None and name != "ray":
        raise BenchError("--address is only used by --executor ray")
    if envs_per_worker is not None and (name != "local" or workers == 0):
        raise BenchError("--envs-per-worker is only used by the local executor with --workers >= 1")
    if name == "ray":
        if workers == 0:
            raise BenchError("--workers 0 (run in this process) cannot be used with Ray")
        return _ray_executor(workers, address)
    if name == "inline" or workers == 0:
        return InlineExecutor()
    return LocalExecutor(workers, envs_per_worker)
