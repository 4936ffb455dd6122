"""Flat discs lying on the table (GatherAndRecall's target disc, TimedTransfer's discs)."""

from __future__ import annotations

from collections.abc import Sequence

import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z, UPRIGHT_CYLINDER_QUAT


def build_disc(
    scene: ManiSkillScene,
    name: str,
    radius: float,
    half_height: float,
    rgba: Sequence[int],
    collision: bool = True,
    body_type: str = "kinematic",
) -> Actor:
    """An upright cylinder of ``radius`` and half height ``half_height``, colour RGBA 0-255.

    Placed by the task (``set_pose`` / ``write_actor_poses``); built parked out of sight.
    """
    builder = scene.create_actor_builder()
    pose = sapien.Pose(q=UPRIGHT_CYLINDER_QUAT)
    material = sapien.render.RenderMaterial(base_color=list(rgba01(rgba)))
    builder.add_cylinder_visual(pose=pose, radius=radius, half_length=half_height, material=material)
    if collision:
        builder.add_cylinder_collision(pose=pose, radius=radius, half_length=half_height)
    builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
    if body_type == "kinematic":
        return builder.build_kinematic(name=name)
    if body_type == "static":
        return builder.build_static(name=name)
    return builder.build(name=name)
