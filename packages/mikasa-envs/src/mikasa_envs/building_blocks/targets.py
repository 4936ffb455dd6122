"""Flat target discs: concentric rings of two colours lying on the table, and a target
whose colour switches (two discs at one spot, one shown at a time).

The disc is ManiSkill's ``build_red_white_target`` geometry with free colours and no
collision: 5 visual cylinders of radius r, 4r/5, 3r/5, 2r/5, r/5 coloured primary /
secondary / primary / secondary / primary from the outside in, each 1e-5 thicker than the
one around it so the inner rings are drawn on top. A cylinder's axis is its local x;
``FLAT_QUAT`` turns it to world z, so the disc lies flat.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import numpy as np
import sapien
import torch
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.building_blocks.cubes import rgba01

# (w, x, y, z): a quarter turn about y, cylinder axis x -> world z.
FLAT_QUAT = (0.7071068, 0.0, 0.7071068, 0.0)
TARGET_THICKNESS = 1e-5
TARGET_Z = 0.001
HIDDEN_Z = 1000.0
NUM_RINGS = 5
TARGET_RED_255 = (194, 19, 22, 255)
WHITE_255 = (255, 255, 255, 255)


def build_target_disc(
    scene: ManiSkillScene,
    radius: float,
    name: str,
    primary_rgba255: Sequence[int] = TARGET_RED_255,
    secondary_rgba255: Sequence[int] = WHITE_255,
    thickness: float = TARGET_THICKNESS,
    initial_pose: sapien.Pose | None = None,
) -> Actor:
    """A kinematic, collision-free target disc of ``NUM_RINGS`` concentric rings.

    With the default colours this is ManiSkill's red/white target without collision.
    """
    builder = scene.create_actor_builder()
    for ring in range(NUM_RINGS):
        colour = primary_rgba255 if ring % 2 == 0 else secondary_rgba255
        builder.add_cylinder_visual(
            radius=radius * (NUM_RINGS - ring) / NUM_RINGS,
            half_length=thickness / 2 + ring * 1e-5,
            material=sapien.render.RenderMaterial(base_color=list(rgba01(colour))),
        )
    builder.initial_pose = initial_pose or sapien.Pose(p=[0, 0, HIDDEN_Z], q=FLAT_QUAT)
    return builder.build_kinematic(name=name)


def flat_poses(xy: torch.Tensor, z: float | torch.Tensor = TARGET_Z) -> Pose:
    """Flat disc poses at ``xy`` ((b, 2)) and height ``z`` (one for all, or (b,))."""
    b = xy.shape[0]
    heights = torch.as_tensor(z, dtype=xy.dtype, device=xy.device).expand(b)
    p = torch.cat([xy, heights[:, None]], dim=1)
    q = torch.tensor(FLAT_QUAT, dtype=xy.dtype, device=xy.device).expand(b, 4)
    return Pose.create_from_pq(p=p, q=q)


def set_disc_pose(disc: Actor, xy: torch.Tensor, z: float, env_idx: torch.Tensor | None = None) -> None:
    """Lay ``disc`` flat at ``xy`` ((b, 2)) and height ``z`` in the envs ``env_idx``.

    ``env_idx`` None means every env (``xy`` then has one row per env). On the GPU backend
    only the rows of envs in the scene's reset mask are written: call it during episode
    initialisation, or see ``SwitchingTarget.switch`` for mid-episode writes.
    """
    if env_idx is None or disc.scene.gpu_sim_enabled:
        disc.set_pose(flat_poses(xy, z))
        return
    # CPU: one env, a direct SAPIEN write (cheaper than the batched setter).
    row = xy[0].cpu().numpy().astype(np.float64)
    disc._objs[0].pose = sapien.Pose([row[0], row[1], z], FLAT_QUAT)


class SwitchingTarget:
    """A target that changes colour: a first disc shown until ``switch``, then a second.

    Both discs share a spot; the one not shown waits at ``HIDDEN_Z`` above it (outside
    every camera's view). Which disc is shown is per env (``switched``, (B,) bool).
    """

    # Per-env state saved with the env's task state (``MikasaVLABaseEnv.TASK_STATE``).
    STATE_ATTRS: ClassVar[tuple[str, ...]] = ("xy", "switched")

    def __init__(
        self,
        scene: ManiSkillScene,
        radius: float,
        name: str,
        first_rgba255: Sequence[int],
        second_rgba255: Sequence[int],
        secondary_rgba255: Sequence[int] = WHITE_255,
        changed_name: str | None = None,
    ) -> None:
        self.first = build_target_disc(scene, radius, name, first_rgba255, secondary_rgba255)
        self.second = build_target_disc(scene, radius, changed_name or f"changed_{name}", second_rgba255, secondary_rgba255)
        self.scene = scene
        device = scene.device
        self.xy = torch.zeros(scene.num_envs, 2, device=device)
        self.switched = torch.zeros(scene.num_envs, dtype=torch.bool, device=device)

    def place(self, env_idx: torch.Tensor, xy: torch.Tensor) -> None:
        """Show the first disc at ``xy`` ((len(env_idx), 2)) in the envs ``env_idx``, unswitched."""
        self.xy[env_idx] = xy.to(self.xy)
        self.switched[env_idx] = False
        set_disc_pose(self.first, xy, TARGET_Z, env_idx)
        set_disc_pose(self.second, xy, HIDDEN_Z, env_idx)

    def switch(self, env_mask: torch.Tensor) -> None:
        """Show the second disc instead of the first in the envs of ``env_mask`` ((B,) bool);
        envs already switched are left alone (the switch is permanent until ``place``)."""
        new = env_mask & ~self.switched
        if not bool(new.any()):
            return
        self.switched |= new
        if not self.scene.gpu_sim_enabled:
            set_disc_pose(self.first, self.xy, HIDDEN_Z, env_idx=new.nonzero()[:, 0])
            set_disc_pose(self.second, self.xy, TARGET_Z, env_idx=new.nonzero()[:, 0])
            return
        # GPU: ManiSkill writes the rows of the envs in the scene's reset mask; write every
        # row (each env's shown disc down, the other up), then push the poses to PhysX.
        saved_mask = self.scene._reset_mask.clone()
        self.scene._reset_mask[:] = True
        first_z = torch.where(self.switched, HIDDEN_Z, TARGET_Z)
        second_z = torch.where(self.switched, TARGET_Z, HIDDEN_Z)
        for disc, z in ((self.first, first_z), (self.second, second_z)):
            disc.set_pose(flat_poses(self.xy, z))
        self.scene._reset_mask[:] = saved_mask
        self.scene.px.gpu_apply_rigid_dynamic_data()

