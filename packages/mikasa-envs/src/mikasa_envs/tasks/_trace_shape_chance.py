"""Chance rule of the two trace families: how often a contour guessed from the task's prior
closes the true one (a Monte Carlo over the env's own geometry and latch rules)."""

from __future__ import annotations

import math

import numpy as np
import torch

from mikasa_envs.family import Chance, TaskSpec
from mikasa_envs.tasks._trace_shape import (
    TraceShapeCommonVLABaseEnv,
    advance_latches,
    checkpoints_of,
    is_closed,
    shape_waypoints,
)

__all__ = ["trace_shape_chance", "trace_shape_guess_rate"]


def trace_shape_guess_rate(
    shape_set: tuple[int, ...],
    samples: int = 200_000,
    seed: int = 0,
    lengths: tuple[int, int] = (1, 1),
    shapes_shown: bool = False,
    passes: int = 2,
    env: type = TraceShapeCommonVLABaseEnv,
) -> float:
    """Monte Carlo chance of TraceShape (``lengths`` (1, 1)) or TraceShapeSeq (``lengths``
    its sequence-length range, ``shapes_shown``: the shapes, and so their number, are in
    ``task_cue``): the share of episodes that a blind guesser passes. It guesses one contour
    per element from the task's prior — one centre for all, per element a size, a rotation
    and (unless shown) a shape, drawn as the env draws them — and traces them one after the
    other as the memoryless oracle does: a straight move from where the cube is
    (``env.GREEN_CUBE_POSITION``, then the previous contour's start) to the guessed start,
    then ``passes`` times round the guessed checkpoints and back, 8 points per straight move.
    Along that route the env's latch rules run on the true contours: only the active element
    scores; its checkpoint 0 latches first (within the checkpoint radius), then the others;
    farther than ``STRAY_RADIUS`` from its contour clears it; all latched and back at
    checkpoint 0 closes it and makes the next one active (so any guessed contour may close
    any element, in order)."""
    rng = np.random.default_rng(seed)
    elements = lengths[1]

    def draw_contours(n: int, shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, elements, 64, 2) waypoints and (n, elements, 12, 2) checkpoints about one
        drawn centre per sample."""
        centres = np.stack([rng.uniform(*env.CENTER_X_RANGE, n), rng.uniform(*env.CENTER_Y_RANGE, n)], -1)
        sizes = rng.uniform(*env.SIZE_RANGE, (n, elements))
        rotations = rng.uniform(0.0, 2 * math.pi, (n, elements))
        waypoints = shape_waypoints(
            torch.as_tensor(shapes),
            torch.as_tensor(np.repeat(centres[:, None], elements, axis=1), dtype=torch.float32),
            torch.as_tensor(sizes, dtype=torch.float32),
            torch.as_tensor(rotations, dtype=torch.float32),
        )
        return waypoints.double().numpy(), checkpoints_of(waypoints).double().numpy()

    steps = np.linspace(0.0, 1.0, 8, endpoint=False)[:, None]
    passed = 0
    for start in range(0, samples, 10_000):
        n = min(10_000, samples - start)
        rows = np.arange(n)
        count = rng.integers(lengths[0], lengths[1] + 1, n)
        true_shapes = rng.choice(shape_set, (n, elements))
        guessed_shapes = true_shapes if shapes_shown else rng.choice(shape_set, (n, elements))
        (contour, truth), (_, guess) = draw_contours(n, true_shapes), draw_contours(n, guessed_shapes)
        # The route's corners: per guessed contour (those past the sequence's length: staying
        # at the last one's start), the move to its start and `passes` rounds.
        corners = [np.broadcast_to(np.asarray(env.GREEN_CUBE_POSITION, dtype=np.float64), (n, 2))]
        for k in range(elements):
            checkpoints = np.where((k < count)[:, None, None], guess[:, k], corners[-1][:, None])
            corners += [checkpoints[:, 0]] + [checkpoints[:, i] for _ in range(passes) for i in (*range(1, 12), 0)]
        route = np.stack(corners, axis=1)
        trace = (route[:, :-1, None] + np.diff(route, axis=1)[:, :, None] * steps).reshape(n, -1, 2)
        active = np.zeros(n, dtype=np.int64)
        visited = np.zeros((n, truth.shape[2]), dtype=bool)
        for point in np.moveaxis(trace, 1, 0):  # (n, 2), in the route's order
            element = np.minimum(active, elements - 1)
            contour_dist = np.linalg.norm(contour[rows, element] - point[:, None], axis=-1).min(axis=-1)
            checkpoint_dist = np.linalg.norm(truth[rows, element] - point[:, None], axis=-1)
            visited = advance_latches(visited, checkpoint_dist, contour_dist, env.CHECKPOINT_RADIUS, env.STRAY_RADIUS)
            closed = is_closed(visited, checkpoint_dist, env.CHECKPOINT_RADIUS) & (active < count)
            active += closed
            visited[closed] = False
        passed += int((active >= count).sum())
    return passed / samples


def trace_shape_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of TraceShape and TraceShapeSeq: the variant's ``GUESS_RATE``, computed
    once by `trace_shape_guess_rate` (the tests recompute it with fewer samples)."""
    if env_class.MAX_ELEMENTS == 1:
        return Chance(
            env_class.GUESS_RATE,
            f"no discrete answer; a contour guessed from the prior ({len(env_class.SHAPE_SET)} "
            "shape(s), centre, size, rotation), traced twice from its start, closes the true one (all 12 "
            "checkpoints within 3.5 cm, never 6 cm off it) at this rate",
        )
    lo, hi = env_class.SEQUENCE_LEN_RANGE
    return Chance(
        env_class.GUESS_RATE,
        f"no discrete answer; {lo}-{hi} contours about one centre, their shapes shown in "
        "task_cue: contours guessed from the prior (centre, sizes, rotations), each traced twice "
        "in turn, close all of "
        "them (every checkpoint within 3.5 cm, never 6 cm off) at this rate",
    )
