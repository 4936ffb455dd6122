"""The shell games' coffee mug, built from primitives (``_shell_game_shared.md`` §2.2).

It replaces the YCB ``025_mug`` scaled by 1.3. Geometry is given in the *upright-mug model
frame*: open end toward +z, handle toward +x, origin at the bounding-box centre; the tasks
turn it upside down with the upstream quaternions, so world geometry and ``obj_pose``
quaternions match the reference. The wall is 16 thin tangential boxes (the cavity stays
open, so a ball fits under the inverted mug), the closed end a disc, the handle a "C" loop
of three boxes whose centre lies ``MUG_HANDLE_OFFSET`` from the origin along model +x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z, UPRIGHT_CYLINDER_QUAT

# Body: a vertical open cylinder whose axis is offset away from the handle so the
# bounding box is centred on the origin.
MUG_AXIS_X = -0.0156
MUG_OUTER_RADIUS = 0.0605
MUG_WALL_THICKNESS = 0.006
MUG_HEIGHT = 0.1053
MUG_WALL_SEGMENTS = 16
# Tangential width of a wall box: the polygon side 2·R·tan(π/16) plus a small overlap.
MUG_WALL_SEGMENT_WIDTH = 0.0245
MUG_BOTTOM_THICKNESS = 0.008
# Handle: two horizontal arms and a vertical grip bar, square 0.015 cross-section.
HANDLE_BAR_SIZE = 0.015
HANDLE_ARM_X_RANGE = (0.040, 0.076)
HANDLE_ARM_Z = 0.030
HANDLE_GRIP_X = 0.0685
HANDLE_GRIP_HALF_HEIGHT = 0.0375
# Centre of the handle loop (the grasp point), along model +x from the origin.
MUG_HANDLE_OFFSET = 0.062
# The YCB mug (0.118 kg) scaled by 1.3 in every dimension.
MUG_MASS = 0.25
MUG_RGBA = (150, 25, 25, 255)

BodyType = Literal["dynamic", "kinematic"]


@dataclass(frozen=True)
class MugPart:
    """One primitive of the mug in the model frame: a box (``size`` = half sizes) or a
    cylinder along its local x axis (``size`` = (radius, half length, 0))."""

    kind: Literal["box", "cylinder"]
    pose: sapien.Pose
    size: tuple[float, float, float]

    @property
    def volume(self) -> float:
        """Volume in m³ (overlaps between parts are counted twice, as PhysX does for mass)."""
        if self.kind == "box":
            return 8.0 * self.size[0] * self.size[1] * self.size[2]
        return math.pi * self.size[0] ** 2 * 2.0 * self.size[1]

    def vertices_z(self) -> np.ndarray:
        """z of the part's extreme points in the model frame (corners; the rim for a cylinder)."""
        if self.kind == "box":
            hx, hy, hz = self.size
            local = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        else:
            radius, half_length, _ = self.size
            angles = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
            rim = np.stack([np.zeros_like(angles), radius * np.cos(angles), radius * np.sin(angles)], axis=1)
            local = np.concatenate([rim + [half_length, 0, 0], rim - [half_length, 0, 0]])
        rotation = self.pose.to_transformation_matrix()[:3, :3]
        return (local @ rotation.T)[:, 2] + self.pose.p[2]


def mug_parts() -> list[MugPart]:
    """The mug's primitives in the upright model frame (collision and visual alike)."""
    parts: list[MugPart] = []
    half_height = MUG_HEIGHT / 2
    centre_radius = MUG_OUTER_RADIUS - MUG_WALL_THICKNESS / 2
    for i in range(MUG_WALL_SEGMENTS):
        angle = 2.0 * math.pi * i / MUG_WALL_SEGMENTS
        position = [MUG_AXIS_X + centre_radius * math.cos(angle), centre_radius * math.sin(angle), 0.0]
        yaw = [math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)]
        half_size = (MUG_WALL_THICKNESS / 2, MUG_WALL_SEGMENT_WIDTH / 2, half_height)
        parts.append(MugPart("box", sapien.Pose(p=position, q=yaw), half_size))
    bottom_z = -half_height + MUG_BOTTOM_THICKNESS / 2
    parts.append(
        MugPart(
            "cylinder",
            sapien.Pose(p=[MUG_AXIS_X, 0.0, bottom_z], q=UPRIGHT_CYLINDER_QUAT),
            (MUG_OUTER_RADIUS, MUG_BOTTOM_THICKNESS / 2, 0.0),
        )
    )
    half_bar = HANDLE_BAR_SIZE / 2
    arm_lo, arm_hi = HANDLE_ARM_X_RANGE
    for z in (HANDLE_ARM_Z, -HANDLE_ARM_Z):
        parts.append(
            MugPart("box", sapien.Pose(p=[(arm_lo + arm_hi) / 2, 0.0, z]), ((arm_hi - arm_lo) / 2, half_bar, half_bar))
        )
    parts.append(MugPart("box", sapien.Pose(p=[HANDLE_GRIP_X, 0.0, 0.0]), (half_bar, half_bar, HANDLE_GRIP_HALF_HEIGHT)))
    return parts


def mug_rest_height() -> float:
    """Height of the origin of a mug standing on the table: minus the lowest collision z of
    the model (the upstream rule; the mug is symmetric in z, so it holds upside down too)."""
    return -float(min(part.vertices_z().min() for part in mug_parts()))


def mug_density() -> float:
    """Density (kg/m³) that gives the mug ``MUG_MASS``."""
    return MUG_MASS / sum(part.volume for part in mug_parts())


def build_mug(
    scene: ManiSkillScene,
    name: str,
    body_type: BodyType = "dynamic",
    rgba: Sequence[int] = MUG_RGBA,
) -> Actor:
    """A mug actor (default physical material: friction 0.3, restitution 0), parked out of
    sight; the task places it (``set_pose`` / ``write_actor_poses``)."""
    builder = scene.create_actor_builder()
    material = sapien.render.RenderMaterial(base_color=list(rgba01(rgba)))
    density = mug_density()
    for part in mug_parts():
        if part.kind == "box":
            builder.add_box_collision(pose=part.pose, half_size=part.size, density=density)
            builder.add_box_visual(pose=part.pose, half_size=part.size, material=material)
        else:
            radius, half_length, _ = part.size
            builder.add_cylinder_collision(pose=part.pose, radius=radius, half_length=half_length, density=density)
            builder.add_cylinder_visual(pose=part.pose, radius=radius, half_length=half_length, material=material)
    builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
    if body_type == "kinematic":
        return builder.build_kinematic(name=name)
    return builder.build(name=name)
