"""The executors of ``mikasa-collect``: where the attempts (one seed each) run.

Every pool has the same small interface: ``submit(seed)``, ``get()`` (the next finished
attempt, in completion order), ``close()`` and ``slots`` (runners in all). The collector keeps
at most ``slots`` attempts in flight and commits them in seed order, so the files do not
depend on the pool, its size or the timing. The local pools also take
``submit(seed, runner_args)``: a runner built for other arguments (another task) is closed
and one for these is built, so one pool serves the tasks of a ``--split`` or repeated
``--env-id`` run one after another without restarting its processes.

* :class:`InlinePool` — ``--workers 1``: in this process.
* :class:`ProcessPool` — ``--workers W``: W spawn-started local processes, each running
  ``--envs-per-worker K`` runners (one env each) in K threads whose envs render together
  (``mikasa_envs.render_batcher``: on a GPU, K times fewer render passes).
* :class:`RayPool` — ``--executor ray``: W actors on a Ray cluster (one CPU each, spread over
  the nodes, with an equal share of the cluster's GPUs where it has any, so that they
  render there). Each actor stages its episodes in a directory of its own node and sends
  the file's bytes back; only this process writes into the dataset, so the nodes need no
  shared filesystem.

A runner is built by ``factory(*runner_args)`` (default: the VLA collector's attempt runner,
``mikasa_oracles.collect_attempts.AttemptRunner``, whose second argument is the staging directory).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from mikasa_oracles.collect_attempts import AttemptRunner
from mikasa_oracles.collect_errors import CollectError, CollectionFailed

__all__ = ["CollectError", "CollectionFailed", "InlinePool", "ProcessPool", "RayPool"]


class _TaskRunner:
    """A worker's runner across tasks: runs ``(runner_args, job)`` pairs on
    ``factory(*runner_args)``, rebuilt when the arguments change (None: built on the first
    job)."""

    def __init__(self, factory: Callable[..., Any], runner_args: tuple[Any, ...] | None) -> None:
        self.factory = factory
        self.args = runner_args
        self.runner = None if runner_args is None else factory(*runner_args)

    def run(self, job: tuple[tuple[Any, ...], Any]) -> Any:
        args, inner = job
        if self.runner is None or args != self.args:
            self.close()
            self.runner, self.args = self.factory(*args), args
        return self.runner.run(inner)

    def close(self) -> None:
        if self.runner is not None:
            self.runner.close()
            self.runner = None


class InlinePool:
    """``--workers 1``: attempts run in this process, one at a time.

    ``factory(*runner_args)`` builds the runner (default :class:`AttemptRunner`; the RL
    collector, ``mikasa_robo_rl.collect``, passes its own; None: built on the first job).
    """

    slots = 1

    def __init__(
        self, runner_args: tuple[Any, ...] | None, factory: Callable[..., Any] | None = None
    ) -> None:
        self.runner_args = runner_args
        self.runner = _TaskRunner(_runner_factory(factory), runner_args)
        self.queue: list[Any] = []

    def submit(self, seed: int, runner_args: tuple[Any, ...] | None = None) -> None:
        self.queue.append((runner_args or self.runner_args, seed))

    def get(self) -> Any:
        return self.runner.run(self.queue.pop(0))

    def close(self, graceful: bool = True) -> None:
        self.runner.close()


def _start_runner(
    runner_args: tuple[Any, ...] | None, factory: Callable[..., Any] | None = None
) -> _TaskRunner:
    from mikasa_envs.workers import quiet_worker  # imported lazily: mikasa_envs loads ManiSkill

    quiet_worker()
    return _TaskRunner(_runner_factory(factory), runner_args)


def _worker_main(
    process_index: int,
    worker_ids: list[int],
    runner_args: tuple[Any, ...],
    jobs: Any,
    results: Any,
    factory: Callable[..., Any] | None = None,
) -> None:
    """Entry point of a spawn-started process: one runner per id of ``worker_ids`` (a thread
    each when there are several), each running jobs (seeds) from the shared ``jobs`` queue
    until it gets ``None``."""
    # imported lazily: mikasa_envs loads ManiSkill
    from mikasa_envs.workers import serve_job_slots, use_one_gpu

    use_one_gpu(process_index)  # a CUDA context on one GPU, not on each; spreads GPU rendering
    start = partial(_start_runner, runner_args, factory)
    serve_job_slots(worker_ids, [jobs] * len(worker_ids), results, lambda _wid: start())


class ProcessPool:
    """``--workers W``: W spawn-started processes sharing one job queue.

    Each process runs ``envs_per_worker`` runners built by ``factory(*runner_args)``
    (default :class:`AttemptRunner`; ``factory`` must be importable by name, e.g. a
    module-level class; ``runner_args`` None: each job names its own), in as many threads
    when there are several (their envs then render in shared passes; a runner's results
    must not depend on the other threads: the collectors' do not, each attempt building its
    scene afresh). ``slots`` runners in all. A job's result names its job in the attribute
    ``job_attr`` (an attempt's ``seed``).
    """

    def __init__(
        self,
        runner_args: tuple[Any, ...] | None,
        workers: int,
        factory: Callable[..., Any] | None = None,
        *,
        envs_per_worker: int = 1,
        job_attr: str = "seed",
        name: str = "mikasa-collect",
    ) -> None:
        ctx = mp.get_context("spawn")
        self.runner_args = runner_args
        self.jobs = ctx.Queue()
        self.results = ctx.Queue()
        self.job_attr = job_attr
        self.in_flight: set[Any] = set()
        self.slots = workers * envs_per_worker
        self.processes = [
            ctx.Process(
                target=_worker_main,
                args=(
                    w,
                    list(range(w * envs_per_worker, (w + 1) * envs_per_worker)),
                    runner_args,
                    self.jobs,
                    self.results,
                    factory,
                ),
                daemon=True,
                name=f"{name}-{w}",
            )
            for w in range(workers)
        ]
        for p in self.processes:
            p.start()

    def submit(self, seed: Any, runner_args: tuple[Any, ...] | None = None) -> None:
        self.in_flight.add(seed)
        self.jobs.put((runner_args or self.runner_args, seed))

    def get(self) -> Any:
        while True:
            try:
                kind, wid, payload = self.results.get(timeout=1.0)
            except queue.Empty:
                dead = [p for p in self.processes if not p.is_alive()]
                if dead and self.in_flight:
                    raise CollectionFailed(
                        f"worker {dead[0].name} died (exit code {dead[0].exitcode}) with "
                        f"{self.job_attr}s {sorted(self.in_flight)} in flight; saved episodes "
                        "are kept, rerun to resume"
                    ) from None
                continue
            if kind == "fatal":
                raise CollectionFailed(f"worker {wid} failed to start:\n{payload}")
            if kind == "ready":
                continue
            self.in_flight.discard(getattr(payload, self.job_attr))
            return payload

    def close(self, graceful: bool = True) -> None:
        from mikasa_envs.workers import stop_processes

        graceful = graceful and not self.in_flight
        if graceful:
            for _ in range(self.slots):
                self.jobs.put(None)
        # Graceful: nothing is left to write (every attempt came back), so a worker slow
        # to tear down its simulator is not worth waiting for long. Error / interrupt:
        # stop now; their attempts were not committed and will be rerun.
        stop_processes(self.processes, wait_s=3 if graceful else 0)


def _runner_factory(factory: Callable[..., Any] | None) -> Callable[..., Any]:
    """``factory``, or the default: the VLA collector's :class:`AttemptRunner` (looked up
    when the pool builds its runners, so a test can stand in for it)."""
    return factory if factory is not None else AttemptRunner


class _RayAttemptWorker:
    """Body of a Ray actor: one runner that stages into a directory of the actor's node."""

    def __init__(self, runner_args: tuple[Any, ...], factory: Callable[..., Any] | None) -> None:
        self.staging = tempfile.mkdtemp(prefix="mikasa-collect-")
        self.args = (runner_args[0], self.staging, *runner_args[2:])
        self.runner = _start_runner(self.args, factory)

    def ready(self) -> str:
        """The node's host name, once the actor is up."""
        import socket

        return socket.gethostname()

    def run(self, seed: int) -> tuple[Any, bytes | None]:
        """One attempt, and the staged episode file's bytes (the file is removed here)."""
        result = self.runner.run((self.args, seed))
        if result.staged is None:
            return result, None
        staged = Path(result.staged)
        data = staged.read_bytes()
        staged.unlink()
        return result, data

    def close(self) -> None:
        self.runner.close()
        shutil.rmtree(self.staging, ignore_errors=True)


def import_ray() -> Any:
    """``import ray`` with an installation hint."""
    try:
        import ray
    except ImportError:
        raise CollectError(
            "--executor ray needs ray: pip install 'mikasa-oracles[ray]' (or pip install ray)"
        ) from None
    return ray


class RayPool:
    """``--executor ray``: ``workers`` Ray actors (see the module docstring).

    Connects to ``address`` (or ``$RAY_ADDRESS``), else starts a local Ray instance with
    ``workers`` CPUs, unless Ray is already initialised; a Ray instance it started is shut
    down by :meth:`close`. Staged files come back into ``runner_args[1]`` on this machine.
    """

    def __init__(
        self,
        runner_args: tuple[Any, ...],
        workers: int,
        factory: Callable[..., Any] | None = None,
        *,
        address: str | None = None,
    ) -> None:
        # Imported lazily: mikasa_envs loads ManiSkill.
        from mikasa_envs.ray_actors import (
            RayStartError,
            actor_options,
            equal_gpu_share,
            init_ray,
            wait_until_ready,
        )

        ray = self.ray = import_ray()
        self.runner_args = runner_args
        self.staging = Path(runner_args[1])
        self.started = init_ray(ray, address, workers)
        gpus = float(ray.cluster_resources().get("GPU", 0.0))
        # Render on the cluster's GPUs where it has any.
        options = actor_options(equal_gpu_share(gpus, workers) if gpus > 0 else 0.0)
        actor_cls = ray.remote(_RayAttemptWorker)
        self.actors = [actor_cls.options(**options).remote(runner_args, factory) for _ in range(workers)]
        try:
            wait_until_ready(ray, self.actors)
        except RayStartError as exc:
            self.close()
            raise CollectionFailed(str(exc)) from None
        self.slots = workers
        self.idle = list(self.actors)
        self.waiting: list[int] = []
        self.running: dict[Any, tuple[Any, int]] = {}

    def _dispatch(self) -> None:
        while self.idle and self.waiting:
            actor, seed = self.idle.pop(), self.waiting.pop(0)
            self.running[actor.run.remote(seed)] = (actor, seed)

    def submit(self, seed: int, runner_args: tuple[Any, ...] | None = None) -> None:
        """Queue ``seed``. A Ray pool serves the one task it was built for (its actors stage
        on their own nodes): ``runner_args``, if given, must be that task's."""
        if runner_args is not None and runner_args != self.runner_args:
            raise ValueError("a RayPool runs the task it was built for only")
        self.waiting.append(seed)
        self._dispatch()

    def get(self) -> Any:
        ray = self.ray
        (ref,), _ = ray.wait(list(self.running), num_returns=1)
        actor, seed = self.running.pop(ref)
        try:
            result, data = ray.get(ref)
        except ray.exceptions.RayError as exc:
            raise CollectionFailed(
                f"Ray worker failed on seed {seed}: {type(exc).__name__}: {exc}; saved episodes "
                "are kept, rerun to resume"
            ) from None
        self.idle.append(actor)
        self._dispatch()
        if data is not None:
            staged = self.staging / Path(result.staged).name
            tmp = staged.with_name(staged.name + ".tmp")
            tmp.write_bytes(data)
            os.replace(tmp, staged)
            result = replace(result, staged=str(staged))
        return result

    def close(self, graceful: bool = True) -> None:
        ray = self.ray
        if graceful and not self.running:
            try:
                ray.get([a.close.remote() for a in self.actors], timeout=30)
            except Exception:
                pass
        for actor in self.actors:
            try:
                ray.kill(actor)
            except Exception:
                pass
        if self.started:
            ray.shutdown()
