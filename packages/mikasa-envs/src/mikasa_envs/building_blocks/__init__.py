"""Scene pieces shared by the task families: cubes, shapes, object sets, lamps, buttons, discs."""

from mikasa_envs.building_blocks.buttons import Button, PressLatch, press_depth
from mikasa_envs.building_blocks.cubes import (
    COLOR_PALETTE_9,
    COLOR_PALETTE_RGB,
    CUBE_HALF_SIZE,
    build_colored_cube,
    rgba01,
)
from mikasa_envs.building_blocks.discs import build_disc
from mikasa_envs.building_blocks.lamps import ColorSwitchLamp
from mikasa_envs.building_blocks.object_sets import (
    ObjectSet,
    blue_shapes,
    palette_cubes,
    shape_color_objects,
)
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z, positions_to_poses, write_actor_poses
from mikasa_envs.building_blocks.shapes import (
    SHAPE_AND_COLOR_SHAPES,
    SHAPE_NAMES,
    SHAPE_REST_Z,
    SHAPE_SCALE,
    build_task_shape,
    set_actor_visual_rgba,
    shape_orientation,
)

__all__ = [
    "HIDE_OFFSET_Z",
    "Button",
    "ColorSwitchLamp",
    "PressLatch",
    "build_disc",
    "positions_to_poses",
    "press_depth",
    "write_actor_poses",
    "COLOR_PALETTE_9",
    "COLOR_PALETTE_RGB",
    "CUBE_HALF_SIZE",
    "SHAPE_AND_COLOR_SHAPES",
    "SHAPE_NAMES",
    "SHAPE_REST_Z",
    "SHAPE_SCALE",
    "ObjectSet",
    "blue_shapes",
    "build_colored_cube",
    "build_task_shape",
    "palette_cubes",
    "rgba01",
    "set_actor_visual_rgba",
    "shape_color_objects",
    "shape_orientation",
]
