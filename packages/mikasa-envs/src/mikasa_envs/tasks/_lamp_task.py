"""Base of the lamp-signalled tasks without cue or delay phases (TimedTransfer, GatherAndRecall)."""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import numpy as np
import torch
from mani_skill.utils.structs import Actor

from mikasa_envs.base_env import MikasaVLABaseEnv


def uniform(b: int, low: float, high: float, device: torch.device | str) -> torch.Tensor:
    """(b,) torch draws from U[low, high)."""
    return torch.rand(b, device=device) * (high - low) + low


class LampTaskVLABaseEnv(MikasaVLABaseEnv):
    """Base of tasks whose cue is a colour-switch lamp and that end on success or failure.

    No cue / delay phases: everything is on the table from the first frame, so
    ``cue_steps_per_env`` and ``empty_steps_per_env`` stay 0 (no random draws for them).
    ``evaluate`` of a subclass returns ``success`` and ``failed`` (both latched);
    ``terminated`` = success ∨ failed. Lamp changes decided in ``evaluate`` (after physics,
    before the frame is rendered) are pushed to PhysX on the GPU sim by ``update_visuals``.
    """

    RENDER_CAMERA_EYE = (0.6, 0.7, 0.6)
    RENDER_CAMERA_TARGET = (0.0, 0.0, 0.15)
    # Smoothness penalty coefficients: action L2, action delta L2, arm joint-velocity L2.
    ACTION_L2_COEF: ClassVar[float] = 0.01
    ACTION_DELTA_L2_COEF: ClassVar[float] = 0.03
    QVEL_L2_COEF: ClassVar[float] = 0.01
    # Dense reward of a failed step (the success value is DENSE_REWARD_MAX).
    DENSE_REWARD_FAIL: ClassVar[float] = -25.0

    GPU_MEMORY: ClassVar[dict[str, int]] = {"found_lost_pairs_capacity": 2**25, "max_rigid_patch_count": 2**18}

    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        # No phases (and no random draws for them): the action phase starts at t = 0.
        self.cue_steps_per_env[env_idx] = 0
        self.empty_steps_per_env[env_idx] = 0

    def _terminated(self, info: dict) -> torch.Tensor:
        """The episode ends on success or failure."""
        return info["success"] | info["failed"]

    def _visual_state(self) -> list[torch.Tensor]:
        """Per-env state of the visual-only pieces rewritten in ``evaluate`` (lamp bulbs, caps)."""
        return []

    def update_visuals(self, update: Callable[[], None]) -> None:
        """Run ``update`` (pose writes of lamp bulbs / button caps); on the GPU sim push them
        to PhysX if anything changed (outside episode initialisation ManiSkill does not)."""
        if not self.gpu_sim_enabled:
            update()
            return
        before = [state.clone() for state in self._visual_state()]
        update()
        if any(bool((a != b).any()) for a, b in zip(before, self._visual_state(), strict=True)):
            self.scene.px.gpu_apply_rigid_dynamic_data()

    def actor_positions(self, actors: list[Actor]) -> torch.Tensor:
        """(B, K, 3) current origins of ``actors``; on the CPU sim read from SAPIEN directly."""
        if not self.gpu_sim_enabled:
            positions = np.array([a._objs[0].pose.p for a in actors], dtype=np.float32)
            return torch.from_numpy(positions)[None].to(self.device)
        return torch.stack([a.pose.p for a in actors], dim=1)

    def actor_raw_poses(self, actors: list[Actor]) -> torch.Tensor:
        """(B, K, 7) current raw poses of ``actors``; on the CPU sim read from SAPIEN directly."""
        if not self.gpu_sim_enabled:
            poses = np.array([np.concatenate([a._objs[0].pose.p, a._objs[0].pose.q]) for a in actors], dtype=np.float32)
            return torch.from_numpy(poses)[None].to(self.device)
        return torch.stack([a.pose.raw_pose for a in actors], dim=1)

    def finish_reward(self, reward: torch.Tensor, info: dict, terms: dict[str, torch.Tensor]) -> torch.Tensor:
        """Success steps get DENSE_REWARD_MAX, failed steps DENSE_REWARD_FAIL; keep the terms
        (``info["reward_dict"]`` shows them one step late, as upstream)."""
        reward = torch.where(info["failed"], torch.full_like(reward, self.DENSE_REWARD_FAIL), reward)
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = {**terms, "success": info["success"], "failed": info["failed"]}
        return reward
