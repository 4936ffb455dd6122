"""Chance success rate per task: what a policy without memory can get by guessing.

The validity check (``mikasa-bench validity``) compares the memoryless oracle
and the random policy with this figure: a task where either does significantly better
than chance shows its answer without memory (a leak).

* Tasks with a discrete answer: the success of a uniform guess among the candidates the
  agent sees when it must act (1/N objects, mugs, buttons or counts; 1/C(9, L) colour sets,
  1/P(9, L) colour sequences). For TakeItBack the candidates are the three start rows.
* Tasks without a discrete answer, each justified in its reason: Intercept* (a continuous
  start and velocity, out of view when the ball must be met: chance 0, any success is a
  leak), TraceShape* and
  TraceShapeSeq* (contours guessed from the task's prior — centre, size, rotation, the shape
  unless shown — traced from checkpoint 0 without straying from the true ones close them at
  a rate computed by ``trace_shape_guess_rate``), Rotate* (a continuous start heading: the success window's share of it),
  TimedTransfer* (a time: the best a policy without a clock gets by descending with a
  constant probability per step), BatteriesChecker* (a checklist: the chance that
  uniformly drawn check cycles cover every battery within the horizon).

The variant parameters are the envs' class constants (``BLINK_COUNT_RANGE``,
``SEQUENCE_LENGTH``, ...), copied here so that this module does not import the simulator;
``tests/test_validity.py`` checks them against the env classes. Plain data otherwise.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["Chance", "task_chance", "chance_table"]


@dataclass(frozen=True)
class Chance:
    """A task's chance success rate and why (one line)."""

    rate: float
    reason: str


# --- variant parameters (class constants of the envs; checked by tests/test_validity.py)
# Bunch/Seq/ChainOfColors: cubes on the arc.
NUM_COLORS = 9
# BlinkCountButtonPress variant -> BLINK_COUNT_RANGE (inclusive).
BLINK_COUNT_RANGES: dict[str, tuple[int, int]] = {
    "Easy": (1, 3),
    "Medium": (1, 5),
    "Hard": (1, 7),
    "Easy-Long": (1, 10),
    "Medium-Long": (10, 20),
    "Hard-Long": (20, 30),
}
# TimedTransfer variant -> DELAY_STEPS; WINDOW_TOLERANCE; SIGNAL_STEP_RANGE (inclusive).
TIMED_TRANSFER_DELAYS: dict[str, int] = {
    "Easy": 100,
    "Medium": 150,
    "Hard": 200,
    "Easy-Long": 300,
    "Medium-Long": 500,
    "Hard-Long": 1000,
}
TIMED_TRANSFER_TOLERANCE = 0.05
TIMED_TRANSFER_SIGNAL_STEPS = (1, 3)
# Rotate*: angle_threshold (rad, the env's default).
ROTATE_ANGLE_THRESHOLD = 0.1
# TakeItBack: START_X, START_Y_STEP, START_Y_JITTER, GOAL_RADIUS (the success radius).
TAKE_IT_BACK_START_X = (-0.05, 0.05)
TAKE_IT_BACK_ROW_STEP = 0.1
TAKE_IT_BACK_ROW_JITTER = 0.05
TAKE_IT_BACK_RADIUS = 0.08
# BatteriesChecker: env steps of one check cycle (pick, insert, Hard: return, press) of
# the oracle, measured (Easy-3 / Easy-6: 247-248 / 502-504 steps for 3 / 6 cycles, Hard-3:
# 427-430 for 3; the memoryless oracle's cycles took 79-88 steps on Easy-3).
BATTERY_CYCLE_STEPS: dict[str, int] = {"batteries_checker_easy": 84, "batteries_checker_hard": 143}
# TraceShape variant -> `trace_shape_guess_rate(SHAPE_SET)` (50,000 samples, seed 0; the
# test recomputes it with fewer).
TRACE_SHAPE_SETS: dict[str, tuple[int, ...]] = {"Easy": (0,), "Medium": (0, 1), "Hard": (0, 1, 2)}
TRACE_SHAPE_GUESS_RATES: dict[str, float] = {"Easy": 0.0589, "Medium": 0.0301, "Hard": 0.0168}
# Both trace families: where the green cube starts (GREEN_CUBE_POSITION), the guessed route's start.
TRACE_SHAPE_CUBE_START = (-0.26, 0.0)
# TraceShapeSeq: SEQUENCE_LEN_RANGE; variant -> trace_shape_guess_rate(SHAPE_SET, lengths=...,
# shapes_shown=True) (30,000 samples, seed 0).
TRACE_SHAPE_SEQ_LENGTHS = (2, 5)
TRACE_SHAPE_SEQ_GUESS_RATES: dict[str, float] = {"Easy": 0.0242, "Medium": 0.0083, "Hard": 0.0056}



def _variant(env_id: str, family_prefix: str) -> str:
    """``BlinkCountButtonPressEasy-Long-VLA-v0`` -> ``Easy-Long`` (prefix ``BlinkCountButtonPress``)."""
    return env_id[len(family_prefix) :].removesuffix("-VLA-v0")


def _selection_candidates(env_id: str) -> int:
    """N objects on the table in the action phase, from the id (``…3x2…`` -> 6, ``…9…`` -> 9)."""
    m = re.search(r"(\d+)x(\d+)", env_id)
    if m:
        return int(m.group(1)) * int(m.group(2))
    m = re.search(r"(?:Color|Shape)(\d+)", env_id)
    if m is None:
        raise ValueError(f"cannot tell the number of candidates of {env_id!r}")
    return int(m.group(1))


def _sequence_length(env_id: str) -> int:
    m = re.search(r"Colors(\d+)", env_id)
    if m is None:
        raise ValueError(f"cannot tell the sequence length of {env_id!r}")
    return int(m.group(1))


def take_it_back_chance() -> float:
    """P(a guessed row centre lies within the success radius of the true start).

    The start is x ~ U[START_X), y = 0.1·j + U[0, 0.05) with j ~ U{−1, 0, 1}; the guess is
    (centre of START_X, 0.1·j' + 0.025) with j' uniform. The guessed row always succeeds
    (its corners are 0.056 away); a neighbouring row only where its near edge comes within
    the radius (a midpoint integral over the row's y jitter).
    """
    x_lo, x_hi = TAKE_IT_BACK_START_X
    width, jitter, r = x_hi - x_lo, TAKE_IT_BACK_ROW_JITTER, TAKE_IT_BACK_RADIUS
    near = TAKE_IT_BACK_ROW_STEP - jitter / 2  # y gap from a row centre to the next row's near edge
    n = 20_000
    share = 0.0
    for i in range(n):
        dy = near + (i + 0.5) / n * jitter
        if dy < r:
            share += min(2 * math.sqrt(r * r - dy * dy), width) / width
    neighbour = share / n
    mean_neighbours = 4 / 3  # rows −1 and 1 have one neighbour, row 0 two
    return (1 + mean_neighbours * neighbour) / 3


def timed_transfer_chance(delay: int) -> tuple[float, int, int]:
    """(chance, window width, steps up to the window's end) for a delay of ``delay`` steps."""
    lo = int((1 - TIMED_TRANSFER_TOLERANCE) * delay)
    hi = int((1 + TIMED_TRANSFER_TOLERANCE) * delay)
    signal = sum(TIMED_TRANSFER_SIGNAL_STEPS) / 2
    width = hi - lo + 1
    end = signal + hi + 1
    return width / end, width, int(end)


def coupon_chance(n: int, draws: int) -> float:
    """P(``draws`` uniform picks among ``n`` items pick every item) (inclusion-exclusion)."""
    return sum((-1) ** j * math.comb(n, j) * ((n - j) / n) ** draws for j in range(n + 1))


def trace_shape_guess_rate(
    shape_set: tuple[int, ...],
    samples: int = 200_000,
    seed: int = 0,
    lengths: tuple[int, int] = (1, 1),
    shapes_shown: bool = False,
    cube_start: tuple[float, float] = TRACE_SHAPE_CUBE_START,
    passes: int = 2,
) -> float:
    """Monte Carlo chance of TraceShape (``lengths`` (1, 1)) or TraceShapeSeq (``lengths``
    its sequence-length range, ``shapes_shown``: the shapes, and so their number, are in
    ``task_cue``): the share of episodes that a blind guesser passes. It guesses one contour
    per element from the task's prior — one centre for all, per element a size, a rotation
    and (unless shown) a shape, drawn as the env draws them — and traces them one after the
    other as the memoryless oracle does: a straight move from where the cube is
    (``cube_start``, then the previous contour's start) to the guessed start, then ``passes``
    times round the guessed checkpoints and back, 8 points per straight move. Along that
    route the env's latch rules run on the true contours: only the active element scores;
    its checkpoint 0 latches first (within the checkpoint radius), then the others; farther
    than ``STRAY_RADIUS`` from its contour clears it; all latched and back at checkpoint 0
    closes it and makes the next one active (so any guessed contour may close any element,
    in order). Imports the env module for its geometry."""
    import numpy as np
    import torch
    from mikasa_envs.tasks._trace_shape import TraceShapeCommonVLABaseEnv as env
    from mikasa_envs.tasks._trace_shape import (
        advance_latches,
        checkpoints_of,
        is_closed,
        shape_waypoints,
    )

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
        corners = [np.broadcast_to(np.asarray(cube_start, dtype=np.float64), (n, 2))]
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


def task_chance(env_id: str) -> Chance:
    """The chance success rate of ``env_id`` (a manifest id) and its one-line reason."""
    from mikasa_envs.manifest import SELECTION_FAMILIES, SHELL_GAME_FAMILIES, get_task

    task = get_task(env_id)
    family = task.family
    if family in SELECTION_FAMILIES:
        n = _selection_candidates(env_id)
        which = "find the imposter among" if family.startswith("find") else "the shown one is one of"
        return Chance(1 / n, f"1/{n}: {which} the {n} objects on the table in the action phase")
    if family in SHELL_GAME_FAMILIES:
        return Chance(1 / 3, "1/3: the ball's mug is one of 3 mugs")
    if family in ("bunch_of_colors", "seq_of_colors", "chain_of_colors"):
        length = _sequence_length(env_id)
        if family == "bunch_of_colors":
            sets = math.comb(NUM_COLORS, length)
            return Chance(1 / sets, f"1/C(9,{length}) = 1/{sets}: the shown set of {length} of 9 cubes")
        orders = math.perm(NUM_COLORS, length)
        return Chance(1 / orders, f"1/P(9,{length}) = 1/{orders}: the shown sequence of {length} of 9 cubes")
    if family == "blink_count_button_press":
        lo, hi = BLINK_COUNT_RANGES[_variant(env_id, "BlinkCountButtonPress")]
        k = hi - lo + 1
        return Chance(1 / k, f"1/{k}: the blink count is one of {lo}..{hi}")
    if family == "gather_and_recall":
        return Chance(1 / 3, "1/3: the flash colour is one of 3 buttons")
    if family == "take_it_back":
        return Chance(
            take_it_back_chance(),
            "≈1/3: the start is in one of 3 rows; a guess at a row's centre is within the "
            "0.08 radius of every start of that row (and of a sliver of a neighbouring row)",
        )
    if family in ("rotate_lenient", "rotate_strict"):
        t = ROTATE_ANGLE_THRESHOLD
        return Chance(
            t / math.pi,
            f"{t}/π: no discrete answer; the unseen start heading is uniform in [0, 2π), and a "
            f"guess succeeds within ±{t} rad of it",
        )
    if family == "timed_transfer":
        rate, width, end = timed_transfer_chance(TIMED_TRANSFER_DELAYS[_variant(env_id, "TimedTransfer")])
        return Chance(
            rate,
            f"{width}/{end}: no discrete answer (a time); the window's share of the steps up to "
            f"its end bounds a clockless policy that descends with a constant probability per step",
        )
    if family in BATTERY_CYCLE_STEPS:
        n = int(re.search(r"-(\d+)-VLA", env_id).group(1))  # type: ignore[union-attr]
        cycles = task.max_episode_steps // BATTERY_CYCLE_STEPS[family]
        return Chance(
            coupon_chance(n, cycles),
            f"no discrete answer (a checklist): {cycles} check cycles fit the horizon; chance that "
            f"cycles on uniformly drawn batteries cover all {n}",
        )
    if family in ("intercept", "intercept_grab"):
        return Chance(
            0.0,
            "0: no discrete answer; the ball's start and launch velocity are continuous, and after "
            "its first 10 frames it is out of view until touched, so meeting it without memory "
            "takes a lucky guess of a continuous path",
        )
    if family == "trace_shape":
        variant = _variant(env_id, "TraceShape")
        return Chance(
            TRACE_SHAPE_GUESS_RATES[variant],
            f"no discrete answer; a contour guessed from the prior ({len(TRACE_SHAPE_SETS[variant])} "
            "shape(s), centre, size, rotation), traced twice from its start, closes the true one (all 12 "
            "checkpoints within 3.5 cm, never 6 cm off it) at this rate",
        )
    if family == "trace_shape_seq":
        variant = _variant(env_id, "TraceShapeSeq")
        lo, hi = TRACE_SHAPE_SEQ_LENGTHS
        return Chance(
            TRACE_SHAPE_SEQ_GUESS_RATES[variant],
            f"no discrete answer; {lo}-{hi} contours about one centre, their shapes shown in "
            "task_cue: contours guessed from the prior (centre, sizes, rotations), each traced twice "
            "in turn, close all of "
            "them (every checkpoint within 3.5 cm, never 6 cm off) at this rate",
        )
    raise ValueError(f"no chance rate for {env_id!r} (family {family!r})")


def chance_table(env_ids: Iterable[str]) -> dict[str, Chance]:
    """`task_chance` of every id."""
    return {env_id: task_chance(env_id) for env_id in env_ids}
