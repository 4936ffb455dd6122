"""Cartesian helpers for driving the Panda with ``pd_ee_delta_pose`` actions."""

from __future__ import annotations

import numpy as np
from transforms3d.axangles import mat2axangle
from transforms3d.euler import euler2mat
from transforms3d.quaternions import quat2mat

# pd_ee_delta_pose maps a normalised translation of 1 to 0.1 m and a rotation of 1 to 0.1 rad.
EE_DELTA_POS_SCALE = 0.1
EE_DELTA_ROT_SCALE = 0.1
GRIPPER_OPEN = 1.0


def tilted(orientation_wxyz: np.ndarray, forward_tilt: float) -> np.ndarray:
    """Rotation matrix of ``orientation`` pitched so a down-pointing gripper leans towards +x."""
    return euler2mat(0.0, -forward_tilt, 0.0) @ quat2mat(orientation_wxyz)


def move_towards(
    tcp_pose: np.ndarray,
    goal: np.ndarray,
    goal_rotation: np.ndarray | None = None,
    gain: float = 1.0,
    gripper: float = GRIPPER_OPEN,
) -> np.ndarray:
    """A 7-D ``pd_ee_delta_pose`` action moving the TCP towards ``goal``.

    ``tcp_pose`` is [x, y, z, qw, qx, qy, qz] in the world (= robot root) frame. Position is
    proportional and saturates at ±1; the rotation (if a goal matrix is given) turns the TCP
    towards ``goal_rotation``. ManiSkill 3.0.1 scales rotation actions by ``rot_lower``
    (−0.1), so an action +r turns the TCP by −0.1·r rad about world (root-aligned) axes.
    """
    translation = np.clip(gain * (goal - tcp_pose[:3]) / EE_DELTA_POS_SCALE, -1.0, 1.0)
    rotation = np.zeros(3)
    if goal_rotation is not None:
        axis, angle = mat2axangle(goal_rotation @ quat2mat(tcp_pose[3:]).T)
        rotation = np.clip(-axis * angle / EE_DELTA_ROT_SCALE, -1.0, 1.0)
    return np.concatenate([translation, rotation, [gripper]]).astype(np.float32)


def hold(gripper: float = GRIPPER_OPEN) -> np.ndarray:
    """An action that keeps the arm where it is."""
    return np.concatenate([np.zeros(6), [gripper]]).astype(np.float32)
