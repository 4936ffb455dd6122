"""Oracle for the six selection families (Remember*, FindImposter*).

It reads privileged simulator state (object poses, the phase clock) but not the answer:
during the cue it notes which objects are on the table, exactly what a camera would show,
and derives the answer from that memory — the one object shown (Remember*) or the one
object never shown (FindImposter*). In the action phase it hovers over the remembered
object, descends to just above its origin and stops.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from mikasa_envs.manifest import SELECTION_FAMILIES

from mikasa_oracles.controller import hold, move_towards, tilted
from mikasa_oracles.registry import register_oracle
from mikasa_oracles.scripted import Memoryless, ScriptedOracle

# Hidden objects are parked at z = 1000; anything below this height is on the table.
VISIBLE_BELOW_Z = 1.0
# Final TCP height above the object's origin: fingertips clear even the 4 cm objects.
TOUCH_HEIGHT = 0.02
# Approach from above: extra height per metre of remaining horizontal distance, capped.
APPROACH_SLOPE = 1.0
APPROACH_MAX_LIFT = 0.06
# A down-pointing gripper cannot reach the far edge of the table (the elbow straightens):
# lean the hand forward by this much per metre of target x beyond TILT_FROM_X, capped.
TILT_FROM_X = 0.05
TILT_PER_M = 4.0
MAX_TILT = 0.8

FAMILIES = SELECTION_FAMILIES


@register_oracle(*FAMILIES)
class SelectionOracle(ScriptedOracle):
    """Scripted solver of the selection tasks; one instance per env, ``num_envs == 1``.

    Follows the bench policy protocol: ``chunk_size``, ``reset()``, ``forward(obs)``.
    """

    GAIN = 1.5

    def reset(self) -> None:
        """Forget the previous episode's cue."""
        self.seen_in_cue: set[int] = set()
        self.start_orientation: np.ndarray | None = None

    def _remembered_target(self) -> int | None:
        n = self.base.num_objects
        if not self.seen_in_cue:
            return None
        if self._is_imposter_task():
            missing = sorted(set(range(n)) - self.seen_in_cue)
            return missing[0] if len(missing) == 1 else None
        return next(iter(self.seen_in_cue)) if len(self.seen_in_cue) == 1 else None

    def _is_imposter_task(self) -> bool:
        return type(self.base).__name__.startswith("FindImposter")

    def forward(self, obs: Any) -> np.ndarray:
        """The action for the current frame."""
        base = self.base
        tcp_pose = base.agent.tcp.pose.raw_pose[0].cpu().numpy()
        if self.start_orientation is None:
            self.start_orientation = tcp_pose[3:].copy()
        t = int(base.elapsed_steps[0])
        positions = base.object_positions()[0].cpu().numpy()
        if t < int(base.cue_steps_per_env[0]):
            # Observe the cue: which objects are on the table right now.
            self.seen_in_cue |= set(np.flatnonzero(positions[:, 2] < VISIBLE_BELOW_Z).tolist())
            return hold()
        if t < int(base.action_phase_start[0]):
            return hold()
        target = self._remembered_target()
        if target is None:
            return hold()
        goal = positions[target].copy()
        horizontal = np.linalg.norm(goal[:2] - tcp_pose[:2])
        goal[2] += TOUCH_HEIGHT + min(APPROACH_SLOPE * horizontal, APPROACH_MAX_LIFT)
        tilt = float(np.clip(TILT_PER_M * (goal[0] - TILT_FROM_X), 0.0, MAX_TILT))
        return move_towards(tcp_pose, goal, tilted(self.start_orientation, tilt), self.gain)


@register_oracle(*FAMILIES, memoryless=True)
class MemorylessSelectionOracle(Memoryless, SelectionOracle):
    """The selection oracle without memory: ``seen_in_cue`` is wiped every step.

    In the action phase all N candidates stand on the table and nothing shows which was
    shown (or missing) in the cue, so it guesses one of the objects on the table now
    (stable: it depends on the episode seed and N only) and touches it: chance is 1/N.
    """

    def forget(self) -> None:
        """Wipe the cue memory; the current frame's cue (if any) is noted again in forward."""
        self.seen_in_cue = set()

    def _remembered_target(self) -> int | None:
        target = super()._remembered_target()  # from this frame alone: None in the action phase
        if target is not None:
            return target
        positions = self.base.object_positions()[0].cpu().numpy()
        on_table = np.flatnonzero(positions[:, 2] < VISIBLE_BELOW_Z)
        return int(on_table[self.guess(len(on_table))]) if len(on_table) else None
