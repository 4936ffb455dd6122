"""Reading finished runs back (report, compare, validity): `load_run` and its `RunData`."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.reference import is_reference, resolve_reference
from mikasa_bench.results.files import SUMMARY_FILENAME, read_json

__all__ = ["RunData", "load_run"]

_TASK_KEYS = ("env_id", "split", "memory_type", "successes", "returns", "sr")


@dataclass
class RunData:
    """A results directory as read back: per-task results (in run order), the summary."""

    run_dir: Path
    label: str
    results: list[dict[str, Any]]
    summary: dict[str, Any] | None
    source: str = ""  # how the user named it, where that is not the path (reference:<name>)

    @property
    def protocol(self) -> dict[str, Any]:
        """The summary's protocol record, or one reconstructed from the task files."""
        if self.summary and isinstance(self.summary.get("protocol"), dict):
            return self.summary["protocol"]
        r = self.results[0]
        return {k: r.get(k) for k in ("start_seed", "n_episodes", "obs_mode", "control_mode")}


def load_run(run_dir: str | Path, label: str | None = None) -> RunData:
    """Read a results directory (every ``*.json`` but ``summary.json`` is a task file), or a
    result set shipped with the package, named ``reference:<name>`` (`mikasa_bench.reference`).

    Raises `BenchError` if the directory is missing, unreadable, holds a malformed file, or
    has no task results, or if there is no reference set of that name.
    """
    source = str(run_dir) if is_reference(run_dir) else ""
    run_dir = resolve_reference(source) if source else Path(run_dir)
    if not run_dir.is_dir():
        raise BenchError(
            f"results directory {run_dir} does not exist; expected a directory written by "
            f"`mikasa-bench run` (with <env_id>.json files and summary.json)"
        )
    try:
        files = sorted(p for p in run_dir.glob("*.json") if p.name != SUMMARY_FILENAME)
    except OSError as exc:
        raise BenchError(f"cannot read results directory {run_dir}: {exc}") from None
    by_id: dict[str, dict[str, Any]] = {}
    for path in files:
        data = read_json(path)
        if not isinstance(data, dict) or not all(k in data for k in _TASK_KEYS):
            continue  # not a task result (e.g. a user's note): ignored like upstream's loader
        by_id[data["env_id"]] = data
    if not by_id:
        raise BenchError(
            f"{run_dir} contains no per-task result files; expected <env_id>.json files with "
            f"keys {', '.join(_TASK_KEYS)} written by `mikasa-bench run`"
        )
    summary_path = run_dir / SUMMARY_FILENAME
    summary = read_json(summary_path) if summary_path.exists() else None
    order: Iterable[str] = (summary or {}).get("tasks") or []
    ordered = [by_id[i] for i in order if i in by_id]
    ordered += [r for i, r in by_id.items() if i not in set(order)]
    if label is None:
        model = (summary or {}).get("model") or ordered[0].get("model") or {}
        label = model.get("name") or run_dir.name
    return RunData(run_dir, str(label), ordered, summary, source)
