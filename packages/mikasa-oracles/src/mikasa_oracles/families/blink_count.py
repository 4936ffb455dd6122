"""Oracle for BlinkCountButtonPress (``oracles_motion_planning.md`` §3, §5.2).

It counts the blinks as a camera would: each frame it looks at which bulb the blink lamp
shows (the lit one or the white one; the other is parked far away) and counts the
white → lit changes. It never reads the env's answer (``target_blinks`` / ``oracle_info``).
During the cue it parks above the red button; once the phase lamp shows its green bulb it
pushes the red button down and lifts, as many times as it counted (the env's press latch
tells it when a push registered and when it was counted), then pushes the black button.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from transforms3d.quaternions import quat2mat

from mikasa_oracles.controller import move_towards
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

GRIPPER_CLOSED = -1.0
# TCP heights: parked / travelling above the caps, pushing (the press registers at
# z <= 0.0831), and lifting after a push (the press counts ~0.085 m above where it registered).
PARK_Z = 0.16
PUSH_Z = 0.065
LIFT_Z = 0.18
# Start pushing the black button once the TCP is this close to above its centre.
ALIGN_TOLERANCE = 0.01


@register_oracle("blink_count_button_press")
class BlinkCountOracle(ScriptedOracle):
    """Scripted solver of BlinkCountButtonPress; ``num_envs == 1``.

    Follows the bench policy protocol: ``chunk_size``, ``reset()``, ``forward(obs)``.
    """


    def reset(self) -> None:
        """Forget the previous episode's blinks."""
        self.blinks_seen = 0
        self.lamp_was_lit = False
        self.ready_seen = False
        self.hold_rotation: np.ndarray | None = None

    @staticmethod
    def _bulb_shown(lamp: Any, bulb: str) -> bool:
        """Whether ``lamp`` shows its bulb ``bulb`` (the one standing on the lamp) in env 0."""
        return int(lamp.shown[0]) == lamp.bulb_index(bulb)

    def _watch_lamps(self) -> None:
        if self.ready_seen:
            return
        lit = self._bulb_shown(self.base.blink_lamp, "on")
        self.blinks_seen += int(lit and not self.lamp_was_lit)
        self.lamp_was_lit = lit
        self.ready_seen = self._bulb_shown(self.base.phase_lamp, "ready")

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        tcp_pose = base.agent.tcp.pose.raw_pose[0].cpu().numpy()
        if self.hold_rotation is None:
            self.hold_rotation = quat2mat(tcp_pose[3:])
        self._watch_lamps()
        red_xy = base.button_xy[0].cpu().numpy()
        if not self.ready_seen or self.blinks_seen == 0:
            return self._move(tcp_pose, red_xy, PARK_Z)
        if int(base.press_count[0]) < self.blinks_seen:
            # Push until the press registers (pending), then lift until it is counted.
            pending = bool(base.latch.pending[0])
            return self._move(tcp_pose, red_xy, LIFT_Z if pending else PUSH_Z)
        black_xy = base.confirm_button_xy[0].cpu().numpy()
        aligned = np.linalg.norm(tcp_pose[:2] - black_xy) < ALIGN_TOLERANCE
        return self._move(tcp_pose, black_xy, PUSH_Z if aligned else PARK_Z)

    def _move(self, tcp_pose: np.ndarray, xy: np.ndarray, z: float) -> np.ndarray:
        goal = np.array([xy[0], xy[1], z])
        return move_towards(tcp_pose, goal, self.hold_rotation, self.gain, GRIPPER_CLOSED)


@register_oracle("blink_count_button_press", memoryless=True)
class MemorylessBlinkCountOracle(Memoryless, BlinkCountOracle):
    """The blink-count oracle without memory: the blink count (and whether the lamp was lit
    a frame ago) is wiped every step, so no blink is ever counted.

    When the phase lamp shows green (visible now) it guesses the count uniformly among the
    variant's counts (``BLINK_COUNT_RANGE``, a fixed rule of the task), the same guess at
    every step, and presses that many times: chance is 1 / (number of counts). Kept: its
    own presses so far, read from the env's press latch (motion progress, not the answer)
    and the hold orientation.
    """

    def forget(self) -> None:
        """Wipe the count and the lamp history."""
        self.blinks_seen = 0
        self.lamp_was_lit = False
        self.ready_seen = False

    def _watch_lamps(self) -> None:
        super()._watch_lamps()  # this frame alone: at most one "blink", the phase lamp now
        if self.ready_seen:
            lo, hi = self.base.BLINK_COUNT_RANGE
            self.blinks_seen = lo + self.guess(hi - lo + 1)
