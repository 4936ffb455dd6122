"""The Ray executor: episodes on the workers of a Ray cluster (``--executor ray``).

For users who outgrow one machine. Each Ray actor is one worker exactly like a process of
the local pool (`EpisodeWorker`): it owns one env, builds it once per task and reuses it
for every episode of that task it gets, builds the policy in-process after the env, and
returns an `EpisodeOutcome` (with the mp4 bytes when recording videos). Jobs are handed out
one at a time per actor, preferring the task the actor already has an env for (the local
executor's `Scheduler`), and the runner puts results back in seed order, so the numbers
are the ones the local executor gives.

Placement (`mikasa_envs.ray_actors`, shared with mikasa-oracles' collector): actors ask
for one CPU each and use Ray's ``SPREAD`` strategy, so they are distributed over the
cluster's nodes rather than packed onto the head node. Actors that render on the GPU
(``--render-device gpu``, or the first N of a mixed pool) also ask for an equal share of the
cluster's GPUs, so Ray places them on GPU nodes and gives each one a
``CUDA_VISIBLE_DEVICES``, spreading the rendering over every GPU of a node.

Requirements on a cluster: every node has the same packages installed (``mikasa-bench``
with its envs, and any policy module); a policy given as a file path must exist at the
same path on every node. Results and videos are written only by the driver (this
process), so run directories need no shared filesystem.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from mikasa_envs.ray_actors import (
    RayStartError,
    actor_options,
    equal_gpu_share,
    init_ray,
    wait_until_ready,
)

from mikasa_bench.errors import BenchError
from mikasa_bench.media.render import apply_environment, worker_environment
from mikasa_bench.runners.jobs import EpisodeJob, EpisodeOutcome, Executor, render_config
from mikasa_bench.runners.scheduler import Scheduler
from mikasa_bench.runners.worker import EpisodeWorker

__all__ = ["RayExecutor", "import_ray"]

def import_ray() -> Any:
    """``import ray`` with an installation hint."""
    try:
        import ray
    except ImportError:
        raise BenchError(
            "the Ray executor needs ray: pip install 'mikasa-bench[ray]' (or pip install ray)"
        ) from None
    return ray


class _RayWorker:
    """Body of a Ray actor: one `EpisodeWorker` in a dedicated Ray worker process."""

    def __init__(self, worker_id: int, env_vars: Mapping[str, str]) -> None:
        # Before anything can initialise Vulkan: the render device's driver restriction.
        apply_environment(env_vars)
        from mikasa_envs.workers import quiet_worker

        quiet_worker(one_raster_thread=False)
        self.worker = EpisodeWorker(worker_id)

    def ready(self) -> str:
        """Returns the node's host name once the actor is up."""
        import socket

        return socket.gethostname()

    def run(self, job: EpisodeJob) -> EpisodeOutcome:
        """Run one episode (errors come back inside the outcome)."""
        return self.worker.run(job)

    def close(self) -> None:
        """Close the env."""
        self.worker.close()


class RayExecutor(Executor):
    """Runs episode jobs on Ray actors.

    ``workers``: number of actors (default: the cluster's CPU count). ``address``: the
    cluster to join (default: ``RAY_ADDRESS``, else a new local Ray instance that this
    executor also shuts down). If Ray is already initialised in this process (e.g. by a
    test or a notebook), that instance is used and left running. ``init_kwargs`` go to
    ``ray.init`` when this executor starts Ray.
    """

    name = "ray"

    def __init__(
        self,
        workers: int | None = None,
        address: str | None = None,
        *,
        init_kwargs: Mapping[str, Any] | None = None,
    ) -> None:
        if workers is not None and workers < 1:
            raise BenchError(f"--workers must be >= 1 for the Ray executor, got {workers}")
        self.workers = workers
        self.address = address
        self.init_kwargs = dict(init_kwargs or {})
        self.startup_s: float | None = None
        self.nodes: dict[str, int] = {}
        """Actors per node host name of the last run."""

    def describe(self) -> dict[str, Any]:
        """Name, actor count (if fixed) and cluster address."""
        out: dict[str, Any] = {"name": self.name}
        if self.workers is not None:
            out["workers"] = self.workers
        out["address"] = self.address or os.environ.get("RAY_ADDRESS") or "local"
        return out

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Start the actors, feed them, yield outcomes; always removes the actors (and
        shuts Ray down if this executor started it)."""
        jobs = list(jobs)
        if not jobs:
            return
        ray = import_ray()
        config = render_config(jobs)
        t_start = time.perf_counter()
        started = init_ray(ray, self.address, self.workers, self.init_kwargs)
        actors: list[Any] = []
        try:
            resources = ray.cluster_resources()
            n = self.workers or max(1, int(resources.get("CPU", 1)))
            n = min(n, len(jobs))
            devices = [config.render_device_for(i) for i in range(n)]
            n_gpu = devices.count("gpu")
            gpu_share = 0.0
            if n_gpu:
                total_gpus = float(resources.get("GPU", 0.0))
                if total_gpus <= 0:
                    raise BenchError(
                        f"{n_gpu} worker(s) should render on the GPU (render device "
                        f"{config.render_description()}), but the Ray cluster has no GPUs"
                    )
                gpu_share = equal_gpu_share(total_gpus, n_gpu)
            actor_cls = ray.remote(_RayWorker)
            for wid, device in enumerate(devices):
                options = actor_options(gpu_share if device == "gpu" else 0.0)
                # One CPU per actor: lavapipe rasterises in the actor's own thread.
                env_vars = worker_environment(device, lp_threads=0)
                actors.append(actor_cls.options(**options).remote(wid, env_vars))
            self._wait_ready(ray, actors)
            self.startup_s = time.perf_counter() - t_start
            yield from self._schedule(ray, actors, jobs)
        finally:
            for actor in actors:
                try:
                    ray.kill(actor)
                except Exception:
                    pass
            if started:
                ray.shutdown()

    def _wait_ready(self, ray: Any, actors: Sequence[Any]) -> None:
        try:
            hosts = wait_until_ready(ray, actors)
        except RayStartError as exc:
            raise BenchError(str(exc)) from None
        self.nodes = {}
        for h in hosts:
            self.nodes[h] = self.nodes.get(h, 0) + 1

    @staticmethod
    def _schedule(
        ray: Any, actors: Sequence[Any], jobs: Sequence[EpisodeJob]
    ) -> Iterator[EpisodeOutcome]:
        scheduler = Scheduler(jobs)
        in_flight: dict[Any, tuple[int, EpisodeJob]] = {}
        last: list[EpisodeJob | None] = [None] * len(actors)

        def assign(wid: int) -> None:
            job = scheduler.next_for(last[wid])
            if job is not None:
                in_flight[actors[wid].run.remote(job)] = (wid, job)

        for wid in range(len(actors)):
            assign(wid)
        remaining = len(jobs)
        while remaining:
            done, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in done:
                wid, job = in_flight.pop(ref)
                try:
                    outcome = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    raise BenchError(
                        f"Ray worker {wid} failed while running {job.task.env_id} episode "
                        f"{job.episode} (seed {job.seed}): {type(exc).__name__}: {exc}; "
                        f"finished episodes are saved — rerun with --resume to continue"
                    ) from None
                last[wid] = job
                remaining -= 1
                assign(wid)
                yield outcome
