"""The shell games' fixed layout (``_shell_game_shared.md``), shared by ``_shell_game.py``.

Slot and mug names, the mugs' orientations, the visual-only balls, the shuffle's swap
schedule and the colour-lamp families' bulb and ball colour tables.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.utils.building import actors as actor_builders
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z

NUM_SLOTS = 3
MUG_NAMES = ("mug_left", "mug_center", "mug_right")
SLOT_NAMES = ("Left", "Center", "Right")
# The shuffle's draws (``ScriptedShellGameVLABaseEnv``), which only the families with a
# shuffle hold: their TASK_STATE.
SHUFFLE_TASK_STATE = ("shuffle_steps_per_env", "num_swaps_per_env", "steps_per_swap_per_env", "swap_pairs", "slot_of_mug")


def normalized_quat(wxyz: Sequence[float]) -> tuple[float, float, float, float]:
    """``wxyz`` scaled to unit length."""
    q = np.asarray(wxyz, dtype=np.float64)
    return tuple(float(v) for v in q / np.linalg.norm(q))  # type: ignore[return-value]


# Upside down, handle toward world (0.6, 0.8, 0): the reference's (0, 1, 0.5, 0), normalised.
MUG_QUAT_HANDLE_AWAY = normalized_quat((0.0, 1.0, 0.5, 0.0))
# Upside down, handle toward world (−0.724, 0.690, 0), i.e. toward the robot (Pick).
MUG_QUAT_HANDLE_TOWARD_ROBOT = normalized_quat((0.0, 1.0, 2.5, 0.0))


def build_ball(scene: Any, name: str, rgba255: Sequence[int], radius: float) -> Actor:
    """A visual-only kinematic sphere (no collision), parked out of sight (shared §4, recommended)."""
    return actor_builders.build_sphere(
        scene,
        radius=radius,
        color=list(rgba01(rgba255)),
        name=name,
        body_type="kinematic",
        add_collision=False,
        initial_pose=sapien.Pose(p=[0, 0, HIDE_OFFSET_Z]),
    )


def swap_schedule(pairs: torch.Tensor, num_swaps: torch.Tensor) -> torch.Tensor:
    """(b, N_max + 1, 3) slot of each mug after i swaps; rows beyond N repeat row N.

    ``pairs`` (b, N_max, 2) are slot pairs: swap i exchanges the two mugs standing in them.
    """
    b, n_max, _ = pairs.shape
    current = torch.arange(NUM_SLOTS, device=pairs.device).repeat(b, 1)
    schedule = [current]
    for i in range(n_max):
        a, c = pairs[:, i, 0:1], pairs[:, i, 1:2]
        swapped = torch.where(current == a, c, torch.where(current == c, a, current))
        current = torch.where((i < num_swaps)[:, None], swapped, current)
        schedule.append(current)
    return torch.stack(schedule, dim=1)


# -------------------------------------------------------------------- colour lamp
LAMP_BULBS: dict[str, tuple[tuple[int, int, int], float]] = {
    "white": ((255, 255, 255), 0.0),
    "red": ((255, 0, 0), 2.0),
    "green": ((0, 255, 0), 2.0),
    "blue": ((0, 0, 255), 2.0),
}
BALL_COLORS: dict[str, tuple[int, int, int, int]] = {
    "ball_red": (255, 0, 0, 255),
    "ball_green": (0, 255, 0, 255),
    "ball_blue": (0, 0, 255, 255),
}
