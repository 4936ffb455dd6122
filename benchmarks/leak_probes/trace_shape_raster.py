"""Leak probe for TraceShapeSeq* (and TraceShape*): a policy without memory that sweeps the
green cube over the whole region where contours can lie, lane after lane, for as long as the
episode allows, then presses the submit button. It never sees the demonstration.

The question: TraceShapeSeq scores only the active element, but its checkpoint latches
accumulate over the whole action phase (1,170+ steps), so repeated sweeps might visit every
checkpoint of every element, in order, by brute force.

    mikasa-bench run --task TraceShapeSeqEasy-VLA-v0 --obs-mode state \
        --policy benchmarks/leak_probes/trace_shape_raster.py --num-episodes 10 --workers 1

It passed TraceShapeSeq Easy/Medium/Hard 6, 5, 5 of 10 and TraceShape Easy/Medium/Hard 0, 0, 2
of 10; since a trace must start at checkpoint 0 and stay within 6 cm of the contour
(DEVIATIONS.md Fixed #28), 0 of 10 on all six (mikasa_bench.results.leaks).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
from mikasa_envs.manifest import get_task
from mikasa_oracles.families.trace_shape import MemorylessTraceShapeOracle

# Every contour point lies within the centre range grown by the largest size (0.13 m).
X_RANGE, Y_RANGE = (-0.28, 0.08), (-0.23, 0.23)
# Lanes 6 cm apart: every point is within 3 cm of one, inside the env's 3.5 cm latch radius.
LANE_SPACING, WAYPOINT_SPACING = 0.06, 0.05
WAYPOINT_TOL, WAYPOINT_MAX_STEPS = 0.02, 12
# Steps kept back at the end for dropping the cube and pressing the button.
SUBMIT_STEPS = 90


def raster_path() -> list[np.ndarray]:
    """Boustrophedon lanes along y over the region, as cube-centre waypoints."""
    xs = np.arange(X_RANGE[0], X_RANGE[1] + 1e-9, LANE_SPACING)
    ys = np.arange(Y_RANGE[0], Y_RANGE[1] + 1e-9, WAYPOINT_SPACING)
    path = []
    for lane, x in enumerate(xs):
        for y in ys if lane % 2 == 0 else ys[::-1]:
            path.append(np.array([x, y]))
    return path


class RasterSweep(MemorylessTraceShapeOracle):
    """Grasp the cube when the lamp turns green, sweep until ``SUBMIT_STEPS`` before the
    horizon (back and forth over the raster), then drop the cube and press the button."""

    def _run(self) -> Iterator[np.ndarray]:
        yield from self._watch_demonstration()
        yield from self._grasp()
        path, regrasps = raster_path(), 0
        horizon = get_task(self.base.spec.id).max_episode_steps
        while int(self.base.elapsed_steps[0]) < horizon - SUBMIT_STEPS:
            for target in path:
                if int(self.base.elapsed_steps[0]) >= horizon - SUBMIT_STEPS:
                    break
                regrasps = yield from self._regrasp_if_lost(regrasps)
                yield from self._carry_to(target, WAYPOINT_TOL, WAYPOINT_MAX_STEPS)
            path = path[::-1]
        yield from self._finish()


def make_policy(env: Any) -> RasterSweep:
    """The probe for ``env`` (mikasa-bench passes the env it builds)."""
    return RasterSweep(env)
