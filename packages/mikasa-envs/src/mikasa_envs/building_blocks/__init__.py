"""Scene pieces shared by the task families: cubes, the shape library, object sets."""

from mikasa_envs.building_blocks.cubes import (
    COLOR_PALETTE_9,
    COLOR_PALETTE_RGB,
    CUBE_HALF_SIZE,
    build_colored_cube,
    rgba01,
)
from mikasa_envs.building_blocks.object_sets import (
    ObjectSet,
    blue_shapes,
    palette_cubes,
    shape_color_objects,
)
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
