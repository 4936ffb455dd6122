"""Comparing two runs task by task.

For every task present in both runs: the success-rate difference B − A with Newcombe's
hybrid score interval (built from the two Wilson intervals). A task *regresses* when the
whole interval lies below zero, i.e. B is significantly worse than A at level ``alpha``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

from mikasa_bench.results.metrics import newcombe_difference_interval
from mikasa_bench.results.run_data import RunData
from mikasa_bench.results.text import format_percent, format_rows

__all__ = ["TaskDelta", "Comparison", "compare_runs", "format_comparison"]

_PROTOCOL_KEYS = (
    "start_seed",
    "n_episodes",
    "obs_mode",
    "control_mode",
    "reward_mode",
    "wrapper_chain",
)


@dataclass(frozen=True)
class TaskDelta:
    """One task's comparison: both rates, the difference and its interval, the verdict."""

    env_id: str
    sr_a: float
    sr_b: float
    n_a: int
    n_b: int
    delta: float
    lower: float
    upper: float
    return_a: float
    return_b: float

    @property
    def verdict(self) -> str:
        """``worse`` / ``better`` (significant) or ``n.s.``."""
        if self.upper < 0:
            return "worse"
        if self.lower > 0:
            return "better"
        return "n.s."


@dataclass
class Comparison:
    """All task deltas plus tasks missing on either side and protocol mismatches."""

    label_a: str
    label_b: str
    alpha: float
    deltas: list[TaskDelta]
    only_a: list[str] = field(default_factory=list)
    only_b: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def regressions(self) -> list[TaskDelta]:
        """Tasks on which B is significantly worse than A."""
        return [d for d in self.deltas if d.verdict == "worse"]


def compare_runs(a: RunData, b: RunData, alpha: float = 0.05) -> Comparison:
    """Compare run B against baseline A (two-sided interval at level ``alpha``)."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    z = NormalDist().inv_cdf(1 - alpha / 2)
    by_a = {r["env_id"]: r for r in a.results}
    by_b = {r["env_id"]: r for r in b.results}
    deltas = []
    for env_id, ra in by_a.items():
        rb = by_b.get(env_id)
        if rb is None:
            continue
        sa, na = sum(bool(x) for x in ra["successes"]), len(ra["successes"])
        sb, nb = sum(bool(x) for x in rb["successes"]), len(rb["successes"])
        d, lo, hi = newcombe_difference_interval(sa, na, sb, nb, z)
        deltas.append(
            TaskDelta(
                env_id,
                sa / na,
                sb / nb,
                na,
                nb,
                d,
                lo,
                hi,
                float(ra["mean_return"]),
                float(rb["mean_return"]),
            )
        )
    comp = Comparison(
        a.label,
        b.label,
        alpha,
        deltas,
        only_a=[i for i in by_a if i not in by_b],
        only_b=[i for i in by_b if i not in by_a],
    )
    pa, pb = a.protocol, b.protocol
    for key in _PROTOCOL_KEYS:
        if key in pa and key in pb and pa[key] != pb[key]:
            comp.warnings.append(f"protocols differ: {key} = {pa[key]!r} (A) vs {pb[key]!r} (B)")
    for env_id in by_a:
        if env_id in by_b and by_a[env_id].get("episode_seeds") != by_b[env_id].get(
            "episode_seeds"
        ):
            comp.warnings.append(f"{env_id}: the runs used different episode seeds")
    return comp


def format_comparison(comp: Comparison) -> str:
    """A plain-text table of the comparison and a one-line verdict."""
    conf = f"{100 * (1 - comp.alpha):.0f}%"
    header = [
        "Task",
        f"SR A ({comp.label_a})",
        f"SR B ({comp.label_b})",
        "Δ SR (B−A)",
        f"{conf} CI of Δ",
        "Δ return",
        "Verdict",
    ]
    rows: list[list[Any]] = [
        [
            d.env_id,
            f"{format_percent(d.sr_a)} (n={d.n_a})",
            f"{format_percent(d.sr_b)} (n={d.n_b})",
            f"{100 * d.delta:+.0f} pp",
            f"[{100 * d.lower:+.0f}, {100 * d.upper:+.0f}] pp",
            f"{d.return_b - d.return_a:+.2f}",
            d.verdict,
        ]
        for d in comp.deltas
    ]
    lines = []
    if rows:
        lines.append(format_rows(header, rows, right={3, 5}))
    else:
        lines.append("no task appears in both runs")
    for title, ids in (("only in A", comp.only_a), ("only in B", comp.only_b)):
        if ids:
            lines.append(f"{title}: {', '.join(ids)}")
    lines += [f"warning: {w}" for w in comp.warnings]
    reg = comp.regressions
    if reg:
        lines.append(
            f"B is significantly worse than A on {len(reg)} task(s): "
            + ", ".join(d.env_id for d in reg)
        )
    else:
        lines.append("B is not significantly worse than A on any task")
    return "\n".join(lines)
