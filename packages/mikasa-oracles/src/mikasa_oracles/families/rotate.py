"""Oracles for the Rotate families (RotateLenient, RotateStrict).

Both read the target turn from ``task_cue`` (what the instruction states) and the peg's
pose from the simulator, but never the env's record of the start heading or the remaining
error (``initial_rotations`` / ``oracle_info``): at the first frame they note the peg's
heading, then add up how far it turns from one frame to the next (less than π per step), so
they know the turn so far even though the 180°-symmetric, single-coloured peg looks the
same at many headings. That tracked turn is the memory the task demands.

* RotateLenient (60 steps, position free): the hand's yaw turns at most ~0.04 rad per step
  under ``pd_ee_delta_pose`` (it targets the current pose + ≤ 0.1 rad and the joints cover
  ~40 % of that per step), so aligning the fingers with the peg and then twisting it can take
  up to ~80 steps. Pushing one end of the peg sideways with the closed fingers turns it
  ~0.1 rad per step instead (the peg also slides, which Lenient allows).
* RotateStrict (90 steps, centre within 5 cm): grasp the peg at its centre with the fingers
  across its width, lift it ~1 cm, turn the hand about the vertical through the centre, hold.
  Of the two finger alignments (the peg is symmetric under a half turn) it takes the one that
  needs less hand rotation and keeps Panda joint 7 within its limits through the twist
  (both fit for every target here; it regrasps if the joint still nears its limit).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from transforms3d.euler import euler2mat
from transforms3d.quaternions import quat2mat

from mikasa_oracles.controller import hold, move_towards
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

GRIPPER_CLOSED = -1.0
GRIPPER_OPEN = 1.0
# A down-pointing hand at yaw 0 (TCP quaternion (0, 1, 0, 0)): 180° about x.
HAND_DOWN = quat2mat([0.0, 1.0, 0.0, 0.0])
ROBOT_BASE_XY = np.array([-0.615, 0.0])
PEG_HALF_WIDTH = 0.025
# Panda joint 7 moves within ±2.8973 rad; stay this far inside.
JOINT7_LIMIT = 2.75
# Beyond this horizontal distance from the robot base a vertical hand near the table is at
# the edge of its reach (the elbow straightens; measured ~0.79 m): lean it outwards.
LEAN_FROM, LEAN_PER_M, MAX_LEAN = 0.62, 4.0, 0.3


def wrap(angle: float) -> float:
    """The angle in [−π, π)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def heading_of(quat_wxyz: np.ndarray) -> float:
    """Heading about world z of a pose (third intrinsic X-Y-Z Euler angle, as the env)."""
    r = quat2mat(quat_wxyz)
    return math.atan2(-r[0, 1], r[0, 0])


def hand_yaw(quat_wxyz: np.ndarray) -> float:
    """Yaw of a down-pointing hand: the bearing of its local x axis (fingers close along y)."""
    r = quat2mat(quat_wxyz)
    return math.atan2(r[1, 0], r[0, 0])


def hand_rotation(yaw: float, goal_xy: np.ndarray | None = None) -> np.ndarray:
    """A down-pointing hand at ``yaw``, leaning away from the robot when ``goal_xy`` is far."""
    rotation = euler2mat(0.0, 0.0, yaw) @ HAND_DOWN
    if goal_xy is None:
        return rotation
    radial = goal_xy - ROBOT_BASE_XY
    tilt = float(np.clip(LEAN_PER_M * (np.linalg.norm(radial) - LEAN_FROM), 0.0, MAX_LEAN))
    bearing = math.atan2(radial[1], radial[0])
    lean = euler2mat(0.0, 0.0, bearing) @ euler2mat(0.0, -tilt, 0.0) @ euler2mat(0.0, 0.0, -bearing)
    return lean @ rotation


class RotateOracleBase(ScriptedOracle):
    """Shared bookkeeping: the target, the tracked turn, a stage machine; ``num_envs == 1``.

    Follows the bench policy protocol: ``chunk_size``, ``reset()``, ``forward(obs)``.
    """

    # Stop correcting once the tracked turn is this close to the target (rad); resume if the
    # peg drifts beyond RESUME_ERROR (the success tolerance is 0.1).
    DONE_ERROR: ClassVar[float] = 0.02
    RESUME_ERROR: ClassVar[float] = 0.07


    def reset(self) -> None:
        """Forget the previous episode."""
        self.target: float | None = None
        self.turned = 0.0
        self.turn_rate = 0.0
        self._last_heading = 0.0
        self.start_centre = np.zeros(2)
        self.stage = "approach"
        self.stage_steps = 0

    @property
    def remaining(self) -> float:
        """Signed turn still to go (rad), from the tracked turn."""
        return self.target - self.turned

    def _observe(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(TCP pose, peg pose, qpos); updates the tracked turn."""
        base = self.base
        tcp = base.agent.tcp.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        peg = base.peg.pose.raw_pose[0].cpu().numpy().astype(np.float64)
        qpos = base.agent.robot.get_qpos()[0].cpu().numpy().astype(np.float64)
        heading = heading_of(peg[3:])
        if self.target is None:
            # First frame: the instruction's target, and the start heading and centre as seen now.
            self.target = float(base.task_cue.reshape(-1)[0])
            self.start_centre = peg[:2].copy()
            self._last_heading = heading
        self.turn_rate = wrap(heading - self._last_heading)
        self.turned += self.turn_rate
        self._last_heading = heading
        return tcp, peg, qpos

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        tcp, peg, qpos = self._observe()
        self.stage_steps += 1
        return self._act(tcp, peg, qpos)

    def _act(self, tcp: np.ndarray, peg: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _enter(self, stage: str) -> None:
        self.stage = stage
        self.stage_steps = 0


@register_oracle("rotate_lenient")
class PushRotateOracle(RotateOracleBase):
    """RotateLenient: turn the peg by pushing one end sideways with the closed fingertips.

    For a counter-clockwise turn it pushes the +axis end along +normal or the −axis end along
    −normal (the other way round for clockwise): the end whose push turns the peg furthest
    while the hand stays within reach, then the nearer one. It slows down as the turn nears
    the target and stops early by about one step's turn (the peg slides on after the push).
    A push that would leave the reach, or stalls, is re-planned from the peg's new pose; an
    overshoot is corrected from the other side. The peg slides ~0.1-0.3 m on the way, which
    Lenient allows.
    """

    # TCP height while pushing (fingertips ~1 cm above the table, below the peg's top).
    PUSH_Z: ClassVar[float] = 0.022
    HOVER: ClassVar[float] = 0.06
    # Pushed point: this far from the centre along the axis (the peg's half length is 0.12).
    LEVER: ClassVar[float] = 0.11
    # Closed fingertips' half thickness, and the gap to the peg's side where the hand descends.
    FINGER_HALF: ClassVar[float] = 0.012
    CLEARANCE: ClassVar[float] = 0.03
    # Push depth per radian still to go, its cap, and the position gain: the speed profile.
    DEPTH_PER_RAD: ClassVar[float] = 0.08
    MAX_DEPTH: ClassVar[float] = 0.03
    PUSH_GAIN: ClassVar[float] = 1.5
    # Stop when the remaining turn is below DONE_ERROR + COAST_STEPS × the last step's turn.
    COAST_STEPS: ClassVar[float] = 1.0
    # The peg turns about a point this far behind its centre (pusher travel ~0.27 m per rad,
    # measured). A push starts only at a contact within START_REACH of the robot base (the
    # leaning hand gets to ~0.85 m near the table), keeps the pusher within COMFORT_REACH
    # unless it is coming back in, and outside INNER_REACH (the arm cannot fold closer); it
    # is re-planned from the new pose where it would leave that band.
    PIVOT_BEHIND: ClassVar[float] = 0.16
    START_REACH: ClassVar[float] = 0.84
    COMFORT_REACH: ClassVar[float] = 0.78
    INNER_REACH: ClassVar[float] = 0.35
    # A push turns at least this much (rad) before it is re-planned.
    MIN_PUSH: ClassVar[float] = 0.3
    # Re-plan a push that turns the peg less than this per step for this many steps.
    STALL_RATE: ClassVar[float] = 0.003
    STALL_STEPS: ClassVar[int] = 4
    # ... and an approach whose TCP moves less than this (m) per step for as long.
    STUCK_MOTION: ClassVar[float] = 0.001

    def reset(self) -> None:
        """Forget the previous episode."""
        super().reset()
        self.push_end = 1.0  # +1: the +axis end, −1: the −axis end
        self.push_sign = 1.0  # +1: counter-clockwise
        self.push_yaw = 0.0
        self.stalled_steps = 0
        self.stalled_end = 0.0
        self.push_budget = math.inf
        self.turned_at_push = 0.0
        self.still_steps = 0
        self._last_tcp = np.zeros(3)

    def _push_geometry(self, peg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(TCP position touching the peg's side at the pushed end, push direction), in xy."""
        gamma = heading_of(peg[3:])
        axis = np.array([math.cos(gamma), math.sin(gamma)])
        normal = np.array([-math.sin(gamma), math.cos(gamma)])
        side = self.push_sign * self.push_end
        contact = peg[:2] + self.push_end * self.LEVER * axis - side * (PEG_HALF_WIDTH + self.FINGER_HALF) * normal
        return contact, side * normal

    def _safe_turn(self, peg: np.ndarray) -> float:
        """How far (rad, up to the remaining turn) the planned push can go within reach.

        The peg turns about a point ``PIVOT_BEHIND`` behind its centre (seen from the pushed
        end), so the pusher follows an arc about it. 0 if the start point is out of reach.
        """
        contact, _ = self._push_geometry(peg)
        if np.linalg.norm(contact - ROBOT_BASE_XY) > self.START_REACH:
            return 0.0
        gamma = heading_of(peg[3:])
        pivot = peg[:2] - self.push_end * self.PIVOT_BEHIND * np.array([math.cos(gamma), math.sin(gamma)])
        arm = contact - pivot
        wanted = abs(self.remaining)
        reach = np.linalg.norm(contact - ROBOT_BASE_XY)
        for turn in np.arange(0.05, wanted, 0.05):
            c, s = math.cos(self.push_sign * turn), math.sin(self.push_sign * turn)
            pusher = pivot + np.array([c * arm[0] - s * arm[1], s * arm[0] + c * arm[1]])
            previous, reach = reach, np.linalg.norm(pusher - ROBOT_BASE_XY)
            # Beyond the comfortable reach only while coming back in.
            if reach < self.INNER_REACH or (reach > self.COMFORT_REACH and reach > previous):
                return float(turn - 0.05)
        return wanted

    def _plan(self, tcp: np.ndarray, peg: np.ndarray) -> None:
        """Choose the end to push: the longest turn within reach, then the shorter way there."""
        self.push_sign = 1.0 if self.remaining > 0 else -1.0
        self.push_yaw = hand_yaw(tcp[3:])
        scores = {}
        for end in (1.0, -1.0):
            self.push_end = end
            contact, direction = self._push_geometry(peg)
            start = contact - direction * self.CLEARANCE
            scores[end] = (self._safe_turn(peg) - 0.5 * np.linalg.norm(start - tcp[:2]) - (end == self.stalled_end), end)
        _, self.push_end = max(scores.values())
        self.push_budget = max(self._safe_turn(peg), self.MIN_PUSH)
        self.turned_at_push = self.turned
        self.stalled_steps = 0
        self.still_steps = 0

    def _hand_stuck(self, tcp: np.ndarray) -> bool:
        """Whether the TCP has moved less than STUCK_MOTION for STALL_STEPS calls in a row."""
        moved = np.linalg.norm(tcp[:3] - self._last_tcp) > self.STUCK_MOTION
        self._last_tcp = tcp[:3].copy()
        self.still_steps = 0 if moved else self.still_steps + 1
        return self.still_steps >= self.STALL_STEPS

    def _move(self, tcp: np.ndarray, goal: np.ndarray, gain: float = 1.5) -> np.ndarray:
        return move_towards(tcp, goal, hand_rotation(self.push_yaw, goal[:2]), gain=gain, gripper=GRIPPER_CLOSED)

    def _act(self, tcp: np.ndarray, peg: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        remaining = self.remaining
        if self.stage == "approach":
            if self.stage_steps == 1:
                self._plan(tcp, peg)
            contact, direction = self._push_geometry(peg)
            goal = np.append(contact - direction * self.CLEARANCE, 0.0)
            horizontal = float(np.linalg.norm(goal[:2] - tcp[:2]))
            # Descend as the hand closes in, so it never sweeps low across the peg.
            goal[2] = self.PUSH_Z + min(2.0 * horizontal, self.HOVER)
            if horizontal < 0.01 and abs(tcp[2] - self.PUSH_Z) < 0.01:
                self._enter("push")
            elif self._hand_stuck(tcp):
                # The arm cannot get there (inverse kinematics fails): try the other end.
                self.stalled_end = self.push_end
                self._enter("lift")
            return self._move(tcp, goal, gain=1.0)
        if self.stage == "push":
            contact, direction = self._push_geometry(peg)
            back_off = self._move(tcp, np.append(tcp[:2] - direction * 0.01, self.PUSH_Z), gain=1.0)
            # Stop about one step's turn early: the peg slides on once the push stops.
            coast = self.COAST_STEPS * max(self.push_sign * self.turn_rate, 0.0)
            if self.push_sign * remaining < self.DONE_ERROR + coast:
                self._enter("settle")
                return back_off
            self.stalled_steps = self.stalled_steps + 1 if abs(self.turn_rate) < self.STALL_RATE else 0
            if self.stalled_steps >= self.STALL_STEPS:
                # Out of reach, most likely: push the other end (the other way) instead.
                self.stalled_end = self.push_end
                self._enter("lift")
                return back_off
            if self.push_sign * (self.turned - self.turned_at_push) > self.push_budget - coast:
                self._enter("lift")  # this push would leave the reach: re-plan from here
                return back_off
            depth = min(self.DEPTH_PER_RAD * abs(remaining), self.MAX_DEPTH)
            return self._move(tcp, np.append(contact + direction * depth, self.PUSH_Z), gain=self.PUSH_GAIN)
        if self.stage == "lift":
            if tcp[2] > self.PUSH_Z + 0.8 * self.HOVER:
                self._enter("approach")
            return self._move(tcp, np.array([tcp[0], tcp[1], self.PUSH_Z + self.HOVER]))
        # settle: keep still while the peg comes to rest; correct if it ends up off target.
        if abs(remaining) > self.RESUME_ERROR:
            self._enter("lift" if self.push_sign * remaining < 0 else "push")
        return hold(GRIPPER_CLOSED)


@register_oracle("rotate_strict")
class GraspTwistRotateOracle(RotateOracleBase):
    """RotateStrict: grasp the peg at its centre, lift ~1 cm, turn the hand, hold.

    The fingers close across the peg's width; the hand turns about the vertical through the
    TCP (the peg's centre), and any drift of the centre is corrected while holding it.
    """

    GRASP_Z: ClassVar[float] = 0.028
    LIFT: ClassVar[float] = 0.012
    HOVER: ClassVar[float] = 0.06
    CLOSE_STEPS: ClassVar[int] = 3
    # Twist: yaw goal = current + gain × remaining (clipped), i.e. full speed until ~0.05 rad.
    TWIST_GAIN: ClassVar[float] = 2.0
    # Close once within these of the grasp pose (m, m, rad).
    GRASP_XY_TOL: ClassVar[float] = 0.006
    GRASP_Z_TOL: ClassVar[float] = 0.006
    GRASP_YAW_TOL: ClassVar[float] = 0.05
    # Keep the fingertips above the peg's top until the hand is roughly aligned.
    ALIGN_BEFORE_DESCENT: ClassVar[float] = 0.15
    # Fingers closer than this have missed the 5 cm peg.
    EMPTY_GRIP: ClassVar[float] = 0.035

    def reset(self) -> None:
        """Forget the previous episode."""
        super().reset()
        self.grasp_yaw = 0.0

    def _choose_grasp_yaw(self, tcp: np.ndarray, peg: np.ndarray, joint7: float) -> float:
        """Hand yaw across the peg needing the least turning, with joint 7 in range throughout.

        Turning the hand by +a about world z moves joint 7 by about −a.
        """
        now = hand_yaw(tcp[3:])
        best, best_cost = now, math.inf
        for half_turns in (0, 1):
            delta = wrap(heading_of(peg[3:]) + half_turns * math.pi - now)
            joint7_at_grasp = joint7 - delta
            joint7_at_end = joint7_at_grasp - self.remaining
            in_range = max(abs(joint7_at_grasp), abs(joint7_at_end)) < JOINT7_LIMIT
            cost = abs(delta) + (0.0 if in_range else 10.0)
            if cost < best_cost:
                best, best_cost = now + delta, cost
        return best

    def _act(self, tcp: np.ndarray, peg: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        remaining = self.remaining
        if self.stage == "approach":
            if self.stage_steps == 1:
                self.grasp_yaw = self._choose_grasp_yaw(tcp, peg, qpos[6])
            goal = np.array([peg[0], peg[1], 0.0])
            horizontal = float(np.linalg.norm(goal[:2] - tcp[:2]))
            goal[2] = self.GRASP_Z + min(2.0 * horizontal, self.HOVER)
            yaw_error = abs(wrap(hand_yaw(tcp[3:]) - self.grasp_yaw))
            if yaw_error > self.ALIGN_BEFORE_DESCENT:
                goal[2] = max(goal[2], self.GRASP_Z + 0.035)
            if (
                horizontal < self.GRASP_XY_TOL
                and abs(tcp[2] - self.GRASP_Z) < self.GRASP_Z_TOL
                and yaw_error < self.GRASP_YAW_TOL
            ):
                self._enter("close")
            return move_towards(tcp, goal, hand_rotation(self.grasp_yaw), gain=1.5, gripper=GRIPPER_OPEN)
        if self.stage == "close":
            if self.stage_steps >= self.CLOSE_STEPS:
                self._enter("twist")
            goal = np.array([peg[0], peg[1], self.GRASP_Z])
            return move_towards(tcp, goal, hand_rotation(self.grasp_yaw), gripper=GRIPPER_CLOSED)
        if self.stage == "release":
            if tcp[2] > self.GRASP_Z + 0.03:
                self._enter("approach")
            return move_towards(tcp, np.array([tcp[0], tcp[1], self.GRASP_Z + 0.04]), gripper=GRIPPER_OPEN)
        if qpos[7] + qpos[8] < self.EMPTY_GRIP or (abs(qpos[6]) > JOINT7_LIMIT and abs(remaining) > self.DONE_ERROR):
            # Lost the peg, or joint 7 at its limit: let go and grasp again.
            self._enter("release")
            return hold(GRIPPER_OPEN)
        if self.stage == "twist":
            if abs(remaining) < self.DONE_ERROR:
                self._enter("settle")
                return hold(GRIPPER_CLOSED)
            # Keep the peg's centre over its start while turning about the TCP.
            goal = np.append(tcp[:2] + self.start_centre - peg[:2], self.GRASP_Z + self.LIFT)
            yaw_goal = hand_yaw(tcp[3:]) + float(np.clip(self.TWIST_GAIN * remaining, -0.5, 0.5))
            return move_towards(tcp, goal, hand_rotation(yaw_goal), gripper=GRIPPER_CLOSED)
        # settle: hold the peg still; twist again if it is off target.
        if abs(remaining) > self.RESUME_ERROR:
            self._enter("twist")
        return hold(GRIPPER_CLOSED)


class MemorylessRotateMixin(Memoryless):
    """The Rotate oracles without memory: the tracked turn (the start heading and the turn
    added up since) is wiped every step, and so is the start centre.

    The target is in the instruction and the peg's heading in view, but once the peg moves
    nothing shows where it started; so the turn so far is measured from a guessed start
    heading, drawn uniformly from [0, 2π) and the same at every step (at the first frame
    the peg's heading is its start, but the next frame has forgotten that). The start
    centre (RotateStrict: keep the peg in place) is where the peg is now. Chance: the
    ±``angle_threshold`` success window over a uniform start heading, 0.1/π ≈ 3.2 %.
    Kept: the last frame's heading (the turn rate, i.e. motion) and the stage machine.
    """

    def forget(self) -> None:
        """Nothing to wipe here: ``_observe`` recomputes the turn from the guess each step."""

    def _observe(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        tcp, peg, qpos = super()._observe()  # target from the instruction, the turn rate
        guessed_start = 2 * math.pi * float(self.guess_rng(1).random())
        # The turn so far as the guess has it, taken so that the turn still to go is the
        # shorter way round to the guessed goal heading.
        self.turned = self.target - wrap(self.target - (heading_of(peg[3:]) - guessed_start))
        self.start_centre = peg[:2].copy()
        return tcp, peg, qpos


@register_oracle("rotate_lenient", memoryless=True)
class MemorylessPushRotateOracle(MemorylessRotateMixin, PushRotateOracle):
    """`PushRotateOracle` without memory (`MemorylessRotateMixin`)."""


@register_oracle("rotate_strict", memoryless=True)
class MemorylessGraspTwistRotateOracle(MemorylessRotateMixin, GraspTwistRotateOracle):
    """`GraspTwistRotateOracle` without memory (`MemorylessRotateMixin`)."""
