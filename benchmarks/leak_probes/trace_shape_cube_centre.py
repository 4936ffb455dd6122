"""Leak probe for TraceShape* / TraceShapeSeq*: the memoryless trace oracle, but with the
contours' centre read off the green cube (the reference starts it at centre +
GREEN_CUBE_OFFSET, where it rests until grasped) instead of guessed from the prior.

    mikasa-bench run --task TraceShapeEasy-VLA-v0 --task TraceShapeSeqEasy-VLA-v0 --obs-mode state \
        --policy benchmarks/leak_probes/trace_shape_cube_centre.py --num-episodes 10 --workers 1

With the cube about the centre (GREEN_CUBE_POSITION None) it passed 10/10 and 7/10; with the
cube at its fixed spot (the default since DEVIATIONS.md Fixed #27) 1/10 and 0/10
(mikasa_bench.results.leaks).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from mikasa_oracles.families.trace_shape import MemorylessTraceShapeOracle


class CubeCentreOracle(MemorylessTraceShapeOracle):
    """Guesses sizes and rotations as the memoryless oracle does; takes the centre from the
    green cube, read when the contours are first needed (just after the grasp)."""

    def guessed_centre(self, rng: np.random.Generator) -> np.ndarray:
        base = self.base
        cube = base.green_cube_position()[0, :2].cpu().numpy().astype(np.float64)
        return cube - np.asarray(base.GREEN_CUBE_OFFSET)


def make_policy(env: Any) -> CubeCentreOracle:
    """The probe for ``env`` (mikasa-bench passes the env it builds)."""
    return CubeCentreOracle(env)
