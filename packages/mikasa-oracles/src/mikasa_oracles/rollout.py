"""Running an oracle (or any policy with ``reset``/``forward``) for one episode."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np


class Policy(Protocol):
    """What a rollout needs from a policy."""

    def reset(self) -> None: ...

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


def rollout(env: gym.Env, policy: Policy, seed: int, stop_on_success: bool = False) -> Rollout:
    """Reset ``env`` with ``seed`` and step ``policy`` until truncation (or first success)."""
    obs, _ = env.reset(seed=seed)
    policy.reset()
    success, steps, total = False, 0, 0.0
    while True:
        obs, reward, terminated, truncated, info = env.step(policy.forward(obs))
        steps += 1
        total += float(reward.reshape(-1)[0])
        success |= bool(info["success"].reshape(-1)[0])
        if (success and stop_on_success) or bool(terminated.reshape(-1)[0] | truncated.reshape(-1)[0]):
            return Rollout(success, steps, total)
