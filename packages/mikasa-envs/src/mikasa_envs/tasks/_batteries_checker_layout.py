"""Fixed layout of the BatteriesChecker scene (``_batteries_checker.py``): the +90° yaw of
its fixtures, the tray's slot offsets, the grasp-test thresholds and a material helper.
"""

from __future__ import annotations

import numpy as np
import sapien

from mikasa_envs.building_blocks.cubes import rgba01

# +90° about z: the tray, socket, lamp and button are all turned by it.
YAW_90_QUAT = (float(np.cos(np.pi / 4)), 0.0, 0.0, float(np.sin(np.pi / 4)))
# ManiSkill's Panda grasp test: at least this force on each finger, within this angle of its
# opening direction. Batteries farther than the radius from the TCP cannot touch both fingers.
GRASP_MIN_FORCE = 0.5
GRASP_MAX_ANGLE_DEG = 85.0
GRASP_CANDIDATE_RADIUS = 0.12


def flat_material(rgba: tuple[int, ...]) -> sapien.render.RenderMaterial:
    """A plain render material of colour ``rgba`` (0-255)."""
    return sapien.render.RenderMaterial(base_color=list(rgba01(rgba)))


def slot_offsets(num_slots: int = 15) -> np.ndarray:
    """(num_slots, 2) slot xy relative to the tray centre (§3.1): row r = i // 3, column c = i % 3,
    x = 0.05 − 0.05·c, y = −0.104 + 0.052·r."""
    i = np.arange(num_slots)
    rows, cols = i // 3, i % 3
    return np.stack([0.05 - 0.05 * cols, -0.104 + 0.052 * rows], axis=1)
