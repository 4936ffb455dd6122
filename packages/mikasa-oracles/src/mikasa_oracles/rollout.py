"""Running an oracle (or any policy with ``reset``/``forward``) for one episode."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np


class Policy(Protocol):
    """What a rollout needs from a policy."""

    def reset(self) -> None: ...  # or reset(seed=None): then it receives the episode seed

    def forward(self, obs: Any) -> Any: ...


class ZeroActions:
    """The baseline a memory task must defeat: all-zero actions of ``action_dim`` values
    (7 for ``pd_ee_delta_pose``, 8 for ``pd_joint_delta_pos``)."""

    def __init__(self, action_dim: int) -> None:
        self.action_dim = int(action_dim)

    def reset(self) -> None:
        """Nothing to forget."""

    def forward(self, obs: Any) -> np.ndarray:
        """Zeros, float32."""
        return np.zeros(self.action_dim, dtype=np.float32)


@dataclass(frozen=True)
class Rollout:
    """Outcome of one episode: success at any step, steps taken, summed reward."""

    success_once: bool
    steps: int
    episode_return: float


def reset_with_seed(policy: Any, seed: int | None) -> None:
    """``policy.reset(seed=seed)`` where ``reset`` takes a seed (e.g. a memoryless oracle,
    whose guesses it seeds), else ``policy.reset()``; no-op for a policy without ``reset``.
    (mikasa-bench's ``reset_policy`` does the same.)"""
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


def rollout(env: gym.Env, policy: Policy, seed: int, stop_on_success: bool = False) -> Rollout:
    """Reset ``env`` with ``seed`` and step ``policy`` until truncation (or first success).

    The policy is reset after the env, with the episode seed if its ``reset`` takes one.
    """
    obs, _ = env.reset(seed=seed)
    reset_with_seed(policy, seed)
    success, steps, total = False, 0, 0.0
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.forward(obs))
        steps += 1
        total += float(reward.reshape(-1)[0])
        success |= bool(info["success"].reshape(-1)[0])
        if (success and stop_on_success) or bool(terminated.reshape(-1)[0] | truncated.reshape(-1)[0]):
            return Rollout(success, steps, total)
