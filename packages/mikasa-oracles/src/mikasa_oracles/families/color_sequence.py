"""Oracle for BunchOfColors, SeqOfColors and ChainOfColors (``oracles_motion_planning.md`` §4.2).

It reads privileged simulator state (cube and button poses, the phase clock, whether a
touch or press has registered) but not the answer: during the cue it notes which cubes
stand on the table, and in which order they first appear, exactly what a camera would
show. In the action phase it touches the remembered cubes (in cue order for Seq/Chain, in
the shortest-path order for Bunch) by stopping its closed gripper just above each, then
pushes the TCP down over the button, lifts it and holds still.
"""

from __future__ import annotations

import itertools
from typing import Any

import gymnasium as gym
import numpy as np
from mikasa_envs.building_blocks.buttons import CONFIRM_LIFT
from transforms3d.quaternions import quat2mat

from mikasa_oracles.controller import EE_DELTA_POS_SCALE, move_towards
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless

GRIPPER_CLOSED = -1.0
# Hidden cubes are parked at z = 1000; anything below this height is on the table.
VISIBLE_BELOW_Z = 1.0
# Final TCP height above a cube's centre: 1.5 cm above its top, 1 cm inside the touch sphere.
TOUCH_ABOVE_CENTRE = 0.035
# Approach from above: extra height per metre of remaining horizontal distance, capped,
# so the closed fingertips clear the neighbouring cubes on the way.
APPROACH_SLOPE = 0.4
APPROACH_MAX_LIFT = 0.03
# Downward speed limit: at most this fraction of the remaining height per step (as a target).
DESCENT_GAIN = 1.0
# Where to wait during the cue and memory phases: above the button's nominal place.
PARK_POINT = np.array([-0.12, 0.0, 0.12])
# Button: move the TCP in at this height (a press registers below 0.0831 within 0.065 of the
# centre), the closed fingertips 1 cm below it clear the cap (top 0.058) and the cubes
# (top 0.04); once surely pressed, rise to LIFT_Z and hold still (a press is confirmed
# 0.085 above where it registered, so at 0.1681 at the latest).
PRESS_Z = 0.07
REGISTERED_PRESS_Z = 0.08
PRESS_CHECK_RADIUS = 0.055
LIFT_Z = 0.18
# With ``read_press_latch``: lift this far past the height the env needs to confirm a press
# (where it registered + CONFIRM_LIFT), and aim the press this far from the button centre on
# the near side (a press registers anywhere within 0.065 of it).
CONFIRM_MARGIN = 0.01
PRESS_AIM_RADIUS = 0.035

FAMILIES = ("bunch_of_colors", "seq_of_colors", "chain_of_colors")


@register_oracle(*FAMILIES)
class ColorSequenceOracle:
    """Scripted solver of the colour-sequence tasks; one instance per env, ``num_envs == 1``.

    Follows the bench policy protocol: ``chunk_size``, ``reset()``, ``forward(obs)``.
    """

    chunk_size = 1

    def __init__(
        self,
        env: gym.Env,
        gain: float = 1.5,
        approach_slope: float = APPROACH_SLOPE,
        approach_max_lift: float = APPROACH_MAX_LIFT,
        descent_gain: float = DESCENT_GAIN,
        park_point: np.ndarray = PARK_POINT,
        read_press_latch: bool = False,
    ) -> None:
        """``gain`` .. ``descent_gain`` shape the motion (module constants above).
        ``park_point``: where the TCP waits during the cue and memory phases.
        ``read_press_latch``: press the button as soon as the press radius allows and lift
        only as far as the env's press latch needs (read from the env, like the touches),
        instead of pressing at the centre and lifting to a fixed height; for short horizons.
        """
        self.env = env
        self.base = env.unwrapped
        self.gain = gain
        self.approach_slope = approach_slope
        self.approach_max_lift = approach_max_lift
        self.descent_gain = descent_gain
        self.park_point = np.asarray(park_point, dtype=float)
        self.read_press_latch = read_press_latch
        # Seq/Chain book touches in order slots and enforce the cue order; Bunch has none.
        self.ordered = hasattr(self.base, "touched_cubes_idx")
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode's cue and plan."""
        self.seen_in_cue: list[int] = []
        self.plan: list[int] | None = None
        self.press_start: np.ndarray | None = None
        self.orientation: np.ndarray | None = None

    # ------------------------------------------------------------------ cue
    def _observe_cue(self) -> None:
        """Append cubes standing on the table now, in key order within one frame."""
        heights = self.base.cube_positions()[0, :, 2].cpu().numpy()
        for key in np.flatnonzero(heights < VISIBLE_BELOW_Z).tolist():
            if key not in self.seen_in_cue:
                self.seen_in_cue.append(key)

    def _make_plan(self, tcp: np.ndarray, cubes: np.ndarray, button: np.ndarray) -> list[int]:
        """Cue order (ordered families) or the shortest tour TCP -> cubes -> button (Bunch)."""
        if self.ordered or not self.seen_in_cue:
            return list(self.seen_in_cue)
        orders = np.array(list(itertools.permutations(self.seen_in_cue)))  # (L!, L), L <= 7
        stops = cubes[orders, :2]
        lengths = (
            np.linalg.norm(stops[:, 0] - tcp[:2], axis=-1)
            + np.linalg.norm(np.diff(stops, axis=1), axis=-1).sum(axis=-1)
            + np.linalg.norm(stops[:, -1] - button[:2], axis=-1)
        )
        return orders[int(np.argmin(lengths))].tolist()

    # --------------------------------------------------------------- acting
    def _move(self, tcp_pose: np.ndarray, goal: np.ndarray) -> np.ndarray:
        action = move_towards(tcp_pose, goal, self.orientation, self.gain, gripper=GRIPPER_CLOSED)
        # Brake on the way down: a fast descent from high up overshoots the touch height
        # by several millimetres and the fingertips hit the cube.
        descent_cap = self.descent_gain * (tcp_pose[2] - goal[2]) / EE_DELTA_POS_SCALE
        action[2] = max(action[2], -max(descent_cap, 0.0))
        return action

    def _approach(self, tcp: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """``goal`` raised in proportion to the horizontal distance still to go."""
        lifted = goal.copy()
        lifted[2] += min(self.approach_slope * np.linalg.norm(goal[:2] - tcp[:2]), self.approach_max_lift)
        return lifted

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        tcp_pose = base.agent.tcp.pose.raw_pose[0].cpu().numpy()
        tcp = tcp_pose[:3]
        if self.orientation is None:
            self.orientation = quat2mat(tcp_pose[3:])
        t = int(base.elapsed_steps[0])
        if t < int(base.cue_steps_per_env[0]):
            self._observe_cue()
        if t < int(base.action_phase_start[0]):
            # Behind the cue spots as the base camera sees them: the cue stays in view.
            return self._move(tcp_pose, self.park_point)
        cubes = base.cube_positions()[0].cpu().numpy()
        button = base.button_xy[0].cpu().numpy()
        if self.plan is None:
            self.plan = self._make_plan(tcp, cubes, button)
        touched = base.touched_cubes[0].cpu().numpy()
        remaining = [k for k in self.plan if not touched[k]]
        if remaining:
            goal = cubes[remaining[0]] + np.array([0.0, 0.0, TOUCH_ABOVE_CENTRE])
            return self._move(tcp_pose, self._approach(tcp, goal))
        if self.read_press_latch:
            return self._move(tcp_pose, self._press_goal(tcp, button))
        if self.press_start is None:
            over_button = np.linalg.norm(tcp[:2] - button) < PRESS_CHECK_RADIUS
            if over_button and tcp[2] <= REGISTERED_PRESS_Z:
                self.press_start = tcp.copy()
            else:
                # Straight in at press height: the press registers on entering the radius.
                return self._move(tcp_pose, np.array([*button, PRESS_Z]))
        # Lift until the press is confirmed, then hold still there.
        return self._move(tcp_pose, np.array([*self.press_start[:2], LIFT_Z]))

    def _press_goal(self, tcp: np.ndarray, button: np.ndarray) -> np.ndarray:
        """Press (``read_press_latch``): in at press height at the nearest point within
        PRESS_AIM_RADIUS of the button centre until the env registers the press, then up to
        just past the height that confirms it."""
        latch = self.base.press_latch
        if bool(latch.pending[0]) or bool(self.base.button_pressed[0]):
            if self.press_start is None:
                self.press_start = np.array([*tcp[:2], float(latch.press_start_z[0])])
            return np.array([*self.press_start[:2], self.press_start[2] + CONFIRM_LIFT + CONFIRM_MARGIN])
        offset = tcp[:2] - button
        distance = np.linalg.norm(offset)
        aim = button + offset * min(1.0, PRESS_AIM_RADIUS / max(distance, 1e-9))
        return np.array([*aim, PRESS_Z])


@register_oracle(*FAMILIES, memoryless=True)
class MemorylessColorSequenceOracle(Memoryless, ColorSequenceOracle):
    """The colour-sequence oracle without memory: the cubes seen in the cue (and the plan
    made from them) are wiped every step.

    In the action phase all nine cubes stand on the arc and none shows whether it was cued,
    so it guesses L of them (L = ``SEQUENCE_LENGTH``, named by the task; for Seq/Chain in
    a guessed order), the same guess at every step: chance is 1 / C(9, L) for Bunch and
    1 / P(9, L) for Seq and Chain. Bunch visits its guess in the shortest tour from the
    park point (a fixed start, so the order does not change as the hand moves). Kept: the
    env's touch and press latches (its own progress), the press start, the orientation.
    """

    def forget(self) -> None:
        """Wipe the cue memory and the plan."""
        self.seen_in_cue = []
        self.plan = None

    def _make_plan(self, tcp: np.ndarray, cubes: np.ndarray, button: np.ndarray) -> list[int]:
        if not self.seen_in_cue:  # the action phase: nothing seen this frame, guess
            on_table = np.flatnonzero(cubes[:, 2] < VISIBLE_BELOW_Z)
            length = min(int(self.base.SEQUENCE_LENGTH), len(on_table))
            picks = self.guess_rng(len(on_table), length).choice(on_table, length, replace=False)
            self.seen_in_cue = [int(k) for k in picks]
            tcp = self.park_point
        return super()._make_plan(tcp, cubes, button)
