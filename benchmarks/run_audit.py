"""Audit a `mikasa-bench run` directory after a long, interrupted and resumed run.

Reads the episode journal (``meta/episodes.jsonl``), the sessions of ``meta/run.json`` and
the per-task files, and prints:

* whether anything was lost or repeated: episodes expected, recorded, missing, recorded
  twice, unreadable (torn) journal lines, and task files that disagree with the journal;
* per session (each `run` / `run --resume` of the directory): its start, workers, wall
  time, episodes, env steps and env steps/s (episodes carry their session's index from
  this version on; older journals show the totals only). A session's wall time is saved
  whenever one of its tasks finishes, so a session killed mid-task counts up to then;
* the totals: episodes, env steps, wall time summed over sessions, env steps/s.

Exit status 1 when something is missing, repeated, torn or inconsistent (a run still in
progress is "missing" until it ends), else 0.

    python benchmarks/run_audit.py results/canonical/zero [--json audit.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

from mikasa_bench.results.files import JOURNAL_FILENAME, META_DIRNAME, RUN_META_FILENAME


def _journal(path: Path) -> tuple[list[dict[str, Any]], int]:
    """Parsed journal records and the number of lines that are not valid JSON. Read-only:
    `RunStore.open` would cut a torn line away and stop at a bad one, hiding what we count."""
    records, torn = [], 0
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            torn += 1
    return records, torn


def audit(run_dir: Path) -> dict[str, Any]:
    """The audit of ``run_dir`` as a JSON-ready dict (see the module docstring)."""
    meta_dir = run_dir / META_DIRNAME
    meta_path, journal_path = meta_dir / RUN_META_FILENAME, meta_dir / JOURNAL_FILENAME
    for path in (meta_path, journal_path):
        if not path.is_file():
            raise SystemExit(
                f"error: {path} not found; expected a directory written by `mikasa-bench run`"
            )
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    n_episodes = int(meta["config"]["n_episodes"])
    tasks = [t["env_id"] for t in meta["tasks"]]
    records, torn = _journal(journal_path)

    counts = Counter((r["env_id"], int(r["episode"])) for r in records)
    expected = {(t, i) for t in tasks for i in range(n_episodes)}
    first = {}
    for r in records:
        first.setdefault((r["env_id"], int(r["episode"])), r)
    mismatched = []
    for env_id in tasks:
        task_file = run_dir / f"{env_id}.json"
        if not task_file.is_file():
            continue
        flags = json.loads(task_file.read_text(encoding="utf-8"))["successes"]
        journalled = [first.get((env_id, i), {}).get("success_once") for i in range(n_episodes)]
        if [bool(f) for f in flags] != journalled:
            mismatched.append(env_id)

    sessions = []
    for index, s in enumerate(meta.get("sessions", [])):
        mine = [r for r in records if r.get("session") == index]
        steps = sum(int(r["n_steps"]) for r in mine)
        wall = float(s.get("wall_time_s", 0.0))
        sessions.append(
            {
                "session": index,
                "started": s.get("started"),
                "workers": (s.get("execution") or {}).get("workers"),
                "wall_time_s": wall,
                "episodes": len(mine) if mine else None,
                "env_steps": steps if mine else None,
                "env_steps_per_s": steps / wall if mine and wall > 0 else None,
            }
        )
    total_steps = sum(int(r["n_steps"]) for r in first.values())
    total_wall = sum(s["wall_time_s"] for s in sessions)
    report = {
        "run_dir": str(run_dir),
        "policy": (meta.get("policy") or {}).get("label"),
        "tasks": len(tasks),
        "episodes_expected": len(expected),
        "episodes_recorded": len(first),
        "missing": len(expected - set(first)),
        "recorded_twice": sorted(f"{k[0]}#{k[1]}" for k, n in counts.items() if n > 1),
        "torn_lines": torn,
        "task_files_disagreeing_with_journal": mismatched,
        "sessions": sessions,
        "env_steps": total_steps,
        "wall_time_s": total_wall,
        "env_steps_per_s": total_steps / total_wall if total_wall > 0 else None,
    }
    report["ok"] = not (report["missing"] or report["recorded_twice"] or torn or mismatched)
    return report


def _print(report: dict[str, Any]) -> None:
    print(f"{report['run_dir']} ({report['policy']}, {report['tasks']} tasks)")
    print(
        f"episodes: {report['episodes_recorded']} of {report['episodes_expected']} recorded, "
        f"{report['missing']} missing, {len(report['recorded_twice'])} recorded twice, "
        f"{report['torn_lines']} torn journal lines, "
        f"{len(report['task_files_disagreeing_with_journal'])} task files disagreeing with the journal"
    )
    print(
        f"{'session':>7}  {'started':<25} {'workers':>7} {'wall s':>8} {'episodes':>8} {'env steps':>10} {'steps/s':>8}"
    )
    for s in report["sessions"]:
        cells = [
            f"{s['episodes']:>8}" if s["episodes"] is not None else f"{'?':>8}",
            f"{s['env_steps']:>10}" if s["env_steps"] is not None else f"{'?':>10}",
            f"{s['env_steps_per_s']:>8.0f}" if s["env_steps_per_s"] is not None else f"{'?':>8}",
        ]
        print(
            f"{s['session']:>7}  {s['started'] or '?':<25} {s['workers'] or '?':>7} {s['wall_time_s']:>8.1f} {' '.join(cells)}"
        )
    rate = report["env_steps_per_s"]
    print(
        f"total: {report['env_steps']} env steps in {report['wall_time_s']:.1f} s of sessions"
        + (f" ({rate:.0f} env steps/s)" if rate else "")
    )
    print("OK: nothing lost or repeated" if report["ok"] else "NOT OK (see above)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--json", type=Path, default=None, help="also write the audit here")
    args = parser.parse_args(argv)
    report = audit(args.run_dir)
    _print(report)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
