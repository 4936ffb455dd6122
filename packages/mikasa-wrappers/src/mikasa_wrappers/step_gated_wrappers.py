"""Wrappers gated on each env's elapsed step count: the action wrappers that freeze envs
(curriculum cue/empty phases, initial steps) and `CameraShutdownWrapper`.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from ._drawing import frames_to_uint8, restore_batching
from ._wrapper_helpers import as_step_tensor, elapsed_from_info

__all__ = [
    "CurriculumPhaseNoopActionWrapper",
    "CurriculumPhaseNoopActionWrapperPdJointPos",
    "InitialZeroActionWrapper",
    "CameraShutdownWrapper",
]

# Finger-joint target range of the Panda gripper under pd_joint_pos: [-0.01, 0.04] maps to
# the normalised gripper command [-1, 1].
_FINGER_CENTER = 0.015
_FINGER_HALF_RANGE = 0.025


# ----------------------------------------------------------------------------------------
# action wrappers
# ----------------------------------------------------------------------------------------


class _StepGatedActionWrapper(gym.ActionWrapper):
    """Base for action wrappers that replace the rows of some envs depending on the step.

    Remembers ``info["elapsed_steps"]`` of the latest reset/step; subclasses say which envs
    are frozen (`_frozen_mask`) and what their rows become (`_frozen_rows`).
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.current_steps: Any = None

    def reset(self, **kwargs: Any):
        """Reset the env and remember ``info["elapsed_steps"]``."""
        obs, info = self.env.reset(**kwargs)
        self.current_steps = elapsed_from_info(info)
        return obs, info

    def step(self, action: Any):
        """Step with the (possibly replaced) action and remember ``info["elapsed_steps"]``."""
        obs, reward, terminated, truncated, info = self.env.step(self.action(action))
        self.current_steps = elapsed_from_info(info)
        return obs, reward, terminated, truncated, info

    def _frozen_mask(self) -> torch.Tensor | None:
        raise NotImplementedError

    def _frozen_rows(self, action: Any, mask: Any) -> Any:
        """Return `action` (already a private (B, dim) copy) with the masked rows replaced."""
        action[mask] = 0
        return action

    def action(self, action: Any) -> Any:
        """Return the action unchanged, or a copy with the rows of frozen envs replaced."""
        mask = self._frozen_mask()
        if mask is None or not bool(mask.any()):
            return action
        batch = int(mask.shape[0])
        if isinstance(action, torch.Tensor):
            out = action.reshape(1, -1).expand(batch, -1) if action.ndim == 1 else action
            out = out.clone()
            return self._frozen_rows(out, mask.to(out.device))
        arr = np.asarray(action)
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (batch, arr.shape[0]))
        return self._frozen_rows(np.array(arr, copy=True), mask.cpu().numpy())


class CurriculumPhaseNoopActionWrapper(_StepGatedActionWrapper):
    """Zero the whole action row of every env still in its cue or empty phase.

    Env i is frozen while ``elapsed_steps[i] < cue_steps_per_env[i] + empty_steps_per_env[i]``
    (the empty term is skipped if the env has no such attribute). Nothing happens before the
    first reset or if the env has no ``cue_steps_per_env``. If no env is frozen the action
    object is passed through unchanged; otherwise a copy is made (a 1-D action is broadcast
    to (B, dim) first) and torch stays torch, numpy stays numpy.
    """

    def _frozen_mask(self) -> torch.Tensor | None:
        if self.current_steps is None:
            return None
        base = self.env.unwrapped
        cue = getattr(base, "cue_steps_per_env", None)
        if cue is None:
            return None
        cue = torch.as_tensor(cue)
        limit = cue
        empty = getattr(base, "empty_steps_per_env", None)
        if empty is not None:
            limit = cue + torch.as_tensor(empty, device=cue.device)
        steps = as_step_tensor(self.current_steps, limit.device)
        # The per-env attributes may be longer than B (allocated for the max num_envs).
        return steps < limit.reshape(-1)[: steps.shape[0]]


class CurriculumPhaseNoopActionWrapperPdJointPos(CurriculumPhaseNoopActionWrapper):
    """`CurriculumPhaseNoopActionWrapper` for ``pd_joint_pos``: frozen envs hold their pose.

    Under ``pd_joint_pos`` a zero action would drive every joint to 0, so the frozen rows
    become the current arm joint positions plus the gripper command that keeps the fingers
    where they are: ``clip((q_finger - 0.015) / 0.025, -1, 1)`` (Panda finger range
    -0.01 ... 0.04).
    """

    def _frozen_rows(self, action: Any, mask: Any) -> Any:
        qpos = self.env.unwrapped.agent.robot.get_qpos()
        arm_dim = action.shape[-1] - 1
        if isinstance(action, torch.Tensor):
            qpos = qpos.to(device=action.device, dtype=action.dtype)
            grip = ((qpos[:, -1] - _FINGER_CENTER) / _FINGER_HALF_RANGE).clamp(-1.0, 1.0)
            hold = torch.cat([qpos[:, :arm_dim], grip[:, None]], dim=-1)
        else:
            q = qpos.detach().cpu().numpy().astype(action.dtype, copy=False)
            grip = np.clip((q[:, -1] - _FINGER_CENTER) / _FINGER_HALF_RANGE, -1.0, 1.0)
            hold = np.concatenate([q[:, :arm_dim], grip[:, None]], axis=-1)
        action[mask] = hold[mask]
        return action


class InitialZeroActionWrapper(_StepGatedActionWrapper):
    """Zero the action rows of every env whose ``elapsed_steps`` is below ``n_initial_steps``."""

    def __init__(self, env: gym.Env, n_initial_steps: int = 1) -> None:
        super().__init__(env)
        self.n_initial_steps = int(n_initial_steps)

    def _frozen_mask(self) -> torch.Tensor | None:
        if self.current_steps is None:
            return None
        return as_step_tensor(self.current_steps) < self.n_initial_steps


# ----------------------------------------------------------------------------------------
# CameraShutdownWrapper
# ----------------------------------------------------------------------------------------


class CameraShutdownWrapper(gym.Wrapper):
    """Black out the cameras once any env is past ``n_initial_steps`` steps.

    From then on every tensor under ``sensor_data/base_camera`` and
    ``sensor_data/hand_camera`` is multiplied by 0, and rendered frames are blanked to the
    right of the human-render camera's width (the sensor tiles of ``render_mode="all"``).
    """

    CAMERAS = ("base_camera", "hand_camera")

    def __init__(self, env: gym.Env, n_initial_steps: int = 19) -> None:
        super().__init__(env)
        self.n_initial_steps = int(n_initial_steps)
        self.current_steps: Any = None

    @property
    def shutdown_active(self) -> bool:
        """Whether any env is past ``n_initial_steps`` (cameras are off)."""
        if self.current_steps is None:
            return False
        return bool((as_step_tensor(self.current_steps) > self.n_initial_steps).any())

    def _observation(self, obs: Any) -> Any:
        if not self.shutdown_active or not isinstance(obs, dict):
            return obs
        sensor_data = obs.get("sensor_data")
        if not isinstance(sensor_data, dict):
            return obs
        obs = dict(obs)
        # New dicts/tensors: the env may still own the originals.
        sensor_data = dict(sensor_data)
        for cam in self.CAMERAS:
            if isinstance(sensor_data.get(cam), dict):
                sensor_data[cam] = {k: v * 0 for k, v in sensor_data[cam].items()}
        obs["sensor_data"] = sensor_data
        return obs

    def reset(self, **kwargs: Any):
        """Reset and remember ``elapsed_steps``."""
        obs, info = self.env.reset(**kwargs)
        self.current_steps = elapsed_from_info(info)
        return self._observation(obs), info

    def step(self, action: Any):
        """Step, remember ``elapsed_steps`` and black out the cameras if past the limit."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.current_steps = elapsed_from_info(info)
        return self._observation(obs), reward, terminated, truncated, info

    def _render_width(self) -> int | None:
        configs = getattr(self.env.unwrapped, "_human_render_camera_configs", None)
        if isinstance(configs, dict) and configs:
            width = getattr(next(iter(configs.values())), "width", None)
            return int(width) if width is not None else None
        return None

    def render(self):
        """Render; once the cameras are off, blank everything right of the render camera."""
        frames = self.env.render()
        width = self._render_width()
        if (
            not isinstance(frames, (torch.Tensor, np.ndarray))
            or not self.shutdown_active
            or width is None
        ):
            return frames
        arr, batched = frames_to_uint8(frames)
        arr[:, :, width:] = 0
        return restore_batching(arr, batched)
