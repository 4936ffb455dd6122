"""Oracle for TimedTransfer (``oracles_motion_planning.md`` §6.2).

The oracle watches the lamp as a camera would (which bulb stands at the lamp) and notes the
step it first shows green; the delay D is the number in the instruction. It grasps the
cube, hovers it above the red disc and descends so that the cube enters the "on red" zone
at the centre of the window, signal + D; success ends the episode there.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle
from mikasa_oracles.waypoints import GRIPPER_CLOSED, Waypoint, WaypointFollower, shown_bulb


@register_oracle("timed_transfer")
class TimedTransferOracle(ScriptedOracle):
    """Scripted solver of TimedTransfer; one instance per env, ``num_envs == 1``."""

    # TCP heights: above the cube before descending, carrying, hovering over the red disc
    # (cube centre ≈ 0.10, clear of the 0.066 "on red" limit) and the placement target.
    APPROACH_Z = 0.12
    CARRY_Z = 0.14
    HOVER_Z = 0.10
    PLACE_Z = 0.03
    CLOSE_STEPS = 5
    # The descent from HOVER_Z takes this many steps to bring the cube below 0.066.
    DESCENT_STEPS = 2

    def __init__(self, env: gym.Env, gain: float | None = None) -> None:
        self.follower = WaypointFollower(self.GAIN if gain is None else gain)
        super().__init__(env, gain)

    def reset(self) -> None:
        """Forget the previous episode."""
        self.follower.reset()
        self.signal_seen_at: int | None = None
        self.planned = False

    def _release_step(self) -> int | None:
        if self.signal_seen_at is None:
            return None
        # D is the number in the instruction; aim at the window's centre, signal + D.
        return self.signal_seen_at + int(self.base.DELAY_STEPS) - self.DESCENT_STEPS

    def _time_to_descend(self) -> bool:
        """Whether to leave the hover point now (asked once per step while hovering)."""
        release = self._release_step()
        return release is not None and int(self.base.elapsed_steps[0]) >= release

    def _plan(self) -> None:
        base = self.base
        cube = base.cube_position()[0].cpu().numpy().astype(np.float64)
        red = base.red_disc_center[0].cpu().numpy().astype(np.float64)
        above_cube = np.array([cube[0], cube[1], self.APPROACH_Z])
        at_cube = cube.copy()

        self.follower.add(
            Waypoint(above_cube, 1.0, tol=0.01, max_steps=40),
            Waypoint(at_cube, 1.0, tol=0.004, max_steps=30),
            Waypoint(at_cube, GRIPPER_CLOSED, tol=1.0, min_steps=self.CLOSE_STEPS),
            Waypoint(np.array([cube[0], cube[1], self.CARRY_Z]), GRIPPER_CLOSED, tol=0.02, max_steps=30),
            Waypoint(np.array([red[0], red[1], self.CARRY_Z]), GRIPPER_CLOSED, tol=0.01, max_steps=40),
            # Hover until two steps before signal + D (no step cap: the wait may be 1000 steps).
            Waypoint(np.array([red[0], red[1], self.HOVER_Z]), GRIPPER_CLOSED, tol=1.0, max_steps=10**9, until=self._time_to_descend),
            Waypoint(np.array([red[0], red[1], self.PLACE_Z]), GRIPPER_CLOSED, tol=0.0, max_steps=10**9),
        )

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        if self.signal_seen_at is None and shown_bulb(base.lamp) == "green":
            self.signal_seen_at = int(base.elapsed_steps[0])
        if not self.planned:
            self._plan()
            self.planned = True
        tcp_pose = base.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        return self.follower.action(tcp_pose)


@register_oracle("timed_transfer", memoryless=True)
class MemorylessTimedTransferOracle(Memoryless, TimedTransferOracle):
    """The TimedTransfer oracle without memory: the step the lamp turned green is wiped
    every step, and it reads no clock (the step count is exactly what the task asks to
    remember; the lamp stays green, so no frame shows how long ago it turned).

    It carries the cube over the red disc as usual; while hovering there it descends with
    probability ``1 / DELAY_STEPS`` at each step (a fresh draw from the episode's stream),
    the only timing a policy without a clock has. Chance (`mikasa_bench.results.chance`): the
    window's share of the steps up to its end, an upper bound on such a constant-hazard
    descent. Kept: the waypoint queue (motion).
    """

    def forget(self) -> None:
        """Wipe the signal time."""
        self.signal_seen_at = None

    def _time_to_descend(self) -> bool:
        green = shown_bulb(self.base.lamp) == "green"
        return green and bool(self.draws.random() < 1.0 / float(self.base.DELAY_STEPS))
