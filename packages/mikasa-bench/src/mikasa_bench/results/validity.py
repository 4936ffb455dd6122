"""The validity table: does each task need memory?

From result directories of the four reference policies (``oracle``, ``oracle-memoryless``,
``random``, ``zero``; any mix of run directories and directories of runs), per task: the
success rate of each with its Wilson 95 % interval, the chance rate
(`mikasa_bench.results.chance`) and flags where something is off:

* ``oracle<95%``: the oracle's success rate is below 95 %;
* ``zero>0``: the zero policy succeeded at least once;
* ``memoryless>chance`` / ``random>chance``: the lower end of that policy's Wilson
  interval lies above chance, i.e. it does significantly better than guessing: the task
  shows its answer without memory (a leak to find and close).

Writes Markdown (``--out``, e.g. ``docs/VALIDITY.md``) and JSON next to it, with the
hand-maintained list of leaks (`mikasa_bench.results.leaks`). ``--update`` an earlier JSON keeps its
rows for the tasks the new directories do not cover (after a change to some tasks, rerun
only those). Command line::

    python -m mikasa_bench.results.validity RESULT_DIR... [--out docs/VALIDITY.md] [--leaks FILE.json]
        [--update docs/VALIDITY.json]

(also ``mikasa-bench validity`` where the CLI wires `add_validity_parser`).
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.reference import is_reference, resolve_reference
from mikasa_bench.results.chance import task_chance
from mikasa_bench.results.files import SUMMARY_FILENAME, atomic_write_json
from mikasa_bench.results.leaks import LEAK_STATUSES, LEAKS, Leak
from mikasa_bench.results.metrics import wilson_interval
from mikasa_bench.results.run_data import load_run

__all__ = [
    "POLICY_COLUMNS",
    "Tally",
    "TaskValidity",
    "collect_tallies",
    "earlier_tallies",
    "validity_rows",
    "validity_markdown",
    "write_validity",
    "add_validity_parser",
    "run_validity",
    "main",
]

# Policy target (as recorded in result files) -> column title, in table order.
POLICY_COLUMNS: dict[str, str] = {
    "oracle": "oracle",
    "oracle-memoryless": "memoryless",
    "random": "random",
    "zero": "zero",
}
ORACLE_MIN_SR = 0.95


@dataclass
class Tally:
    """Episode outcomes of one policy on one task, by episode seed (runs merge by seed),
    or the counts of an earlier table (``--update``), whose seeds it does not keep."""

    by_seed: dict[int, bool] = field(default_factory=dict)
    # (episodes, successes) carried over from an earlier table.
    earlier: tuple[int, int] = (0, 0)

    @property
    def n(self) -> int:
        """Episodes."""
        return len(self.by_seed) + self.earlier[0]

    @property
    def successes(self) -> int:
        """Successful episodes."""
        return sum(self.by_seed.values()) + self.earlier[1]

    @property
    def sr(self) -> float:
        """Success rate (nan without episodes)."""
        return self.successes / self.n if self.n else float("nan")

    def ci95(self) -> tuple[float, float]:
        """Wilson 95 % interval."""
        return wilson_interval(self.successes, self.n)


@dataclass
class TaskValidity:
    """One row of the table."""

    env_id: str
    family: str
    chance: float
    chance_reason: str
    tallies: dict[str, Tally]
    flags: list[str]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        policies = {}
        for target, tally in self.tallies.items():
            lo, hi = tally.ci95()
            policies[target] = {
                "n": tally.n,
                "successes": tally.successes,
                "sr": tally.sr if tally.n else None,
                "sr_ci95": [lo, hi] if tally.n else None,
            }
        return {
            "env_id": self.env_id,
            "family": self.family,
            "chance": self.chance,
            "chance_reason": self.chance_reason,
            "policies": policies,
            "flags": list(self.flags),
        }


def _run_dirs(given: str | Path) -> list[Path]:
    """``given`` if it holds task result files, else its subdirectories that do; a shipped
    ``reference:<name>`` set is its own directory."""
    if is_reference(given):
        return [resolve_reference(str(given))]
    path = Path(given)
    if not path.is_dir():
        raise BenchError(f"results directory {path} does not exist")

    def has_results(d: Path) -> bool:
        return any(p.name != SUMMARY_FILENAME for p in d.glob("*.json"))

    if has_results(path):
        return [path]
    subs = sorted(d for d in path.iterdir() if d.is_dir() and has_results(d))
    if not subs:
        raise BenchError(
            f"{path} holds no result files; expected a directory written by `mikasa-bench run` "
            f"(<env_id>.json files) or a directory of such runs"
        )
    return subs


def _target(result: dict[str, Any]) -> str:
    model = result.get("model") or {}
    return str(model.get("target") or model.get("name") or "")


def collect_tallies(dirs: Iterable[str | Path]) -> tuple[dict[str, dict[str, Tally]], list[str]]:
    """(env_id -> policy target -> `Tally`, notes) over every run under ``dirs``.

    Episodes of the same policy and task from several runs merge by episode seed (a seed
    seen twice keeps its first outcome, with a note); runs of other policies are skipped
    with a note.
    """
    tallies: dict[str, dict[str, Tally]] = {}
    notes: list[str] = []
    for given in dirs:
        for run_dir in _run_dirs(given):
            run = load_run(run_dir)
            for result in run.results:
                target = _target(result)
                if target not in POLICY_COLUMNS:
                    notes.append(f"{run_dir}: policy {target!r} is not one of {', '.join(POLICY_COLUMNS)}; skipped")
                    break
                tally = tallies.setdefault(result["env_id"], {}).setdefault(target, Tally())
                seeds = result.get("episode_seeds") or [
                    int(result.get("start_seed", 0)) + i for i in range(len(result["successes"]))
                ]
                repeated = 0
                for seed, success in zip(seeds, result["successes"], strict=True):
                    if int(seed) in tally.by_seed:
                        repeated += 1
                        continue
                    tally.by_seed[int(seed)] = bool(success)
                if repeated:
                    notes.append(f"{run_dir}: {result['env_id']} ({target}): {repeated} seed(s) already counted; kept the first")
    return tallies, notes


def earlier_tallies(json_path: str | Path) -> tuple[dict[str, dict[str, Tally]], list[str]]:
    """(env_id -> policy target -> `Tally`, sources) from a VALIDITY.json written earlier."""
    try:
        data = json.loads(Path(json_path).read_text(encoding="utf-8"))
        tallies = {
            task["env_id"]: {
                target: Tally(earlier=(int(cell["n"]), int(cell["successes"])))
                for target, cell in task["policies"].items()
                if target in POLICY_COLUMNS and cell["n"]
            }
            for task in data["tasks"]
        }
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise BenchError(
            f"cannot read the earlier table {json_path}: {exc}; expected the VALIDITY.json that "
            "`mikasa-bench validity` wrote (keys tasks -> env_id, policies -> n, successes)"
        ) from None
    return tallies, [str(s) for s in data.get("sources", [])]


def _flags(tallies: dict[str, Tally], chance: float) -> list[str]:
    flags = []
    oracle = tallies.get("oracle")
    if oracle is not None and oracle.n and oracle.sr < ORACLE_MIN_SR:
        flags.append("oracle<95%")
    zero = tallies.get("zero")
    if zero is not None and zero.successes > 0:
        flags.append("zero>0")
    for target in ("oracle-memoryless", "random"):
        tally = tallies.get(target)
        if tally is not None and tally.n and tally.ci95()[0] > chance:
            flags.append(f"{POLICY_COLUMNS[target]}>chance")
    return flags


def _manifest_order(env_ids: Iterable[str]) -> list[str]:
    from mikasa_envs.manifest import list_tasks

    order = {t.env_id: i for i, t in enumerate(list_tasks(include_extra=True))}
    return sorted(env_ids, key=lambda e: (order.get(e, len(order)), e))


def validity_rows(tallies: dict[str, dict[str, Tally]]) -> list[TaskValidity]:
    """One `TaskValidity` per task, in manifest order."""
    from mikasa_envs.manifest import get_task

    rows = []
    for env_id in _manifest_order(tallies):
        chance = task_chance(env_id)
        per_policy = tallies[env_id]
        rows.append(
            TaskValidity(
                env_id=env_id,
                family=get_task(env_id).family,
                chance=chance.rate,
                chance_reason=chance.reason,
                tallies=per_policy,
                flags=_flags(per_policy, chance.rate),
            )
        )
    return rows


def _pct(x: float) -> str:
    return f"{100 * x:.0f}%" if x >= 0.01 or x == 0 else f"{100 * x:.2g}%"


def _cell(tally: Tally | None) -> str:
    if tally is None or not tally.n:
        return "—"
    lo, hi = tally.ci95()
    return f"{_pct(tally.sr)} [{_pct(lo)}, {_pct(hi)}] ({tally.successes}/{tally.n})"


def _wrapped(text: str) -> str:
    return textwrap.fill(text, width=100, break_on_hyphens=False, break_long_words=False)


def _item(text: str) -> str:
    """A Markdown list item, wrapped."""
    return textwrap.fill(
        text, width=100, initial_indent="- ", subsequent_indent="  ", break_on_hyphens=False, break_long_words=False
    )


def _md_escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def validity_headline(rows: Sequence[TaskValidity]) -> str:
    """One sentence of the table's findings: per check, on how many tasks it holds."""
    n = len(rows)

    def holds(flag: str) -> int:
        return sum(1 for r in rows if flag not in r.flags)

    return (
        f"**The oracle reaches at least {ORACLE_MIN_SR:.0%} on {holds('oracle<95%')} of {n} tasks; "
        f"without its memory it stays at or below chance on {holds('memoryless>chance')} of {n}; "
        f"random actions stay at or below chance on {holds('random>chance')} of {n}; zero actions "
        f"never succeed on {holds('zero>0')} of {n}.**"
    )


def validity_markdown(
    rows: Sequence[TaskValidity], leaks: Sequence[Leak], notes: Sequence[str] = (), sources: Sequence[str] = ()
) -> str:
    """The Markdown document (see the module docstring)."""
    from mikasa_envs.manifest import canonical_env_ids

    out = ["# Validity: does each task need memory?", "", validity_headline(rows), ""]
    out += [
        "Generated by `mikasa-bench validity` (`python -m mikasa_bench.results.validity`) from result "
        "directories of the oracle, the memoryless oracle (`--policy oracle-memoryless`: the "
        "same controller, its memory of the answer wiped before every step, guessing where "
        "the current frame does not show the answer), the seeded random policy and the zero "
        "policy. Do not edit by hand: rerun the command.",
        "",
        "Each cell: success rate, Wilson 95 % interval, (successes/episodes). Expected: "
        f"oracle ≥ {ORACLE_MIN_SR:.0%}, zero 0 %, memoryless and random at or below chance. "
        "Flags: `oracle<95%`, `zero>0`, and `memoryless>chance` / `random>chance` where the "
        "lower end of the interval lies above chance (significantly better than guessing: the "
        "task leaks its answer). Chance per task is explained below the table "
        "(`mikasa_bench.results.chance`).",
        "",
    ]
    out = [_wrapped(line) for line in out]
    if sources:
        out += [_wrapped("Result directories: " + ", ".join(f"`{s}`" for s in sources)), ""]
    missing = [e for e in canonical_env_ids() if e not in {r.env_id for r in rows}]
    if missing:
        out += [_wrapped(f"Canonical tasks without results ({len(missing)}): " + ", ".join(missing)), ""]
    covered = {
        name: sum(1 for r in rows if r.tallies.get(key) is not None and r.tallies[key].n)
        for key, name in POLICY_COLUMNS.items()
    }
    if any(n < len(rows) for n in covered.values()):
        out += [
            "Tasks with results per policy (— in a cell: none yet): "
            + ", ".join(f"{name} {n}/{len(rows)}" for name, n in covered.items()),
            "",
        ]
    header = ["Task", "Chance", *POLICY_COLUMNS.values(), "Flags"]
    out += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [f"`{row.env_id}`", _pct(row.chance)]
        cells += [_cell(row.tallies.get(target)) for target in POLICY_COLUMNS]
        cells.append(", ".join(f"**{f}**" for f in row.flags) or "")
        out.append("| " + " | ".join(cells) + " |")
    flagged = [r for r in rows if r.flags]
    out += ["", f"{len(rows)} task(s); {len(flagged)} flagged.", ""]

    out += ["## Chance", ""]
    by_reason: dict[tuple[str, str], list[str]] = {}
    for row in rows:
        by_reason.setdefault((row.family, row.chance_reason), []).append(row.env_id)
    for (family, reason), ids in by_reason.items():
        out.append(_item(f"**{family}** ({', '.join(f'`{e}`' for e in ids)}): {_md_escape(reason)}"))
    out.append("")

    out += ["## Leaks found", ""]
    out += [
        _wrapped(
            "Hand-maintained (`mikasa_bench.results.leaks`). Status: "
            + ", ".join(LEAK_STATUSES)
            + " (closed: fixed in the envs; open: not fixed yet; kept: known and kept on purpose)."
        ),
        "",
    ]
    for leak in leaks:
        parts = [f"**{leak.tasks}** ({leak.status}). Leak: {leak.leak}. Evidence: {leak.evidence}."]
        parts += [f"Fix: {leak.fix}."] if leak.fix else []
        parts += [f"({leak.reference})"] if leak.reference else []
        out.append(_item(_md_escape(" ".join(parts))))
    if notes:
        out += ["", "## Notes", ""] + [_item(_md_escape(n)) for n in notes]
    return "\n".join(out) + "\n"


def _load_leaks(path: str | None) -> list[Leak]:
    if path is None:
        return list(LEAKS)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        leaks = [Leak(**entry) for entry in data]
    except (OSError, json.JSONDecodeError, TypeError) as exc:
        raise BenchError(
            f"cannot read the leaks list {path}: {exc}; expected a JSON list of objects with keys "
            "tasks, leak, evidence, status[, fix, reference]"
        ) from None
    bad = [leak.status for leak in leaks if leak.status not in LEAK_STATUSES]
    if bad:
        raise BenchError(f"{path}: unknown leak status {bad[0]!r}; expected one of {', '.join(LEAK_STATUSES)}")
    return leaks


def write_validity(
    dirs: Sequence[str | Path], out: str | Path, leaks_path: str | None = None, update: str | Path | None = None
) -> tuple[Path, Path, list[TaskValidity]]:
    """Write ``out`` (Markdown) and ``out`` with suffix ``.json``; returns (md, json, rows).

    ``update``: an earlier VALIDITY.json whose rows stand for the tasks ``dirs`` do not cover.
    """
    if not dirs and update is None:
        raise BenchError("give result directories, or --update an earlier VALIDITY.json to rewrite its table")
    tallies, notes = collect_tallies(dirs) if dirs else ({}, [])
    if dirs and not tallies:
        raise BenchError(f"no results of the policies {', '.join(POLICY_COLUMNS)} under {', '.join(map(str, dirs))}")
    leaks = _load_leaks(leaks_path)
    sources = [str(d) for d in dirs]
    if update is not None:
        earlier, earlier_sources = earlier_tallies(update)
        earlier_sources = [s for s in earlier_sources if s not in sources]
        if dirs:
            notes.append(
                f"{', '.join(_manifest_order(tallies))}: from {', '.join(sources)}; the other rows from "
                f"the earlier table ({', '.join(earlier_sources) or update})"
            )
        else:  # the earlier table rewritten as it is (e.g. after a change of this generator)
            notes = list(json.loads(Path(update).read_text(encoding="utf-8")).get("notes", []))
        tallies = {**{e: t for e, t in earlier.items() if e not in tallies}, **tallies}
        sources = [*earlier_sources, *sources]
    rows = validity_rows(tallies)
    md_path = Path(out)
    json_path = md_path.with_suffix(".json")
    md_path.parent.mkdir(parents=True, exist_ok=True)
    md_path.write_text(validity_markdown(rows, leaks, notes, sources), encoding="utf-8")
    atomic_write_json(
        json_path,
        {
            "policies": POLICY_COLUMNS,
            "oracle_min_sr": ORACLE_MIN_SR,
            "sources": sources,
            "tasks": [r.to_dict() for r in rows],
            "flagged": [r.env_id for r in rows if r.flags],
            "leaks": [leak.to_dict() for leak in leaks],
            "notes": list(notes),
        },
    )
    return md_path, json_path, rows


def add_validity_parser(sub: Any) -> argparse.ArgumentParser:
    """Add the ``validity`` subcommand to an argparse subparsers object."""
    p = sub.add_parser(
        "validity",
        help="per-task oracle / memoryless / random / zero success vs chance, and the leaks list",
        description="Write the validity table (docs/VALIDITY.md and .json) from result directories "
        "of the oracle, oracle-memoryless, random and zero policies.",
    )
    p.add_argument(
        "dirs", nargs="*", metavar="DIR", help="run directories, or directories of runs (none: rewrite --update's table)"
    )
    p.add_argument("--out", default="docs/VALIDITY.md", metavar="PATH", help="Markdown output (JSON goes next to it)")
    p.add_argument("--leaks", default=None, metavar="JSON", help="leaks list to use instead of mikasa_bench.results.leaks")
    p.add_argument(
        "--update",
        default=None,
        metavar="JSON",
        help="an earlier VALIDITY.json: its rows stay for the tasks the DIRs do not cover (theirs replace the rest)",
    )
    return p


def run_validity(args: argparse.Namespace) -> int:
    """The ``validity`` subcommand; returns the exit code (0, or 2 on bad input)."""
    try:
        md, js, rows = write_validity(args.dirs, args.out, args.leaks, args.update)
    except BenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    flagged = [r for r in rows if r.flags]
    for r in flagged:
        print(f"{r.env_id}: {', '.join(r.flags)}")
    print(f"{len(rows)} task(s), {len(flagged)} flagged; wrote {md} and {js}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mikasa_bench.results.validity``."""
    parser = argparse.ArgumentParser(prog="mikasa-bench")
    add_validity_parser(parser.add_subparsers(dest="command", required=True))
    return run_validity(parser.parse_args(["validity", *(sys.argv[1:] if argv is None else argv)]))


if __name__ == "__main__":
    raise SystemExit(main())
