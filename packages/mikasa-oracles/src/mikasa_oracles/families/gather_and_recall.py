"""Oracle for GatherAndRecall (``oracles_motion_planning.md`` §10.2).

It carries the cubes one by one onto the disc and, meanwhile, watches the lamp as a camera
would (which bulb stands at the lamp), remembering the colour of the flash. When every cube
is on the disc it presses the button of that colour. Cube, disc and button positions are
read from the simulator; the flash colour is never read from the env's answer.

Placement spots keep every placed cube clear of the open fingers of the next placement: the
fingers close along world y and reach ≈ 5.4 cm from the TCP when opened to release a cube,
so cubes sharing a column (|Δx| < 5 cm) are 8 cm apart in y, columns 5 cm apart in x.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle
from mikasa_oracles.waypoints import (
    GRIPPER_CLOSED,
    Waypoint,
    WaypointFollower,
    shown_bulb,
)

# Spots on the disc, offsets from its centre: two inner columns of three, two outer of two.
DISC_SPOTS = np.array(
    [[x, y] for x in (-0.025, 0.025) for y in (0.0, -0.08, 0.08)] + [[x, y] for x in (-0.075, 0.075) for y in (-0.04, 0.04)]
)
SINGLE_CUBE_SPOT = np.zeros((1, 2))
ROBOT_BASE_XY = np.array([-0.615, 0.0])
# A cube counts as placed when its centre is this close (XY) to the disc centre (the task's
# limit is 0.10) and below this height.
PLACED_RADIUS = 0.095
PLACED_MAX_Z = 0.1
# Another cube this close (XY) to a spot occupies it.
SPOT_TAKEN_RADIUS = 0.035


@register_oracle("gather_and_recall")
class GatherAndRecallOracle(ScriptedOracle):
    """Scripted solver of GatherAndRecall; one instance per env, ``num_envs == 1``."""

    TRAVEL_Z = 0.15
    APPROACH_Z = 0.12
    GRASP_Z = 0.02  # TCP at the centre of a cube standing on the table
    RELEASE_Z = 0.03  # cube bottom ≈ 4 mm above the disc top
    PRESS_Z = 0.07  # presses below 0.0831; the fingertips stay above the lowered cap
    # Gripper opening to grasp / release: 2.75 cm per finger, 7.5 mm of play per side.
    GRIPPER_AJAR = 0.5
    CLOSE_STEPS = 5
    RELEASE_STEPS = 3

    def __init__(self, env: gym.Env, gain: float | None = None) -> None:
        self.follower = WaypointFollower(self.GAIN if gain is None else gain)
        super().__init__(env, gain)

    def reset(self) -> None:
        """Forget the previous episode."""
        self.follower.reset()
        self.flash_seen: int | None = None
        self.pressing = False

    # ------------------------------------------------------------ perception
    def _watch_lamp(self) -> None:
        if self.flash_seen is not None:
            return
        bulb = shown_bulb(self.base.lamp)
        if bulb not in (None, "off"):
            self.flash_seen = self.base.lamp.bulb_names.index(bulb) - 1  # bulb 0 is "off"

    def _cube_positions(self) -> np.ndarray:
        return self.base.cube_positions()[0].cpu().numpy().astype(np.float64)

    def _disc_xy(self) -> np.ndarray:
        return self.base.disc_xy[0].cpu().numpy().astype(np.float64)

    def _placed(self, positions: np.ndarray) -> np.ndarray:
        on_disc = np.linalg.norm(positions[:, :2] - self._disc_xy(), axis=1) < PLACED_RADIUS
        return on_disc & (positions[:, 2] < PLACED_MAX_Z)

    def _spots(self) -> np.ndarray:
        """World XY of the N spots nearest the robot (the far ones can be out of reach)."""
        n = len(self.base.cubes)
        spots = self._disc_xy() + (SINGLE_CUBE_SPOT if n == 1 else DISC_SPOTS)
        order = np.argsort(np.linalg.norm(spots - ROBOT_BASE_XY, axis=1), kind="stable")
        return spots[np.sort(order[:n])]

    def _free_spot(self, positions: np.ndarray, moving: int) -> np.ndarray | None:
        others = np.delete(positions, moving, axis=0)[:, :2]
        for spot in self._spots():
            if len(others) == 0 or np.linalg.norm(others - spot, axis=1).min() > SPOT_TAKEN_RADIUS:
                return spot
        return None

    # -------------------------------------------------------------- planning
    def _plan_transfer(self, cube: np.ndarray, spot: np.ndarray) -> None:
        x, y = cube[:2]
        sx, sy = spot
        ajar = self.GRIPPER_AJAR
        self.follower.add(
            Waypoint(np.array([x, y, self.APPROACH_Z]), ajar, tol=0.006, max_steps=60),
            Waypoint(np.array([x, y, self.GRASP_Z]), ajar, tol=0.004, max_steps=30),
            Waypoint(np.array([x, y, self.GRASP_Z]), GRIPPER_CLOSED, tol=1.0, min_steps=self.CLOSE_STEPS),
            Waypoint(np.array([x, y, self.TRAVEL_Z]), GRIPPER_CLOSED, tol=0.02, max_steps=30),
            Waypoint(np.array([sx, sy, self.TRAVEL_Z]), GRIPPER_CLOSED, tol=0.01, max_steps=60),
            Waypoint(np.array([sx, sy, self.RELEASE_Z]), GRIPPER_CLOSED, tol=0.004, max_steps=30),
            Waypoint(np.array([sx, sy, self.RELEASE_Z]), ajar, tol=1.0, min_steps=self.RELEASE_STEPS),
            Waypoint(np.array([sx, sy, self.TRAVEL_Z]), ajar, tol=0.02, max_steps=30),
        )

    def _plan_press(self) -> None:
        bx, by = self.base.buttons_xy[self.flash_seen, 0].cpu().numpy().astype(np.float64)
        self.follower.add(
            Waypoint(np.array([bx, by, self.TRAVEL_Z]), GRIPPER_CLOSED, tol=0.01, max_steps=60),
            Waypoint(np.array([bx, by, self.PRESS_Z]), GRIPPER_CLOSED, tol=0.004, max_steps=30),
            Waypoint(np.array([bx, by, self.TRAVEL_Z]), GRIPPER_CLOSED, tol=0.02, max_steps=30),
        )
        self.pressing = True

    def _plan_next(self) -> None:
        positions = self._cube_positions()
        placed = self._placed(positions)
        if not placed.all():
            moving = int(np.flatnonzero(~placed)[0])
            spot = self._free_spot(positions, moving)
            if spot is not None:
                self._plan_transfer(positions[moving], spot)
                return
        elif self.flash_seen is not None and not self.pressing:
            self._plan_press()

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        self._watch_lamp()
        if self.follower.idle:
            self._plan_next()
        tcp_pose = self.base.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        return self.follower.action(tcp_pose, idle_gripper=GRIPPER_CLOSED)


@register_oracle("gather_and_recall", memoryless=True)
class MemorylessGatherAndRecallOracle(Memoryless, GatherAndRecallOracle):
    """The GatherAndRecall oracle without memory: the flash colour is wiped every step.

    It gathers the cubes as usual. The button to press is decided anew at every step: the
    colour the lamp shows now if it is lit, else a guess among the three buttons (the same
    at every step); if that changes while it is on its way to press, it turns to the new
    button. Chance is 1/3. (In GatherAndRecall1 the flash starts as the only cube lands,
    so it may still be lit when the press is planned: that variant can beat chance.) Kept:
    the waypoint queue of the transfers (motion).
    """

    def reset(self, seed: int | None = None) -> None:
        """Start an episode; ``seed`` seeds the guess."""
        self.press_button: int | None = None
        super().reset(seed)

    def forget(self) -> None:
        """Wipe the flash colour."""
        self.flash_seen = None

    def _watch_lamp(self) -> None:
        super()._watch_lamp()  # the colour the lamp shows in this frame, if any
        if self.flash_seen is None:
            self.flash_seen = self.guess(len(self.base.buttons))
        if self.pressing and self.flash_seen != self.press_button:
            # Decided otherwise from this frame: drop the press on its way, press that one.
            self.follower.reset()
            self.pressing = False

    def _plan_press(self) -> None:
        self.press_button = self.flash_seen
        super()._plan_press()
