"""Oracle for BatteriesCheckerEasy / BatteriesCheckerHard (``oracles_motion_planning.md`` §7.3).

For every active battery in index order: pick it from its slot, drop it into the socket,
read the lamp (which bulb is shown, as a camera would see it) to learn whether it works,
(Hard) take it out again and stand it back in its slot, then press the button. Success
needs every battery cycled, working or not, so the lamp reading is only remembered
(``working_seen``), not needed to act.

The script is a generator of actions; before each sub-task it looks at the env's stage
machine (privileged state, not the answer) and the batteries' poses, so a failed grasp or
a battery that missed its target is simply tried again.

Grasping: the gripper is turned 45° about the vertical so its fingers close along a diagonal
of the slot grid, away from the neighbouring batteries.

Reach: the socket lies 0.73-0.81 m from the robot's base axis, at the edge of what a
straight-down gripper reaches. There the gripper leans forward a little (at most ~11°, so
a held battery still rights itself when dropped), and a move whose next step asks for an
unreachable pose (ManiSkill's IK then leaves the arm where it is) retries with shorter steps.
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Iterator
from typing import Any

import numpy as np
from transforms3d.quaternions import qmult, quat2mat

from mikasa_oracles.controller import hold, move_towards, tilted
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

Actions = Generator[np.ndarray, None, bool]

# Hidden objects are parked at z = 1000; a bulb below this height is the one shown.
VISIBLE_BELOW_Z = 1.0
ROBOT_BASE_XY = np.array([-0.615, 0.0])
TRAVEL_Z = 0.20
APPROACH_ABOVE = 0.10  # over a target, before the last straight descent
BUTTON_APPROACH_Z = 0.15
# Gripper commands (+1 open, −1 closed): narrow pre-opening between neighbours in the tray,
# wider around a battery in the socket, and to let go over a slot.
GRIP_CLOSED = -1.0
PREOPEN_TRAY = 0.1
PREOPEN_SOCKET = 0.22
OPEN_RELEASE = 0.28
GRIP_OPEN = 1.0
# Where the battery's bottom goes: 4.5 mm above the socket's floor plate (top z 0.0105, so
# 1.5 cm inside the 3 cm deep hole), 4 mm above the table over its slot.
INSERT_BOTTOM_Z = 0.015
PLACE_BOTTOM_Z = 0.004
# Extraction: the TCP a little above the battery centre keeps the fingertips over the walls.
EXTRACT_ABOVE_CENTRE = 0.004
# Button: TCP down to this height (a press registers at ≤ 0.0831; the cap top is 0.058).
PRESS_Z = 0.07
LIFTED_BY = 0.02  # a battery this far above its start height is held
# Lean the gripper forward by TILT_PER_M per metre of target distance from the base axis
# beyond TILT_FROM, at most MAX_TILT (rad).
TILT_FROM = 0.74
TILT_PER_M = 4.0
MAX_TILT = 0.2
# The fingers close along a diagonal of the slot grid: the nearest batteries that way are
# 7.2 cm off, against 5.0-5.2 cm along the rows and columns, where the wide upper part of a
# finger can catch a neighbour's top.
GRIPPER_YAW = np.pi / 4
# Releasing: keep the hand still until each finger is this far from the hand's centre line
# (6 mm clear of a 1 cm battery; at least RELEASE_MIN_STEPS, at most RELEASE_MAX_STEPS),
# then rise the first RELEASE_BACKOFF slowly.
RELEASED_FINGER_OPENING = 0.016
RELEASE_MIN_STEPS = 2
RELEASE_MAX_STEPS = 10
RELEASE_BACKOFF = 0.03
RELEASE_BACKOFF_GAIN = 0.5
# A step that moved the TCP less than this while far from the goal counts as a stall.
STALL_DISTANCE = 0.001
STALL_CHECK_FROM = 0.02


def finger_target(gripper: float) -> float:
    """Finger joint target (m) of a gripper command: −1 → −0.01, +1 → 0.04 (linear)."""
    return -0.01 + (gripper + 1.0) / 2.0 * 0.05


@register_oracle("batteries_checker_easy", "batteries_checker_hard")
class BatteriesCheckerOracle(ScriptedOracle):
    """Scripted solver of both BatteriesChecker families; ``num_envs == 1``."""


    def reset(self) -> None:
        """Forget the previous episode."""
        self.working_seen: set[int] = set()
        self.inserted: int | None = None
        self.yawed_orientation: np.ndarray | None = None  # quaternion (w, x, y, z)
        self._actions: Iterator[np.ndarray] | None = None
        self._tcp_now: np.ndarray | None = None
        self._poses_now: np.ndarray | None = None

    # ------------------------------------------------------------ reading state
    # The script runs inside forward(), between two env steps: read each pose once per step.
    def _tcp(self) -> np.ndarray:
        if self._tcp_now is None:
            self._tcp_now = self.base.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        return self._tcp_now

    def _battery_pose(self, k: int) -> np.ndarray:
        if self._poses_now is None:
            self._poses_now = self.base.battery_raw_poses()[0].cpu().numpy().astype(np.float64)
        return self._poses_now[k]

    def _centre(self, k: int) -> np.ndarray:
        return self._battery_pose(k)[:3]

    def _bottom(self, k: int) -> np.ndarray:
        """The centre of battery k's lower end (the cylinder runs along its local x axis)."""
        pose = self._battery_pose(k)
        axis = quat2mat(pose[3:])[:, 0]
        if axis[2] > 0:
            axis = -axis
        return pose[:3] + self.base.BATTERY_HALF_HEIGHT * axis

    def _lamp_on(self) -> bool:
        """Whether the yellow bulb is on the lamp, from where the bulbs are (what a camera sees)."""
        lamp = self.base.lamp
        on_bulb = lamp.bulbs[lamp.bulb_index("on")]
        return float(on_bulb.pose.p[0, 2]) < VISIBLE_BELOW_Z

    # ------------------------------------------------------------------ policy
    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        self._tcp_now = self._poses_now = None
        if self.yawed_orientation is None:
            yaw = np.array([np.cos(GRIPPER_YAW / 2), 0.0, 0.0, np.sin(GRIPPER_YAW / 2)])
            self.yawed_orientation = qmult(yaw, self._tcp()[3:])
        # The lamp answers for the battery last dropped into the socket.
        if self.inserted is not None and self._lamp_on():
            self.working_seen.add(self.inserted)
        if self._actions is None:
            self._actions = self._script()
        return next(self._actions)

    def _script(self) -> Iterator[np.ndarray]:
        base = self.base
        while True:
            stage = int(base.action_stage[0])
            if stage == base.STAGE_RETURN:
                yield from self._return_battery(int(base.active_battery_idx[0]))
            elif stage == base.STAGE_CONFIRM:
                yield from self._press_button()
            else:
                k = self._next_battery()
                if k is None:
                    yield hold(GRIP_CLOSED)
                    continue
                if (yield from self._pick(k, PREOPEN_TRAY)):
                    yield from self._insert(k)

    def _next_battery(self) -> int | None:
        """The battery to check next: the first unchecked one (None when all are)."""
        base = self.base
        unchecked = np.flatnonzero(~base.checked_mask[0, : base.active_battery_count].cpu().numpy())
        return int(unchecked[0]) if len(unchecked) else None

    # -------------------------------------------------------------- primitives
    def _orientation(self, xy: np.ndarray) -> np.ndarray:
        """Straight down, turned by GRIPPER_YAW, leaning forward near the edge of the reach."""
        distance = float(np.linalg.norm(xy - ROBOT_BASE_XY))
        tilt = float(np.clip(TILT_PER_M * (distance - TILT_FROM), 0.0, MAX_TILT))
        return tilted(self.yawed_orientation, tilt)

    def _move(
        self,
        goal: np.ndarray,
        gripper: float,
        tol: float,
        max_steps: int,
        point: Callable[[], np.ndarray] | None = None,
        gain: float | None = None,
    ) -> Actions:
        """Bring ``point`` (default the TCP) to ``goal``; True once within ``tol``.

        A stalled step (the IK found no pose for the full step) halves the next step.
        """
        point = point or (lambda: self._tcp()[:3])
        rotation = self._orientation(goal[:2])
        scale, last = 1.0, None
        for _ in range(max_steps):
            tcp = self._tcp()
            error = goal - point()
            if np.linalg.norm(error) < tol:
                return True
            far = np.linalg.norm(error) > STALL_CHECK_FROM
            if far and last is not None and np.linalg.norm(tcp[:3] - last) < STALL_DISTANCE:
                scale = max(scale / 2, 0.1)
            elif last is not None:
                scale = min(scale * 2, 1.0)
            last = tcp[:3].copy()
            yield move_towards(tcp, tcp[:3] + error * scale, rotation, gain or self.gain, gripper)
        return False

    def _hold_at(self, goal: np.ndarray, gripper: float, steps: int) -> Actions:
        """Keep commanding the TCP to ``goal`` for ``steps`` steps (e.g. while the fingers move)."""
        rotation = self._orientation(goal[:2])
        for _ in range(steps):
            yield move_towards(self._tcp(), goal, rotation, self.gain, gripper)
        return True

    def _travel(self, xy: np.ndarray, z: float, gripper: float, point: Callable[[], np.ndarray] | None = None) -> Actions:
        """Rise to the travel height, cross over to ``xy`` there, descend to ``z`` (for ``point``)."""
        point = point or (lambda: self._tcp()[:3])
        here = point()
        if here[2] < TRAVEL_Z - 0.03 and np.linalg.norm(xy - here[:2]) > 0.01:
            yield from self._move(np.array([here[0], here[1], TRAVEL_Z]), gripper, 0.02, 40, point)
        yield from self._move(np.array([xy[0], xy[1], max(z, TRAVEL_Z)]), gripper, 0.015, 60, point)
        return (yield from self._move(np.array([xy[0], xy[1], z]), gripper, 0.01, 40, point))

    def _release(self, gripper: float) -> Actions:
        """Open the hand where it is, wait until the fingers have let go, then back off
        slowly upwards (a finger still touching the battery must not drag it along)."""
        here = self._tcp()[:3].copy()
        opening = min(RELEASED_FINGER_OPENING, 0.9 * finger_target(gripper))
        for step in range(RELEASE_MAX_STEPS):
            fingers = self.base.agent.robot.get_qpos()[0, 7:9].cpu().numpy()
            if step >= RELEASE_MIN_STEPS and fingers.min() >= opening:
                break
            yield move_towards(self._tcp(), here, self._orientation(here[:2]), self.gain, gripper)
        yield from self._move(here + np.array([0.0, 0.0, RELEASE_BACKOFF]), gripper, 0.01, 15, gain=RELEASE_BACKOFF_GAIN)
        return (yield from self._lift(gripper))

    def _lift(self, gripper: float) -> Actions:
        tcp = self._tcp()
        return (yield from self._move(np.array([tcp[0], tcp[1], TRAVEL_Z]), gripper, 0.02, 40))

    def _pick(self, k: int, preopen: float, above_centre: float = 0.0) -> Actions:
        """Grasp battery k where it stands and lift it; True if it came up with the gripper."""
        start = self._centre(k).copy()
        yield from self._travel(start[:2], start[2] + APPROACH_ABOVE, preopen)
        grasp = start + np.array([0.0, 0.0, above_centre])
        yield from self._move(grasp, preopen, 0.003, 30)
        yield from self._hold_at(grasp, GRIP_CLOSED, 5)
        yield from self._lift(GRIP_CLOSED)
        if self._centre(k)[2] > start[2] + LIFTED_BY:
            return True
        yield from self._hold_at(self._tcp()[:3], preopen, 3)  # let go of whatever was caught
        return False

    def _lower_onto(self, k: int, xy: np.ndarray, bottom_z: float) -> Actions:
        """Carry held battery k until its lower end is at (xy, bottom_z)."""
        def bottom() -> np.ndarray:
            return self._bottom(k)

        yield from self._travel(xy, bottom_z + APPROACH_ABOVE, GRIP_CLOSED, bottom)
        return (yield from self._move(np.array([xy[0], xy[1], bottom_z]), GRIP_CLOSED, 0.003, 40, bottom))

    def _insert(self, k: int) -> Actions:
        """Drop held battery k into the socket and back off; the stage machine takes it from there."""
        socket = self.base.socket_slot_pos[0].cpu().numpy().astype(np.float64)
        yield from self._lower_onto(k, socket[:2], INSERT_BOTTOM_Z)
        self.inserted = k
        yield from self._release(GRIP_OPEN)

    def _return_battery(self, k: int) -> Actions:
        """Hard: take battery k out of the socket (or wherever it is) and stand it in its slot."""
        if not (yield from self._pick(k, PREOPEN_SOCKET, EXTRACT_ABOVE_CENTRE)):
            return False
        home = self.base.tray_slot_positions[0, k].cpu().numpy().astype(np.float64)
        yield from self._lower_onto(k, home[:2], PLACE_BOTTOM_Z)
        yield from self._release(OPEN_RELEASE)
        return True

    def _press_button(self) -> Actions:
        """Press the button once (down to PRESS_Z) and rise above the re-arm height."""
        button = self.base.button_xy[0].cpu().numpy().astype(np.float64)
        yield from self._travel(button, BUTTON_APPROACH_Z, GRIP_CLOSED)
        press = np.array([button[0], button[1], PRESS_Z])
        yield from self._move(press, GRIP_CLOSED, 0.004, 20)
        yield from self._hold_at(press, GRIP_CLOSED, 1)
        yield from self._move(np.array([button[0], button[1], BUTTON_APPROACH_Z]), GRIP_CLOSED, 0.02, 30)
        self.inserted = None
        return True


@register_oracle("batteries_checker_easy", "batteries_checker_hard", memoryless=True)
class MemorylessBatteriesCheckerOracle(Memoryless, BatteriesCheckerOracle):
    """The BatteriesChecker oracle without memory: the lamp readings (``working_seen``) are
    wiped every step, and it never reads the checklist (``checked_mask``, which no camera
    shows: a checked battery stands in its slot like an unchecked one).

    Each check cycle (pick, insert, Hard: return, press) takes a battery drawn uniformly
    from the active ones, a fresh draw per cycle from the episode's stream (the view before
    every cycle is the same, so a stable guess would check one battery forever); the
    episode succeeds once every battery has come up. Chance (`mikasa_bench.results.chance`): the
    probability that the cycles fitting in the horizon draw every battery. Kept: the
    motor program within a cycle and the env's stage machine (its feedback on the last
    insert, return or press), neither of which says which batteries are done.
    """

    def forget(self) -> None:
        """Wipe the lamp readings."""
        self.working_seen = set()

    def _next_battery(self) -> int | None:
        return int(self.draws.integers(int(self.base.active_battery_count)))
