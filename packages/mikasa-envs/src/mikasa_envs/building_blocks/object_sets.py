"""The candidate-object sets of the selection tasks, built in key order.

Each builder returns an ``ObjectSet``: the actors, a per-key description the overlays read,
and each object's rest pose (origin height above the table and orientation, at x = y = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.cubes import (
    COLOR_PALETTE_9,
    COLOR_PALETTE_RGB,
    CUBE_HALF_SIZE,
    build_colored_cube,
    rgba01,
)
from mikasa_envs.building_blocks.shapes import (
    SHAPE_AND_COLOR_SHAPES,
    SHAPE_NAMES,
    SHAPE_REST_Z,
    build_task_shape,
    shape_orientation,
)

# Every RememberShape / FindImposterShape object is pure blue.
SHAPE_TASK_COLOR = rgba01((0, 0, 255, 255))


@dataclass
class ObjectSet:
    """Actors in key order, a per-key description and (N, 7) rest poses [x, y, z, qw, qx, qy, qz]."""

    actors: list[Actor]
    descriptions: dict[int, Any]
    rest_poses: np.ndarray


def _rest_pose(z: float, quat: list[float] | tuple[float, ...] = (1, 0, 0, 0)) -> list[float]:
    return [0.0, 0.0, z, *quat]


def palette_cubes(scene: ManiSkillScene, n: int) -> ObjectSet:
    """Cubes ``cube_k`` in the first n colours of the 9-colour palette; descriptions = RGBA."""
    colors = {k: rgba01(rgba) for k, (_, rgba) in enumerate(COLOR_PALETTE_9[:n])}
    actors = [build_colored_cube(scene, colors[k], f"cube_{k}") for k in range(n)]
    rest = np.array([_rest_pose(CUBE_HALF_SIZE)] * n)
    return ObjectSet(actors, colors, rest)


def blue_shapes(scene: ManiSkillScene, n: int) -> ObjectSet:
    """The first n task shapes, all blue, named ``<shape>_k``; descriptions = shape names."""
    names = {k: SHAPE_NAMES[k] for k in range(n)}
    actors = [build_task_shape(scene, names[k], SHAPE_TASK_COLOR, f"{names[k]}_{k}") for k in range(n)]
    rest = np.array([_rest_pose(SHAPE_REST_Z[names[k]], shape_orientation(names[k])) for k in range(n)])
    return ObjectSet(actors, names, rest)


def shape_color_objects(scene: ManiSkillScene, n: int) -> ObjectSet:
    """Objects i = 3·shape_id + color_id (shapes outer, red/green/blue inner), i < n.

    Descriptions: {"shape", "color", "shape_id", "color_id"} per index.
    """
    descriptions, actors, rest = {}, [], []
    for i in range(n):
        shape_id, color_id = divmod(i, len(COLOR_PALETTE_RGB))
        shape = SHAPE_AND_COLOR_SHAPES[shape_id]
        color = rgba01(COLOR_PALETTE_RGB[color_id][1])
        descriptions[i] = dict(shape=shape, color=color, shape_id=shape_id, color_id=color_id)
        actors.append(build_task_shape(scene, shape, color, f"{shape}_{i}"))
        rest.append(_rest_pose(SHAPE_REST_Z[shape], shape_orientation(shape)))
    return ObjectSet(actors, descriptions, np.array(rest))
