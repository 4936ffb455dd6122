"""Oracles for the six shell-game families (Touch, Push, Pick, ColorLamp, Shuffle, ShuffleColorLamp).

They read privileged simulator state (object poses, the phase clock) but derive the answer
the way a camera would: during the cue they note where the visible balls lie (and their
colours); from the first frame the mugs are visible they track the three mugs as an
unordered set of positions, each frame matched to the previous one by the closest
assignment (so a shuffle is followed swap by swap); the ball mug is the mug that first
appeared over the remembered ball. The colour-lamp oracles read the lit bulb's colour once
the lamp shows one. In the action phase they touch the mug's top and hold still (Touch,
ColorLamp, the shuffles), push it a few cm along +x (Push), or grasp its handle and lift it
(Pick).
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
from transforms3d.axangles import mat2axangle
from transforms3d.euler import euler2mat
from transforms3d.quaternions import quat2mat

from mikasa_oracles.controller import hold, move_towards
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

# Hidden objects are parked 1000 m up; anything below this height is in view.
VISIBLE_BELOW_Z = 1.0
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, -1.0
_PERMUTATIONS = [list(p) for p in itertools.permutations(range(3))]


class MugTracker:
    """Three mugs followed by position alone: each frame's positions are matched to the
    previous ones by the assignment with the smallest total distance."""

    def __init__(self) -> None:
        self.positions: np.ndarray | None = None  # (3, 3), in tracking order

    def update(self, seen: np.ndarray) -> None:
        """Match the visible mug positions ``seen`` ((3, 3), any order) to the tracked mugs."""
        if np.any(seen[:, 2] > VISIBLE_BELOW_Z):
            return  # mugs not in view
        if self.positions is None:
            self.positions = seen.copy()
            return
        costs = [np.linalg.norm(seen[p] - self.positions, axis=1).sum() for p in _PERMUTATIONS]
        self.positions = seen[_PERMUTATIONS[int(np.argmin(costs))]].copy()

    def nearest(self, xy: np.ndarray) -> int:
        """The tracked mug whose centre is nearest to ``xy`` horizontally."""
        return int(np.argmin(np.linalg.norm(self.positions[:, :2] - xy, axis=1)))


class ShellGameOracle(ScriptedOracle):
    """Observes the cue and tracks the mugs; subclasses choose the target mug and the motion.

    One instance per env, ``num_envs == 1``; bench policy protocol: ``chunk_size``,
    ``reset()``, ``forward(obs)``.
    """

    GAIN = 1.5

    def reset(self) -> None:
        """Forget the previous episode."""
        self.tracker = MugTracker()
        # Ball name -> xy where it was seen during the cue.
        self.balls_seen: dict[str, np.ndarray] = {}
        # Ball name -> tracked mug that appeared over it.
        self.mug_of_ball: dict[str, int] = {}
        self.start_orientation: np.ndarray | None = None
        self.target: int | None = None
        self.stage = 0
        self.stage_steps = 0

    # ------------------------------------------------------------ perception
    def _ball_actors(self) -> dict[str, Any]:
        """The task's balls by name."""
        balls = getattr(self.base, "balls", None) or [self.base.red_ball]
        return {ball.name: ball for ball in balls}

    def _observe(self) -> None:
        base = self.base
        actors = self._ball_actors()
        ball_poses = base.actor_raw_poses(list(actors.values()))[0].cpu().numpy()
        for name, pose in zip(actors, ball_poses, strict=True):
            if pose[2] < VISIBLE_BELOW_Z and self.tracker.positions is None:
                self.balls_seen[name] = pose[:2].copy()
        appeared = self.tracker.positions is None
        self.tracker.update(base.mug_positions()[0].cpu().numpy())
        if appeared and self.tracker.positions is not None:
            self.mug_of_ball = {name: self.tracker.nearest(xy) for name, xy in self.balls_seen.items()}

    def _choose_target(self) -> int | None:
        """The tracked mug to act on, or None while it cannot be told yet."""
        if len(self.mug_of_ball) != 1:
            return None
        return next(iter(self.mug_of_ball.values()))

    # ------------------------------------------------------------------ act
    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        tcp_pose = base.agent.tcp.pose.raw_pose[0].cpu().numpy()
        if self.start_orientation is None:
            self.start_orientation = tcp_pose[3:].copy()
        self._observe()
        if int(base.elapsed_steps[0]) < int(base.action_phase_start[0]):
            return hold()
        if self.target is None:
            self.target = self._choose_target()
            if self.target is None:
                return hold()
        return self._act(tcp_pose, self.tracker.positions[self.target])

    def _act(self, tcp_pose: np.ndarray, mug: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _move(
        self, tcp_pose: np.ndarray, goal: np.ndarray, gripper: float = GRIPPER_OPEN, rotation: np.ndarray | None = None
    ) -> np.ndarray:
        """A proportional move toward ``goal``, turning toward ``rotation`` (default: the
        orientation the episode started with, pointing down)."""
        rotation = quat2mat(self.start_orientation) if rotation is None else rotation
        return move_towards(tcp_pose, goal, rotation, self.gain, gripper)

    def _advance(self, done: bool, max_steps: int) -> None:
        """Go to the next stage once ``done`` or after ``max_steps`` in this one."""
        self.stage_steps += 1
        if done or self.stage_steps >= max_steps:
            self.stage += 1
            self.stage_steps = 0


@register_oracle("shell_game_touch", "shell_game_shuffle_touch")
class TouchMugOracle(ShellGameOracle):
    """Hover just above the target mug's top (TCP 7 cm over its centre), then hold still."""

    HOVER_ABOVE_CENTRE = 0.07
    # Approach from above: extra height per metre of remaining horizontal distance, capped.
    APPROACH_SLOPE = 0.6
    APPROACH_MAX_LIFT = 0.08

    def _act(self, tcp_pose: np.ndarray, mug: np.ndarray) -> np.ndarray:
        goal = mug.copy()
        horizontal = float(np.linalg.norm(goal[:2] - tcp_pose[:2]))
        goal[2] += self.HOVER_ABOVE_CENTRE + min(self.APPROACH_SLOPE * horizontal, self.APPROACH_MAX_LIFT)
        return self._move(tcp_pose, goal)


@register_oracle("shell_game_color_lamp_touch", "shell_game_shuffle_color_lamp_touch")
class ColorLampTouchOracle(TouchMugOracle):
    """Touch the mug that appeared over the ball whose colour the lamp shows."""

    def _lamp_colour(self) -> str | None:
        """The colour name of the lit bulb in view, or None (white, or no bulb in view)."""
        lamp = self.base.lamp
        positions = self.base.actor_raw_poses(lamp.bulbs)[0, :, :3].cpu().numpy()
        shown = [name for name, p in zip(lamp.bulb_names, positions, strict=True) if p[2] < VISIBLE_BELOW_Z]
        return shown[0] if len(shown) == 1 and shown[0] != "white" else None

    def _choose_target(self) -> int | None:
        colour = self._lamp_colour()
        return None if colour is None else self.mug_of_ball.get(f"ball_{colour}")


@register_oracle("shell_game_push")
class PushMugOracle(ShellGameOracle):
    """Come down behind the target mug (−x side), push it a few cm along +x, hold still."""

    BEHIND = 0.12
    TRAVEL_Z = 0.15
    PUSH_Z = 0.05
    # Final TCP x relative to the mug centre at the start of the push.
    PUSH_TO = -0.035

    def _act(self, tcp_pose: np.ndarray, mug: np.ndarray) -> np.ndarray:
        if self.stage == 0 and self.stage_steps == 0:
            self.push_from = mug.copy()  # where the mug stood before the push
        start = self.push_from
        waypoints = [
            (np.array([start[0] - self.BEHIND, start[1], self.TRAVEL_Z]), 0.02, 20),
            (np.array([start[0] - self.BEHIND, start[1], self.PUSH_Z]), 0.01, 12),
            (np.array([start[0] + self.PUSH_TO, start[1], self.PUSH_Z]), 0.005, 12),
        ]
        if self.stage >= len(waypoints):
            return hold()
        goal, tol, max_steps = waypoints[self.stage]
        action = self._move(tcp_pose, goal)
        self._advance(float(np.linalg.norm(goal - tcp_pose[:3])) < tol, max_steps)
        return action


@register_oracle("shell_game_pick")
class PickMugOracle(ShellGameOracle):
    """Top-down grasp of the handle loop's top arm, fingers closing across the loop; lift."""

    # Grasp point: along the handle direction from the mug centre, and TCP height above it.
    GRASP_ALONG_HANDLE = 0.066
    GRASP_TCP_ABOVE_CENTRE = 0.022
    # Approach from above: extra height per metre of remaining horizontal distance, capped.
    APPROACH_SLOPE = 1.0
    APPROACH_MAX_LIFT = 0.08
    # ...and per radian the fingers are still turned away from across the handle, beyond a
    # tolerance (the EE controller turns only ~0.04 rad per step; the closing fingers align
    # the handle for the rest).
    APPROACH_LIFT_PER_RAD = 0.3
    APPROACH_TURN_TOLERANCE = 0.3
    # Fingers 2 cm from the centre each while approaching (4 cm gap around the 1.5 cm bar):
    # wide enough for the handle, narrow enough to stay off the mug's top.
    GRIPPER_APPROACH = 0.2
    LIFT_TCP_Z = 0.20
    CLOSE_STEPS = 2
    # Steps the descent may take before the fingers close wherever they are.
    APPROACH_MAX_STEPS = 18

    def __init__(self, env: Any, gain: float | None = None, approach_max_steps: int = APPROACH_MAX_STEPS) -> None:
        """``approach_max_steps``: the descent's time limit (a slower arm, e.g. one acting in
        joint deltas, needs more than the default)."""
        self.approach_max_steps = approach_max_steps
        super().__init__(env, gain)

    def _grasp_rotation(self, mug_quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(handle direction in the world xy plane, TCP rotation with the fingers closing
        across it, pointing down)."""
        handle = quat2mat(mug_quat)[:, 0]
        handle = handle[:2] / np.linalg.norm(handle[:2])
        start = quat2mat(self.start_orientation)
        closing = start[:2, 1]  # the Panda fingers move along the TCP's y axis
        across = np.array([-handle[1], handle[0]])
        yaw = math.atan2(across[1], across[0]) - math.atan2(closing[1], closing[0])
        yaw = (yaw + math.pi / 2) % math.pi - math.pi / 2  # the gripper is symmetric: turn < 90°
        return handle, euler2mat(0.0, 0.0, yaw) @ start

    def _act(self, tcp_pose: np.ndarray, mug: np.ndarray) -> np.ndarray:
        base = self.base
        if self.stage == 0 and self.stage_steps == 0:
            mug_quat = base.actor_raw_poses(base.mugs)[0, self._target_actor(), 3:].cpu().numpy()
            self.handle, self.grasp_rotation = self._grasp_rotation(mug_quat)
            self.grasp = mug.copy()
            self.grasp[:2] += self.GRASP_ALONG_HANDLE * self.handle
            self.grasp[2] += self.GRASP_TCP_ABOVE_CENTRE
        grasp = self.grasp
        if self.stage == 0:  # descend onto the handle, turning the fingers across it
            goal = grasp.copy()
            horizontal = float(np.linalg.norm(goal[:2] - tcp_pose[:2]))
            _, turn_left = mat2axangle(self.grasp_rotation @ quat2mat(tcp_pose[3:]).T)
            over_turn = max(abs(turn_left) - self.APPROACH_TURN_TOLERANCE, 0.0)
            lift = self.APPROACH_SLOPE * horizontal + self.APPROACH_LIFT_PER_RAD * over_turn
            goal[2] += min(lift, self.APPROACH_MAX_LIFT)
            action = self._move(tcp_pose, goal, self.GRIPPER_APPROACH, self.grasp_rotation)
            self._advance(float(np.linalg.norm(grasp - tcp_pose[:3])) < 0.008, self.approach_max_steps)
            return action
        if self.stage == 1:  # close on the handle
            action = self._move(tcp_pose, grasp, GRIPPER_CLOSED, self.grasp_rotation)
            self._advance(False, self.CLOSE_STEPS)
            return action
        lifted = np.array([grasp[0], grasp[1], self.LIFT_TCP_Z])
        return self._move(tcp_pose, lifted, GRIPPER_CLOSED, self.grasp_rotation)

    def _target_actor(self) -> int:
        """The mug actor at the tracked target's position (for its orientation)."""
        positions = self.base.mug_positions()[0].cpu().numpy()
        return int(np.argmin(np.linalg.norm(positions - self.tracker.positions[self.target], axis=1)))


class MemorylessShellGameMixin(Memoryless):
    """The shell-game oracles without memory.

    Wiped every step: the balls seen in the cue, the mug tracker (so a shuffle cannot be
    followed), which mug appeared over which ball, and the chosen target. Kept: the motion
    stages of Push / Pick and the start orientation. A ball at table height counts as seen
    only while the mugs are out of view: once they stand on the table it is under one of
    them, and a camera does not see it (its privileged pose is ignored).

    In the action phase it guesses one of the three mugs on the table, numbered by slot
    (left to right along y, which a push along +x or a lift does not change), so the guess
    stays on the same mug. The colour-lamp families add the task's fixed rule: the ball of
    the lamp's colour stood at slot red 0 / green 1 / blue 2 in the cue, so without a
    shuffle the lamp alone names the mug (a known leak of ShellGameColorLampTouch, kept
    upstream); after a shuffle that slot holds the right mug only by chance.
    """

    def forget(self) -> None:
        """Wipe the cue, the tracking and the target."""
        self.tracker = MugTracker()
        self.balls_seen = {}
        self.mug_of_ball = {}
        self.target = None

    def _observe(self) -> None:
        mugs = self.base.mug_positions()[0].cpu().numpy()
        if np.all(mugs[:, 2] < VISIBLE_BELOW_Z):
            self.tracker.update(mugs)  # the mugs are in view: any ball is under one of them
            return
        super()._observe()

    def _choose_target(self) -> int | None:
        target = super()._choose_target()  # from this frame alone: None in the action phase
        if target is None and self.tracker.positions is not None:
            by_slot = np.argsort(self.tracker.positions[:, 1], kind="stable")
            target = int(by_slot[self._slot_guess()])
        return target

    def _slot_guess(self) -> int:
        return self.guess(len(self.tracker.positions))


@register_oracle("shell_game_touch", "shell_game_shuffle_touch", memoryless=True)
class MemorylessTouchMugOracle(MemorylessShellGameMixin, TouchMugOracle):
    """`TouchMugOracle` without memory (`MemorylessShellGameMixin`)."""


@register_oracle("shell_game_push", memoryless=True)
class MemorylessPushMugOracle(MemorylessShellGameMixin, PushMugOracle):
    """`PushMugOracle` without memory (`MemorylessShellGameMixin`)."""


@register_oracle("shell_game_pick", memoryless=True)
class MemorylessPickMugOracle(MemorylessShellGameMixin, PickMugOracle):
    """`PickMugOracle` without memory (`MemorylessShellGameMixin`)."""


@register_oracle(
    "shell_game_color_lamp_touch", "shell_game_shuffle_color_lamp_touch", memoryless=True
)
class MemorylessColorLampTouchOracle(MemorylessShellGameMixin, ColorLampTouchOracle):
    """`ColorLampTouchOracle` without memory: the lamp's colour (shown now) and the fixed
    cue slot of that colour's ball pick the slot (`MemorylessShellGameMixin`)."""

    def _slot_guess(self) -> int:
        colour = self._lamp_colour()
        if colour is None:
            return super()._slot_guess()
        return [ball.name for ball in self.base.balls].index(f"ball_{colour}")
