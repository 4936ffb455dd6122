"""Writing per-env poses of actors, correct on the CPU sim and batched on the GPU sim."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

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


_ZERO3 = np.zeros(3, dtype=np.float32)


def set_cpu_actor_pose(actor: Actor, raw_pose: np.ndarray, zero_velocity: bool = False) -> None:
    """CPU sim (one env): set ``actor``'s SAPIEN entity to ``raw_pose`` (7,) directly
    (ManiSkill's batched setter costs ~10x more per call), optionally at rest."""
    actor._objs[0].pose = sapien.Pose(raw_pose[:3], raw_pose[3:])
    if zero_velocity:
        body = actor._bodies[0]
        body.linear_velocity = _ZERO3
        body.angular_velocity = _ZERO3


@contextmanager
def only_rows(scene: ManiSkillScene, env_idx: torch.Tensor) -> Iterator[None]:
    """GPU sim: ManiSkill's batched setters write the rows flagged in the scene's reset
    mask; inside this block only the rows of ``env_idx`` are flagged (restored after)."""
    saved_mask = scene._reset_mask.clone()
    scene._reset_mask[:] = False
    scene._reset_mask[env_idx] = True
    try:
        yield
    finally:
        scene._reset_mask[:] = saved_mask


def write_actor_poses(
    scene: ManiSkillScene,
    actors: Sequence[Actor],
    env_idx: torch.Tensor,
    poses: torch.Tensor,
    zero_velocity: bool = False,
) -> None:
    """Set ``actors[k]``'s pose in the envs ``env_idx`` to ``poses[:, k]`` ((b, K, 7) raw
    poses), with zero linear and angular velocity if ``zero_velocity`` (dynamic actors).

    CPU sim (one env): the SAPIEN entities are set directly (`set_cpu_actor_pose`). GPU sim:
    only the rows of ``env_idx`` are written (`only_rows`); the caller applies the data to
    PhysX (``scene.px.gpu_apply_rigid_dynamic_data()``) when it is not inside
    ``_initialize_episode``, where ManiSkill does it.
    """
    if len(env_idx) == 0:
        return
    if not scene.gpu_sim_enabled:
        rows = poses[0].detach().cpu().numpy().astype(np.float64)
        for actor, row in zip(actors, rows, strict=True):
            set_cpu_actor_pose(actor, row, zero_velocity)
        return
    with only_rows(scene, env_idx):
        for k, actor in enumerate(actors):
            actor.set_pose(Pose.create(poses[:, k]))
    if zero_velocity:
        zero_actor_velocities(scene, actors, env_idx)


def zero_actor_velocities(scene: ManiSkillScene, actors: Sequence[Actor], env_idx: torch.Tensor) -> None:
    """Stop the (dynamic) ``actors`` in the envs ``env_idx``: zero linear and angular velocity."""
    if not scene.gpu_sim_enabled:
        for actor in actors:
            actor._bodies[0].linear_velocity = _ZERO3
            actor._bodies[0].angular_velocity = _ZERO3
        return
    zeros = torch.zeros(len(env_idx), 3, device=scene.device)
    with only_rows(scene, env_idx):
        for actor in actors:
            actor.set_linear_velocity(zeros)
            actor.set_angular_velocity(zeros)


def positions_to_poses(positions: torch.Tensor, quat: tuple[float, float, float, float] = IDENTITY_QUAT) -> torch.Tensor:
    """(..., 3) positions -> (..., 7) raw poses with one fixed orientation."""
    q = torch.tensor(quat, dtype=positions.dtype, device=positions.device).expand(*positions.shape[:-1], 4)
    return torch.cat([positions, q], dim=-1)
