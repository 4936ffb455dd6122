"""Metrics: Wilson intervals, the spec summary and its aggregations (benchmark.md §7.2)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    "Z_95",
    "wilson_interval",
    "newcombe_difference_interval",
    "summarize_task_results",
    "aggregate_by",
]

Z_95 = 1.959963984540054
"""Two-sided 95 % standard-normal quantile."""


def wilson_interval(successes: int, n: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default).

    Well behaved at 0/n and n/n, unlike the normal approximation; ``n == 0`` gives
    ``(0.0, 1.0)`` (no information).
    """
    if n < 0 or successes < 0 or successes > n:
        raise ValueError(f"need 0 <= successes <= n, got successes={successes}, n={n}")
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    center = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    # The exact interval ends at 0 for 0/n and at 1 for n/n (the float arithmetic leaves
    # ~1e-17 there, which would read as "above a chance of 0"); clamp rounding noise.
    lower = 0.0 if successes == 0 else max(0.0, center - half)
    upper = 1.0 if successes == n else min(1.0, center + half)
    return lower, upper


def newcombe_difference_interval(
    s_a: int, n_a: int, s_b: int, n_b: int, z: float = Z_95
) -> tuple[float, float, float]:
    """Newcombe's hybrid score interval for ``p_b - p_a`` from the two Wilson intervals.

    Returns ``(difference, lower, upper)``; B is significantly worse than A (at the level
    of ``z``) iff ``upper < 0``. Chosen because it is consistent with the per-task Wilson
    intervals that the reports show and stays valid for small n and 0 % / 100 % rates.
    """
    p_a, p_b = s_a / n_a, s_b / n_b
    l_a, u_a = wilson_interval(s_a, n_a, z)
    l_b, u_b = wilson_interval(s_b, n_b, z)
    d = p_b - p_a
    lower = d - math.sqrt((p_b - l_b) ** 2 + (u_a - p_a) ** 2)
    upper = d + math.sqrt((u_b - p_b) ** 2 + (p_a - l_a) ** 2)
    return d, lower, upper


def _mean(values: Sequence[float]) -> float:
    return float(sum(values) / len(values)) if values else float("nan")


def summarize_task_results(results: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The spec summary of per-task result dicts (keys and order of benchmark.md §7.2).

    ``sr_split`` counts each env id once (last value wins); ``sr_per_memory_type`` counts
    repeated ids each time (upstream quirk, kept for parity).
    """
    if not results:
        raise ValueError("cannot summarize an empty list of task results")
    per_task: dict[str, Mapping[str, Any]] = {}
    for r in results:
        per_task[r["env_id"]] = r
    splits = {r["split"] for r in results}
    by_type: dict[str, list[float]] = {}
    for r in results:
        by_type.setdefault(r["memory_type"], []).append(float(r["sr"]))
    return {
        "split": splits.pop() if len(splits) == 1 else "Custom",
        "sr_split": _mean([float(r["sr"]) for r in per_task.values()]),
        "sr_per_memory_type": {k: _mean(by_type[k]) for k in sorted(by_type)},
        "tasks": list(per_task),
        "per_task_sr": {k: float(r["sr"]) for k, r in per_task.items()},
        "per_task_mean_return": {k: float(r["mean_return"]) for k, r in per_task.items()},
    }


def aggregate_by(
    results: Sequence[Mapping[str, Any]], *keys: str, value: str = "sr"
) -> dict[Any, Any]:
    """Mean of ``value`` over tasks grouped by one key, or nested by two (e.g. split then
    memory type); groups keep first-appearance order."""
    out: dict[Any, Any] = {}
    if len(keys) == 1:
        groups: dict[Any, list[float]] = {}
        for r in results:
            groups.setdefault(r[keys[0]], []).append(float(r[value]))
        return {k: _mean(v) for k, v in groups.items()}
    outer: dict[Any, list[Mapping[str, Any]]] = {}
    for r in results:
        outer.setdefault(r[keys[0]], []).append(r)
    for k, rs in outer.items():
        out[k] = aggregate_by(rs, *keys[1:], value=value)
    return out
