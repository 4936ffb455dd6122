"""Waypoint following for the pick-and-place oracles, and reading which lamp bulb is shown."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from transforms3d.quaternions import quat2mat

from mikasa_oracles.controller import hold, move_towards

GRIPPER_CLOSED = -1.0
# TCP orientation the oracles hold: pointing straight down, fingers closing along world y.
DOWNWARD = quat2mat([0.0, 1.0, 0.0, 0.0])
# Bulbs that are not shown are parked 1000 m above the lamp: a shown one is below this.
SHOWN_BELOW_Z = 1.0


@dataclass
class Waypoint:
    """Drive the TCP to ``goal`` with a fixed gripper command.

    Reached when within ``tol`` of the goal after at least ``min_steps`` steps (and
    ``until()``, if given, holds); abandoned after ``max_steps`` steps.
    """

    goal: np.ndarray
    gripper: float
    tol: float = 0.01
    max_steps: int = 40
    min_steps: int = 0
    until: Callable[[], bool] | None = None


class WaypointFollower:
    """Runs a queue of waypoints with a proportional ``pd_ee_delta_pose`` controller that also
    turns the gripper to (and holds it at) ``DOWNWARD`` (the hold term of §3)."""

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = gain
        self.queue: list[Waypoint] = []
        self.steps_on_current = 0

    def reset(self) -> None:
        """Drop every waypoint."""
        self.queue.clear()
        self.steps_on_current = 0

    def add(self, *waypoints: Waypoint) -> None:
        """Append waypoints to the queue."""
        self.queue.extend(waypoints)

    @property
    def idle(self) -> bool:
        """Whether every waypoint has been reached (or abandoned)."""
        return not self.queue

    def action(self, tcp_pose: np.ndarray, idle_gripper: float = GRIPPER_CLOSED) -> np.ndarray:
        """The action towards the current waypoint; advances past reached ones first."""
        while self.queue:
            waypoint = self.queue[0]
            near = np.linalg.norm(waypoint.goal - tcp_pose[:3]) < waypoint.tol
            done = near and self.steps_on_current >= waypoint.min_steps
            if waypoint.until is not None:
                done = done and waypoint.until()
            if not (done or self.steps_on_current >= waypoint.max_steps):
                break
            self.queue.pop(0)
            self.steps_on_current = 0
        if not self.queue:
            return hold(idle_gripper)
        self.steps_on_current += 1
        waypoint = self.queue[0]
        return move_towards(tcp_pose, waypoint.goal, DOWNWARD, self.gain, waypoint.gripper)


def shown_bulb(lamp: Any) -> str | None:
    """The name of the bulb a camera sees at ``lamp`` (env 0), from the bulbs' positions."""
    for name, bulb in zip(lamp.bulb_names, lamp.bulbs, strict=True):
        if float(bulb.pose.p[0, 2]) < SHOWN_BELOW_Z:
            return name
    return None
