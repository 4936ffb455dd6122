"""Executors: where episodes run.

The unit of work is one episode (`EpisodeJob`). An `Executor` takes a list of jobs and
yields an `EpisodeOutcome` per job in completion order; the runner puts results back in
seed order, so the numbers never depend on the executor or the worker count.

* `LocalExecutor` (default): a pool of spawn-started worker processes (SAPIEN is not
  fork-safe once imported). Each worker owns at most one CPU-simulated env; it builds the
  env for a task once and reuses it for every episode (and policy) of that task it gets.
  Jobs are handed out one at a time, preferring the task the worker already has an env
  for, so each worker moves through the task list in order.
* `InlineExecutor`: the same worker logic in the calling process (``--workers 0``;
  debugging, tests with fake envs).

A Ray executor can be added by implementing `Executor.run` (jobs and outcomes are plain
picklable dataclasses) and registering it in `EXECUTORS`.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import queue
import signal
import time
import traceback
from abc import ABC, abstractmethod
from collections import OrderedDict, deque
from collections.abc import Hashable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from .episode import EpisodeResult, make_benchmark_env, run_episode
from .errors import BenchError
from .policies import PolicySpec, build_policy, policy_chunk_size
from .protocol import BenchmarkConfig
from .tasks import BenchmarkTask

__all__ = [
    "EpisodeJob",
    "EpisodeOutcome",
    "Executor",
    "InlineExecutor",
    "LocalExecutor",
    "EXECUTORS",
    "make_executor",
]


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to run: which run it belongs to, task, episode index and seed, protocol
    settings and the policy description."""

    run_index: int
    task: BenchmarkTask
    episode: int
    seed: int
    config: BenchmarkConfig
    policy: PolicySpec

    @property
    def env_key(self) -> Hashable:
        """Jobs with equal keys can share one env instance."""
        return (self.task.env_id, self.config)


@dataclass
class EpisodeOutcome:
    """What a worker sends back for a job: the result, or an error description."""

    job: EpisodeJob
    result: EpisodeResult | None
    action_chunk_size: int
    wall_s: float
    worker: int
    error: str | None = None
    traceback: str | None = None
    user_error: bool = False

    def describe_failure(self) -> str:
        """A message naming the task, episode, seed and policy of a failed job."""
        j = self.job
        return (
            f"policy {j.policy.label or j.policy.target!r} failed on {j.task.env_id} "
            f"episode {j.episode} (seed {j.seed}): {self.error}"
        )


class _EpisodeWorker:
    """Per-process worker state: one cached env and the policies built for it."""

    def __init__(self, worker_id: int) -> None:
        self.worker_id = worker_id
        self.env: Any = None
        self.env_key: Hashable | None = None
        self.policies: dict[str, Any] = {}

    def _env_for(self, job: EpisodeJob) -> Any:
        if self.env_key != job.env_key:
            self.close()
            self.env = make_benchmark_env(job.task.env_id, job.config)
            self.env_key = job.env_key
        return self.env

    def _policy_for(self, job: EpisodeJob, env: Any) -> Any:
        key = job.policy.key()
        if key not in self.policies:
            self.policies[key] = build_policy(job.policy, env, job.task.env_id, job.task)
        return self.policies[key]

    def run(self, job: EpisodeJob) -> EpisodeOutcome:
        """Run one job; exceptions become an outcome with ``error`` set."""
        t0 = time.perf_counter()
        try:
            env = self._env_for(job)
            policy = self._policy_for(job, env)
            chunk = policy_chunk_size(policy)
            result, _ = run_episode(env, policy, job.seed)
            return EpisodeOutcome(job, result, chunk, time.perf_counter() - t0, self.worker_id)
        except Exception as exc:
            # The env may be mid-episode: drop it so a later job starts clean.
            self.close()
            return EpisodeOutcome(
                job,
                None,
                0,
                time.perf_counter() - t0,
                self.worker_id,
                error=f"{type(exc).__name__}: {exc}",
                traceback=traceback.format_exc(),
                user_error=isinstance(exc, BenchError),
            )

    def close(self) -> None:
        """Close the cached env and forget its policies."""
        if self.env is not None:
            try:
                self.env.close()
            except Exception:
                pass
        self.env, self.env_key, self.policies = None, None, {}


class Executor(ABC):
    """Runs episode jobs and yields their outcomes in completion order.

    `run` is a generator: closing it early (the runner does so on an error or Ctrl-C)
    must stop all work promptly.
    """

    name: str = "executor"

    @abstractmethod
    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Yield one `EpisodeOutcome` per job."""

    def describe(self) -> dict[str, Any]:
        """JSON-ready description recorded with the run (never affects results)."""
        return {"name": self.name}


class InlineExecutor(Executor):
    """Runs every job in the calling process, in order."""

    name = "inline"

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Yield outcomes one by one; the env cache lives for this call."""
        worker = _EpisodeWorker(0)
        try:
            for job in jobs:
                yield worker.run(job)
        finally:
            worker.close()


def _quiet_worker() -> None:
    """Limit a worker to one thread (the pool already uses every core) and hush the
    per-process 'no CUDA render device' warning of ManiSkill."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    logging.getLogger("mani_skill").setLevel(logging.ERROR)


def _worker_main(worker_id: int, inbox: Any, outbox: Any) -> None:
    """Entry point of a `LocalExecutor` worker process."""
    # Ctrl-C reaches the whole process group: the parent handles it (it stops the pool
    # and keeps what is saved); a worker dying mid-episode would only add noise.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _quiet_worker()
    try:
        import torch

        torch.set_num_threads(1)
        import mikasa_envs  # noqa: F401  (registers the envs once per process)
    except BaseException:
        outbox.put(("fatal", worker_id, traceback.format_exc()))
        return
    worker = _EpisodeWorker(worker_id)
    parent = mp.parent_process()
    try:
        while True:
            try:
                job = inbox.get(timeout=1.0)
            except queue.Empty:
                # The parent was killed (e.g. kill -9): exit instead of idling forever.
                if parent is not None and not parent.is_alive():
                    break
                continue
            if job is None:
                break
            outbox.put(("done", worker_id, worker.run(job)))
    finally:
        worker.close()


class _Scheduler:
    """Hands out jobs task by task, preferring the env a worker already has."""

    def __init__(self, jobs: Sequence[EpisodeJob]) -> None:
        self.groups: OrderedDict[Hashable, deque[EpisodeJob]] = OrderedDict()
        for job in jobs:
            self.groups.setdefault(job.env_key, deque()).append(job)

    def next_for(self, last_key: Hashable | None) -> EpisodeJob | None:
        group = self.groups.get(last_key) if last_key is not None else None
        if not group:
            group = next((g for g in self.groups.values() if g), None)
        if not group:
            return None
        job = group.popleft()
        if not group:
            del self.groups[job.env_key]
        return job


@dataclass
class _Handle:
    process: Any
    inbox: Any
    job: EpisodeJob | None = None
    last_key: Hashable | None = None


class LocalExecutor(Executor):
    """A pool of ``workers`` spawn-started processes on this machine."""

    name = "local"

    def __init__(self, workers: int | None = None) -> None:
        n = workers if workers is not None else (os.cpu_count() or 1)
        if n < 1:
            raise BenchError(f"--workers must be >= 1 for the local executor, got {n}")
        self.workers = int(n)

    def describe(self) -> dict[str, Any]:
        """Name and worker count."""
        return {"name": self.name, "workers": self.workers}

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Start the pool, feed it, yield outcomes; always stops the workers."""
        jobs = list(jobs)
        if not jobs:
            return
        ctx = mp.get_context("spawn")
        outbox = ctx.Queue()
        handles: list[_Handle] = []
        scheduler = _Scheduler(jobs)
        clean = False
        try:
            for wid in range(min(self.workers, len(jobs))):
                inbox = ctx.Queue()
                p = ctx.Process(
                    target=_worker_main,
                    args=(wid, inbox, outbox),
                    daemon=True,
                    name=f"mikasa-bench-worker-{wid}",
                )
                p.start()
                handles.append(_Handle(p, inbox))
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
                h = handles[wid]
                h.job, h.last_key = None, payload.job.env_key
                remaining -= 1
                self._assign(h, scheduler)
                yield payload
            clean = True
        finally:
            self._shutdown(handles, graceful=clean)

    @staticmethod
    def _assign(h: _Handle, scheduler: _Scheduler) -> None:
        job = scheduler.next_for(h.last_key)
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
            deadline = time.monotonic() + 30
            for h in handles:
                h.process.join(timeout=max(0.1, deadline - time.monotonic()))
        # Error / interrupt (or a worker that did not exit): stop now; the episodes they
        # were running are not recorded and will be rerun by --resume.
        for h in handles:
            if h.process.is_alive():
                h.process.terminate()
        for h in handles:
            h.process.join(timeout=5)
            if h.process.is_alive():
                h.process.kill()
                h.process.join(timeout=5)


EXECUTORS: dict[str, type[Executor]] = {"local": LocalExecutor, "inline": InlineExecutor}
"""Executor name -> class; a ``ray`` entry is the planned extension."""


def make_executor(name: str = "local", workers: int | None = None) -> Executor:
    """Build an executor by name (``workers == 0`` selects `InlineExecutor`)."""
    if name == "ray":
        raise BenchError("the Ray executor is not implemented yet; use --executor local")
    if name not in EXECUTORS:
        raise BenchError(f"unknown executor {name!r}; expected one of {', '.join(EXECUTORS)}")
    if name == "inline" or workers == 0:
        return InlineExecutor()
    return LocalExecutor(workers)
