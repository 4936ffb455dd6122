"""Oracle for TakeItBack: push the cube onto the target, then push it back to where it started.

The start spot is never shown to the cameras, but the cube stands on it at reset: the
oracle remembers the cube's position in the first frame and never reads the start marker
(``oracle_info``). It reads the cube pose, the target position and the goal status (the
target's colour change) from the privileged state.

Both pushes use the closed fingertips as a paddle, their broad face turned square to the
push: hover behind the cube (seen from where it must go), descend, and push through it
towards the destination, re-aiming every step; near the target the push slows down so the
cube stops just inside the disc (the nearer it stays, the easier the way back). The return
push starts from beyond the cube, at the far edge of the Panda's reach; the hand leans
forward there (a straight-down hand cannot reach past x ≈ 0.19 at table height) and takes
small steps (a large one makes the per-step IK fail: the arm does not move at all).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from transforms3d.euler import euler2mat

from mikasa_oracles.controller import hold, move_towards, tilted
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

GRIPPER_CLOSED = -1.0
DOWN = np.array([0.0, 1.0, 0.0, 0.0])  # TCP orientation (w, x, y, z) pointing straight down
# Fingertip paddle: TCP height while pushing (cube centre 0.02), and distance from the cube
# centre to the TCP at contact (half the cube + half the closed fingertips' depth).
PUSH_Z = 0.02
CONTACT = 0.02 + 0.009
# Hover height to pass over the cube (top at 0.04, fingertips ~1 cm below the TCP).
HOVER_Z = 0.07
# Set-down point this far behind the contact point; descend when within XY_TOL of it.
APPROACH_GAP = 0.015
XY_TOL = 0.012
LOW_ENOUGH = 0.03
# Push speed (m per step) and how far into the cube the paddle aims.
PUSH_STEP = 0.025
MIN_PUSH_STEP = 0.008
PUSH_SLOWDOWN = 0.4
PUSH_DEPTH = 0.004
# The paddle has lost the cube when this far off the push line (it goes round again).
LOST_LATERAL = 0.03
# Forward lean of the hand per metre of TCP x beyond TILT_FROM_X, capped (reach, see above).
TILT_FROM_X = 0.08
TILT_PER_M = 5.0
MAX_TILT = 0.6
# Beyond this x, translation actions are capped at FAR_MAX_STEP (0.1 m per unit).
FAR_X = 0.1
FAR_MAX_STEP = 0.5
# Largest turn of the hand about the vertical (the pushes run within ~35° of ±x).
MAX_YAW = 0.6
# The return push ends this close to the start spot (success needs < 0.08).
RETURN_STOP = 0.02


@register_oracle("take_it_back")
class TakeItBackOracle(ScriptedOracle):
    """Scripted solver of TakeItBack; one instance per env, ``num_envs == 1``."""

    GAIN = 1.5

    def reset(self) -> None:
        """Forget the previous episode."""
        self.start_xy: np.ndarray | None = None
        self.pushing = False  # in contact phase of the current push
        self.stage = "to_goal"

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        tcp = base.agent.tcp.pose.raw_pose[0].cpu().numpy()
        cube = base.cube_position()[0].cpu().numpy()
        if self.start_xy is None:
            # What the cameras showed at reset: the cube standing on its start spot.
            self.start_xy = cube[:2].copy()
        if self.stage == "to_goal" and bool(base.goal_reached_status[0]):
            self.stage, self.pushing = "back", False
        if self.stage == "to_goal":
            destination = base.goal_pos[0, :2].cpu().numpy()
            # Creep over the edge of the target disc: the cube slides on when the paddle stops.
            self.push_stop = base.GOAL_RADIUS - 0.01
        else:
            self.push_stop = 0.0
            destination = self.start_xy
            if np.linalg.norm(cube[:2] - destination) < RETURN_STOP:
                return hold(GRIPPER_CLOSED)
        return self._push(tcp, cube, destination)

    def _push(self, tcp: np.ndarray, cube: np.ndarray, destination: np.ndarray) -> np.ndarray:
        """Push the cube towards ``destination`` (xy) with the fingertips."""
        direction = destination - cube[:2]
        remaining = float(np.linalg.norm(direction))
        direction /= max(remaining, 1e-6)
        contact_xy = cube[:2] - direction * CONTACT
        behind = np.dot(tcp[:2] - cube[:2], direction) < -CONTACT + 0.01
        lateral = np.linalg.norm((tcp[:2] - contact_xy) - np.dot(tcp[:2] - contact_xy, direction) * direction)
        if self.pushing and not (behind and lateral < LOST_LATERAL and tcp[2] < LOW_ENOUGH):
            self.pushing = False  # lost the cube: go round again
        if self.pushing:
            # Slow down near the destination: the cube slides on once the paddle stops.
            step = float(np.clip(PUSH_SLOWDOWN * (remaining - self.push_stop), MIN_PUSH_STEP, PUSH_STEP))
            goal_xy = cube[:2] + direction * (step + PUSH_DEPTH - CONTACT)
            goal = np.array([*goal_xy, PUSH_Z])
        else:
            set_down = contact_xy - direction * APPROACH_GAP
            near = np.linalg.norm(tcp[:2] - set_down) < XY_TOL
            low = tcp[2] < LOW_ENOUGH
            if near and low:
                self.pushing = True
                goal = np.array([*contact_xy, PUSH_Z])
            elif near or (low and behind and lateral < XY_TOL):
                goal = np.array([*set_down, PUSH_Z])
            elif tcp[2] < HOVER_Z - 0.015:
                goal = np.array([*tcp[:2], HOVER_Z])  # straight up first, then across
            else:
                goal = np.array([*set_down, HOVER_Z])
        tilt = float(np.clip(TILT_PER_M * (max(goal[0], tcp[0]) - TILT_FROM_X), 0.0, MAX_TILT))
        # Turn the fingertips' broad face (normal: the hand's x axis) square to the push.
        yaw = float(np.clip(np.arctan2(direction[1], abs(direction[0])) * np.sign(direction[0]), -MAX_YAW, MAX_YAW))
        rotation = euler2mat(0.0, 0.0, yaw) @ tilted(DOWN, tilt)
        action = move_towards(tcp, goal, rotation, self.gain, GRIPPER_CLOSED)
        if max(goal[0], tcp[0]) > FAR_X:
            # Near the edge of the reach a large step makes the per-step IK fail (no motion).
            action[:3] *= min(1.0, FAR_MAX_STEP / max(np.linalg.norm(action[:3]), 1e-6))
        return action


@register_oracle("take_it_back", memoryless=True)
class MemorylessTakeItBackOracle(Memoryless, TakeItBackOracle):
    """The TakeItBack oracle without memory: the start spot (the cube's first-frame
    position) is wiped every step, and no frame after the first shows it.

    It pushes the cube onto the target as usual (the target is in view), and brings it back
    to a guessed start: the centre of one of the three start rows of the task's fixed
    layout (x ∈ [−0.05, 0.05), y = 0.1·j + [0, 0.05), j ∈ {−1, 0, 1}), the same row at
    every step. A row centre lies within the 0.08 success radius of every start in its row,
    so chance is about 1/3 (`mikasa_bench.results.chance` gives the exact figure). Kept: whether
    the paddle is in contact (motion); the stage follows the target's colour (in view).
    """

    def forget(self) -> None:
        """Wipe the start spot: the guessed row stands in for it."""
        base = self.base
        row = self.guess(3) - 1
        x_lo, x_hi = base.START_X
        self.start_xy = np.array([(x_lo + x_hi) / 2, base.START_Y_STEP * row + base.START_Y_JITTER / 2])
