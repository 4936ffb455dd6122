"""The built-in policies: ``zero``, ``random``, ``oracle``, ``oracle-memoryless`` (and
`DummyChunkPolicy`, the reference demo's policy, given as
``mikasa_bench.policies:DummyChunkPolicy``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mikasa_bench.policies.base import ACTION_SHAPE, policy_chunk_size
from mikasa_bench.policies.oracle_extra import require_oracles

__all__ = [
    "BUILTIN_POLICIES",
    "ORACLE_TARGETS",
    "DummyChunkPolicy",
    "RandomPolicy",
    "ZeroPolicy",
]


class ZeroPolicy:
    """All-zero actions (under ``pd_ee_delta_pose``: hold the pose, gripper command 0)."""

    def __init__(self, chunk_size: int = 1, action_shape: Sequence[int] = ACTION_SHAPE) -> None:
        self.chunk_size = int(chunk_size)
        self.action_shape = tuple(action_shape)
        policy_chunk_size(self)

    def forward(self, obs: Any) -> np.ndarray:
        """``chunk_size`` zero actions."""
        return np.zeros((self.chunk_size, *self.action_shape), dtype=np.float32)


class RandomPolicy:
    """Uniform actions in ``[-1, 1]``, reproducible: reseeded from ``(seed, episode seed)``
    at every episode start."""

    def __init__(
        self, seed: int = 0, chunk_size: int = 1, action_shape: Sequence[int] = ACTION_SHAPE
    ) -> None:
        self.seed = int(seed)
        self.chunk_size = int(chunk_size)
        self.action_shape = tuple(action_shape)
        policy_chunk_size(self)
        self.reset(seed=0)

    def reset(self, seed: int | None = None) -> None:
        """Restart the action stream for the episode with seed ``seed``."""
        self._rng = np.random.default_rng([self.seed, int(seed or 0)])

    def forward(self, obs: Any) -> np.ndarray:
        """``chunk_size`` uniform random actions."""
        return self._rng.uniform(-1.0, 1.0, (self.chunk_size, *self.action_shape)).astype(
            np.float32
        )


class DummyChunkPolicy:
    """The reference demo's policy (benchmark.md §9): random ``(chunk_size, action_dim)``
    float32 tensor in ``[-1, 1]`` on the device of ``obs["proprio"]``."""

    def __init__(self, chunk_size: int = 8, action_dim: int = 7) -> None:
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be > 0, got {chunk_size}")
        self.chunk_size = int(chunk_size)
        self.action_dim = int(action_dim)

    def forward(self, obs: Any) -> Any:
        """Random chunk drawn from torch's global RNG (seeded per episode by the runner)."""
        import torch

        proprio = obs.get("proprio") if isinstance(obs, dict) else None
        device = proprio.device if isinstance(proprio, torch.Tensor) else torch.device("cpu")
        with torch.no_grad():
            return torch.rand(self.chunk_size, self.action_dim, device=device) * 2 - 1


def _make_oracle(env: Any, **kwargs: Any) -> Any:
    return require_oracles("the oracle policy").make_oracle(env, **kwargs)


def _make_memoryless_oracle(env: Any, **kwargs: Any) -> Any:
    return require_oracles("the oracle-memoryless policy").make_oracle(
        env, memoryless=True, **kwargs
    )


ORACLE_TARGETS: tuple[str, ...] = ("oracle", "oracle-memoryless")
"""Built-ins that read the privileged state of the env they are built for."""

BUILTIN_POLICIES: dict[str, Callable[..., Any]] = {
    "zero": ZeroPolicy,
    "random": RandomPolicy,
    "oracle": _make_oracle,
    "oracle-memoryless": _make_memoryless_oracle,
}
"""Built-in policy name -> factory."""
