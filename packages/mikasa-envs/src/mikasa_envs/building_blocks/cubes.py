"""Coloured cubes and the colour palettes the colour tasks share."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import sapien
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.building import actors
from mani_skill.utils.structs import Actor

CUBE_HALF_SIZE = 0.02

# The nine-colour palette of RememberColor / FindImposterColor, RGBA 0-255.
# Upstream labels key 7 "Olive" although it is orange; the label is kept for the overlay.
COLOR_PALETTE_9: tuple[tuple[str, tuple[int, int, int, int]], ...] = (
    ("Red", (255, 0, 0, 255)),
    ("Lime", (0, 255, 0, 255)),
    ("Blue", (0, 0, 255, 255)),
    ("Yellow", (255, 255, 0, 255)),
    ("Magenta", (255, 0, 255, 255)),
    ("Cyan", (0, 255, 255, 255)),
    ("Maroon", (128, 0, 0, 255)),
    ("Olive", (255, 128, 0, 255)),
    ("Teal", (0, 128, 128, 255)),
)
# The three colours of the ShapeAndColor families (red, green, blue).
COLOR_PALETTE_RGB: tuple[tuple[str, tuple[int, int, int, int]], ...] = COLOR_PALETTE_9[:3]


def rgba01(rgba255: Sequence[int]) -> np.ndarray:
    """RGBA 0-255 -> float RGBA in [0, 1]."""
    return np.asarray(rgba255, dtype=np.float64) / 255.0


def build_colored_cube(
    scene: ManiSkillScene,
    color: Sequence[float],
    name: str,
    half_size: float = CUBE_HALF_SIZE,
    initial_pose: sapien.Pose | None = None,
) -> Actor:
    """A dynamic cube of one colour (RGBA floats in [0, 1])."""
    return actors.build_cube(
        scene,
        half_size=half_size,
        color=list(color),
        name=name,
        body_type="dynamic",
        initial_pose=initial_pose or sapien.Pose(p=[0, 0, half_size]),
    )
