"""Ray actors that own envs: joining or starting Ray, placing the actors and waiting for
them, shared by the Ray executors of mikasa-bench (evaluation) and mikasa-oracles
(demonstration collection). Ray itself is the callers' optional dependency: these helpers
take the imported ``ray`` module.

Placement: each actor asks for one CPU and Ray's ``SPREAD`` strategy, so the actors are
distributed over the cluster's nodes rather than packed onto the head node; an actor that
renders on the GPU also asks for a share of a GPU, so Ray places it on a GPU node and gives
it a ``CUDA_VISIBLE_DEVICES``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    "READY_TIMEOUT_S",
    "RayStartError",
    "actor_options",
    "equal_gpu_share",
    "init_ray",
    "wait_until_ready",
]

READY_TIMEOUT_S = 600.0
"""How long the actors may take to start (imports, scheduling) before giving up, e.g. when
the cluster cannot satisfy their resource requests."""


class RayStartError(RuntimeError):
    """The actors did not start: the cluster could not place them in time, or one failed."""


def init_ray(
    ray: Any,
    address: str | None = None,
    num_cpus: int | None = None,
    init_kwargs: Mapping[str, Any] | None = None,
) -> bool:
    """Join the cluster at ``address`` (default ``$RAY_ADDRESS``), else start a local Ray
    instance (with ``num_cpus`` CPUs, unless ``init_kwargs`` for ``ray.init`` say otherwise),
    unless Ray is already initialised in this process (by a test or a notebook, say: then it
    is used as it is). True when this call joined or started Ray, so that the caller shuts it
    down."""
    if ray.is_initialized():
        return False
    options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
    options.update(init_kwargs or {})
    address = address or os.environ.get("RAY_ADDRESS")
    if address:
        ray.init(address=address, **options)
    else:
        if num_cpus is not None:
            options.setdefault("num_cpus", num_cpus)
        ray.init(**options)
    return True


def equal_gpu_share(total_gpus: float, actors: int) -> float:
    """Each of ``actors`` actors' equal share of ``total_gpus`` (Ray takes 4 decimals, and a
    share above one GPU must be whole, so at most 1)."""
    return min(1.0, int(total_gpus / actors * 10_000) / 10_000)


def actor_options(gpu_share: float = 0.0) -> dict[str, Any]:
    """``ActorClass.options(...)`` for one env-owning actor: one CPU, spread over the nodes,
    not restarted (a crashed actor is an error the caller reports), ``gpu_share`` of a GPU
    where it is above 0."""
    options: dict[str, Any] = {"num_cpus": 1, "scheduling_strategy": "SPREAD", "max_restarts": 0}
    if gpu_share > 0:
        options["num_gpus"] = gpu_share
    return options


def wait_until_ready(
    ray: Any, actors: Sequence[Any], timeout_s: float = READY_TIMEOUT_S
) -> list[str]:
    """Wait for every actor's ``ready()`` (which returns its node's host name); the host
    names, in the actors' order. ``RayStartError`` when they are not all up within
    ``timeout_s`` or one failed to start."""
    try:
        return ray.get([actor.ready.remote() for actor in actors], timeout=timeout_s)
    except ray.exceptions.GetTimeoutError:
        raise RayStartError(
            f"Ray could not start {len(actors)} worker(s) within {timeout_s:.0f} s; "
            f"cluster resources: {ray.cluster_resources()} (lower --workers?)"
        ) from None
    except ray.exceptions.RayError as exc:
        raise RayStartError(f"a Ray worker failed to start:\n{exc}") from None
