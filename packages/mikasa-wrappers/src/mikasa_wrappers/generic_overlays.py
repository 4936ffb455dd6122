"""Overlay base class and generic overlays: the reward-overlay switch, the value-access
helpers, `RenderOverlayWrapper`, and the step / reward / reward-term overlays.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from ._drawing import WHITE, draw_text, frames_to_uint8, restore_batching

__all__ = [
    "RenderStepInfoWrapper",
    "RenderRewardInfoWrapper",
    "DebugRewardWrapper",
    "DISABLE_REWARD_OVERLAY_ENV_VAR",
    "reward_overlay_disabled",
]

DISABLE_REWARD_OVERLAY_ENV_VAR = "MIKASA_DISABLE_REWARD_OVERLAY"
_TRUTHY = {"1", "true", "yes", "y", "on"}


def reward_overlay_disabled() -> bool:
    """Whether ``MIKASA_DISABLE_REWARD_OVERLAY`` is set to 1/true/yes/y/on (any case)."""
    return os.environ.get(DISABLE_REWARD_OVERLAY_ENV_VAR, "").strip().lower() in _TRUTHY


# ----------------------------------------------------------------------------------------
# value access helpers
# ----------------------------------------------------------------------------------------


def to_numpy(value: Any) -> Any:
    """A torch tensor as a numpy array (detached, on the CPU); anything else as it is."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return value


def per_env(value: Any, i: int) -> Any:
    """Env i's entry of a batched value; unbatched scalars are returned as they are."""
    value = to_numpy(value)
    if value is None:
        return None
    if isinstance(value, (list, tuple)):
        if not value:
            return None
        return value[i] if i < len(value) else None
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            return value.item()
        return value[i] if i < value.shape[0] else None
    return value


def scalar(value: Any) -> float | None:
    """A single finite number from a value (first element of an array), or None."""
    if value is None:
        return None
    try:
        arr = np.asarray(to_numpy(value), dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        return None
    if not arr.size or not np.isfinite(arr[0]):
        return None
    return float(arr[0])


def lookup(table: Any, key: int) -> Any:
    """``table[key]`` for dicts (int or str keys) and sequences; None if absent."""
    if table is None:
        return None
    if isinstance(table, dict):
        for k in (key, str(key)):
            if k in table:
                return table[k]
        return None
    try:
        return table[key]
    except (IndexError, KeyError, TypeError):
        return None


# ----------------------------------------------------------------------------------------
# base class
# ----------------------------------------------------------------------------------------


class RenderOverlayWrapper(gym.Wrapper):
    """Base class: remember info/reward/steps and draw on every rendered frame."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.last_info: dict = {}
        self.last_reward: Any = None
        self.elapsed_steps: Any = None

    def _remember(self, info: Any, reward: Any) -> None:
        self.last_info = info if isinstance(info, dict) else {}
        self.last_reward = reward
        self.elapsed_steps = self.last_info.get("elapsed_steps")

    def reset(self, **kwargs: Any):
        """Reset and remember the info (the reward is unset until the first step)."""
        obs, info = self.env.reset(**kwargs)
        self._remember(info, None)
        return obs, info

    def step(self, action: Any):
        """Step and remember info, reward and ``elapsed_steps``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._remember(info, reward)
        return obs, reward, terminated, truncated, info

    def _value(self, name: str, i: int) -> Any:
        """Env i's value of ``name`` from the latest info, else from the base env."""
        value = self.last_info.get(name)
        if value is None:
            value = getattr(self.env.unwrapped, name, None)
        return per_env(value, i)

    def render(self):
        """Render through the inner env and draw this overlay on each env's frame."""
        frames = self.env.render()
        if not isinstance(frames, (torch.Tensor, np.ndarray)):
            return frames  # None, or a viewer in render_mode="human": nothing to draw on
        arr, batched = frames_to_uint8(frames)
        for i in range(arr.shape[0]):
            self.draw(arr[i], i)
        return restore_batching(arr, batched)

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw on env i's (H, W, 3) uint8 frame in place."""
        raise NotImplementedError


# ----------------------------------------------------------------------------------------
# generic overlays
# ----------------------------------------------------------------------------------------


class RenderStepInfoWrapper(RenderOverlayWrapper):
    """Draw ``Step: <elapsed_steps>`` at (10, 30)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw the step counter of env i."""
        steps = scalar(per_env(self.elapsed_steps, i))
        if steps is not None:
            draw_text(frame, f"Step: {int(steps)}", (10, 30), 1.0, WHITE, 2)


class RenderRewardInfoWrapper(RenderOverlayWrapper):
    """Draw ``Reward: <r>`` (latest step reward, 3 decimals) at (10, 90).

    Draws nothing while ``MIKASA_DISABLE_REWARD_OVERLAY`` is 1/true/yes/y/on.
    """

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw the latest reward of env i (0.000 before the first step)."""
        if reward_overlay_disabled():
            return
        reward = 0.0 if self.last_reward is None else scalar(per_env(self.last_reward, i))
        if reward is not None:
            draw_text(frame, f"Reward: {reward:.3f}", (10, 90), 1.0, WHITE, 2)


class DebugRewardWrapper(RenderOverlayWrapper):
    """List every ``info["reward_dict"]`` entry (scale 0.5) from y = 170 down, 20 px apart."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's reward terms."""
        reward_dict = self.last_info.get("reward_dict")
        if not isinstance(reward_dict, dict):
            return
        for row, (key, value) in enumerate(reward_dict.items()):
            v = scalar(per_env(value, i))
            text = f"{key}: {v:.3f}" if v is not None else f"{key}: {value}"
            draw_text(frame, text, (10, 170 + 20 * row), 0.5, WHITE, 1)
