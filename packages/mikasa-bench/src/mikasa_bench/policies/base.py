"""The policy interface: what the runner calls on a policy, and the action shape.

A policy is any object with

* ``chunk_size: int`` (optional, default 1; recorded as ``action_chunk_size``),
* ``forward(obs) -> torch.Tensor | numpy.ndarray`` returning one action ``(7,)``, a
  chunk ``(K, 7)`` or a batched chunk ``(1, K, 7)``,
* ``reset()`` or ``reset(seed)`` (optional): called at every episode start, after the env
  reset, so recurrent policies can clear their memory; the ``seed`` form receives the
  episode seed, which makes stochastic policies reproducible whatever the worker count.
"""

from __future__ import annotations

import inspect
from typing import Any, Protocol, runtime_checkable

__all__ = ["ACTION_SHAPE", "ChunkPolicy", "policy_chunk_size", "reset_policy"]

ACTION_SHAPE: tuple[int, ...] = (7,)
"""Action shape of every MIKASA-Robo-VLA task under ``pd_ee_delta_pose`` (num_envs=1)."""


@runtime_checkable
class ChunkPolicy(Protocol):
    """What the runner calls; ``chunk_size`` and ``reset`` are optional (see module doc)."""

    def forward(self, obs: Any) -> Any:
        """Return one action, ``(K, *A)`` or ``(1, K, *A)`` actions for observation ``obs``."""
        ...


def policy_chunk_size(policy: Any) -> int:
    """``policy.chunk_size`` (default 1); ``ValueError`` unless it is a positive int."""
    k = getattr(policy, "chunk_size", 1)
    try:
        k_int = int(k)
    except (TypeError, ValueError):
        raise ValueError(f"policy.chunk_size must be a positive int, got {k!r}") from None
    if k_int <= 0:
        raise ValueError(f"policy.chunk_size must be > 0, got {k!r}")
    return k_int


def reset_policy(policy: Any, seed: int | None) -> None:
    """Call ``policy.reset(seed=seed)`` or ``policy.reset()``, whichever it accepts; no-op
    for policies without ``reset`` (the oracles' rollout does the same; the bench keeps its
    own copy so that policies other than the oracles run without mikasa-oracles)."""
    reset = getattr(policy, "reset", None)
    if not callable(reset):
        return
    try:
        params = inspect.signature(reset).parameters
    except (TypeError, ValueError):  # builtins without a signature
        params = {}
    if "seed" in params or any(p.kind is p.VAR_KEYWORD for p in params.values()):
        reset(seed=seed)
    else:
        reset()
