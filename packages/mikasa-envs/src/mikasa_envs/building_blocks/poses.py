"""Writing per-env poses of actors, correct on the CPU sim and batched on the GPU sim."""

from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor, Pose

IDENTITY_QUAT = (1.0, 0.0, 0.0, 0.0)
# SAPIEN cylinders lie along x; this rotation (+90° about y) stands one upright.
UPRIGHT_CYLINDER_QUAT = (float(np.cos(np.pi / 4)), 0.0, float(np.sin(np.pi / 4)), 0.0)
# Objects "hidden" by teleporting are parked this far above their place (common.md §10).
HIDE_OFFSET_Z = 1000.0


def write_actor_poses(scene: ManiSkillScene, actors: list[Actor], env_idx: torch.Tensor, poses: torch.Tensor) -> None:
    """Set ``actors[k]``'s pose in the envs ``env_idx`` to ``poses[:, k]`` ((b, K, 7) raw poses).

    CPU sim (one env): the SAPIEN entities are set directly (ManiSkill's batched setter costs
    ~10x more per call). GPU sim: only the rows of ``env_idx`` are written (ManiSkill writes
    the rows flagged in the scene's reset mask, which is saved and restored here); the caller
    applies the data to PhysX (``scene.px.gpu_apply_rigid_dynamic_data()``) when it is not
    inside ``_initialize_episode``, where ManiSkill does it.
    """
    if len(env_idx) == 0:
        return
    if not scene.gpu_sim_enabled:
        rows = poses[0].detach().cpu().numpy().astype(np.float64)
        for actor, row in zip(actors, rows, strict=True):
            actor._objs[0].pose = sapien.Pose(row[:3], row[3:])
        return
    saved_mask = scene._reset_mask.clone()
    scene._reset_mask[:] = False
    scene._reset_mask[env_idx] = True
    for k, actor in enumerate(actors):
        actor.set_pose(Pose.create(poses[:, k]))
    scene._reset_mask[:] = saved_mask


def positions_to_poses(positions: torch.Tensor, quat: tuple[float, float, float, float] = IDENTITY_QUAT) -> torch.Tensor:
    """(..., 3) positions -> (..., 7) raw poses with one fixed orientation."""
    q = torch.tensor(quat, dtype=positions.dtype, device=positions.device).expand(*positions.shape[:-1], 4)
    return torch.cat([positions, q], dim=-1)
