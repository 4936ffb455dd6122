"""Task manifest and task selection (benchmark.md §2, §4).

The benchmark's tasks are the rows of `mikasa_envs.manifest` (each family registers its own);
every function that reads them accepts ``csv_path``, a manifest in the upstream format
(semicolon-delimited, `MANIFEST_HEADER`; `manifest_csv_text` writes ours), to
run another task list. Registration checks (is the id registered with Gymnasium in this
installation?) live here too: a manifest passed with ``csv_path`` may name ids that no
installed package registers.
"""

from __future__ import annotations

import csv
import difflib
import io
import subprocess
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from mikasa_envs.manifest import list_tasks

from mikasa_bench.errors import BenchError, UnknownTaskError
from mikasa_bench.protocol import SUPPORTED_SPLITS

__all__ = [
    "MANIFEST_HEADER",
    "BenchmarkTask",
    "TaskSelection",
    "load_benchmark_tasks",
    "select_benchmark_tasks",
    "resolve_tasks",
    "registered_env_ids",
    "repository_root",
    "make_run_dir",
    "benchmark_commit",
    "manifest_csv_text",
]

MANIFEST_HEADER: tuple[str, ...] = (
    "id",
    "Name",
    "Max Length",
    "Memory Type",
    "Horizon Split",
    "Data Source",
    "language_instruction",
)


@dataclass(frozen=True)
class BenchmarkTask:
    """One task of the benchmark: a manifest row (``split`` is lowercase or ``custom``)."""

    env_id: str
    split: str
    memory_type: str
    max_episode_steps: int
    language_instruction: str = ""
    data_source: str = ""

    @classmethod
    def from_csv_row(cls, row: Mapping[str, str]) -> BenchmarkTask:
        """Parse one row of the upstream manifest (``;``-delimited dict-reader row)."""
        try:
            split = row["Horizon Split"].strip().lower()
            task = cls(
                env_id=row["Name"].strip(),
                split=split,
                memory_type=row["Memory Type"].strip(),
                max_episode_steps=int(row["Max Length"]),
                language_instruction=(row.get("language_instruction") or ""),
                data_source=(row.get("Data Source") or "").strip(),
            )
        except KeyError as exc:
            raise ValueError(
                f"manifest row lacks column {exc.args[0]!r}; expected header "
                f"{';'.join(MANIFEST_HEADER)}"
            ) from None
        if split not in SUPPORTED_SPLITS:
            raise ValueError(
                f"manifest row {task.env_id!r} has Horizon Split {row['Horizon Split']!r}; "
                f"expected one of Short, Medium, Long"
            )
        return task

    @classmethod
    def custom(cls, env_id: str) -> BenchmarkTask:
        """A task for an id that is not in the manifest (benchmark.md §4)."""
        return cls(env_id, "custom", "Unknown", 0, "", "custom")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready field mapping (round-trips through ``BenchmarkTask(**d)``)."""
        return asdict(self)


def repository_root() -> Path:
    """The monorepo root if this package runs from a source checkout, else the package dir."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / ".git").exists():
            return parent
    return here.parent


def manifest_csv_text() -> str:
    """The canonical rows of `mikasa_envs.manifest` in the upstream format (``;``-delimited,
    `MANIFEST_HEADER`), the format ``csv_path`` accepts."""
    buf = io.StringIO()
    writer = csv.writer(buf, delimiter=";", lineterminator="\n")
    writer.writerow(MANIFEST_HEADER)
    for i, t in enumerate(list_tasks(split="all"), start=1):
        writer.writerow(
            [
                i,
                t.env_id,
                t.max_episode_steps,
                t.memory_type,
                (t.split or "").title(),
                t.data_source or "",
                t.language_instruction,
            ]
        )
    return buf.getvalue()


def load_benchmark_tasks(csv_path: str | Path | None = None) -> list[BenchmarkTask]:
    """All canonical manifest rows in manifest order (``csv_path``: those of that file)."""
    if csv_path is None:
        return [
            BenchmarkTask(
                env_id=t.env_id,
                split=t.split or "",
                memory_type=t.memory_type,
                max_episode_steps=t.max_episode_steps,
                language_instruction=t.language_instruction,
                data_source=t.data_source or "",
            )
            for t in list_tasks(split="all")
        ]
    path = Path(csv_path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise BenchError(f"cannot read task manifest {path}: {exc.strerror or exc}") from None
    reader = csv.DictReader(io.StringIO(text), delimiter=";")
    if reader.fieldnames is None or "Name" not in reader.fieldnames:
        raise BenchError(
            f"{path} is not a MIKASA-Robo manifest: expected the ';'-delimited header "
            f"{';'.join(MANIFEST_HEADER)}"
        )
    return [BenchmarkTask.from_csv_row(row) for row in reader]


def _canonical_split(split: str) -> str:
    canon = split.strip().lower()
    if canon not in SUPPORTED_SPLITS:
        raise BenchError(f"unknown split {split!r}; expected one of {', '.join(SUPPORTED_SPLITS)}")
    return canon


def select_benchmark_tasks(
    *,
    split: str | None = None,
    env_ids: Sequence[str] | None = None,
    csv_path: str | Path | None = None,
) -> list[BenchmarkTask]:
    """Tasks of a split (file order) or of explicit ids (given order) — exactly one of them.

    Ids that are not in the manifest become ``BenchmarkTask.custom(id)`` (upstream
    behaviour); `resolve_tasks` is the strict front end the CLI uses.
    """
    if (split is None) == (env_ids is None):
        raise ValueError("give exactly one of split= or env_ids=")
    tasks = load_benchmark_tasks(csv_path)
    if split is not None:
        canon = _canonical_split(split)
        return [t for t in tasks if canon == "all" or t.split == canon]
    by_id = {t.env_id: t for t in tasks}
    return [by_id.get(i) or BenchmarkTask.custom(i) for i in env_ids or ()]


def make_run_dir(base_dir: str | Path) -> Path:
    """Create and return ``<base_dir>/<YYYY-MM-DD_HH-MM-SS>`` (a suffix avoids collisions)."""
    base = Path(base_dir)
    stamp = datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    path, n = base / stamp, 1
    while path.exists():
        n += 1
        path = base / f"{stamp}_{n}"
    path.mkdir(parents=True)
    return path


def benchmark_commit() -> str | None:
    """``git rev-parse HEAD`` of the repository this package runs from, or None."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=repository_root(),
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def registered_env_ids() -> set[str]:
    """Ids known to Gymnasium after importing `mikasa_envs` (which registers the tasks)."""
    import gymnasium as gym
    import mikasa_envs  # noqa: F401  (registers the envs)

    return set(gym.registry)


def supported_env_ids() -> tuple[str, ...]:
    """Ids that the canonical wrapper chain supports (keys of ``VLA_WRAPPER_CONFIGS``)."""
    from mikasa_wrappers import MIKASA_VLA_ENV_IDS

    return tuple(MIKASA_VLA_ENV_IDS)


@dataclass
class TaskSelection:
    """The outcome of resolving a split or id list into runnable tasks."""

    tasks: list[BenchmarkTask]
    split: str | None = None
    env_ids: list[str] | None = None
    skipped_unregistered: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record of what was asked for and what was skipped."""
        return {
            "split": self.split,
            "env_ids": self.env_ids,
            "tasks": [t.env_id for t in self.tasks],
            "skipped_unregistered": self.skipped_unregistered,
            "complete_split": self.split is not None and not self.skipped_unregistered,
        }


def _unknown_id(env_id: str, known: Iterable[str]) -> UnknownTaskError:
    close = difflib.get_close_matches(env_id, list(known), n=3, cutoff=0.6)
    hint = f" Did you mean: {', '.join(close)}?" if close else ""
    return UnknownTaskError(
        f"unknown env id {env_id!r}: it is not in the MIKASA-Robo-VLA manifest.{hint} "
        f"Run `mikasa-bench list` for the canonical ids."
    )


def resolve_tasks(
    *,
    split: str | None = None,
    env_ids: Sequence[str] | None = None,
    strict: bool = False,
    csv_path: str | Path | None = None,
    registered: set[str] | None = None,
    warn: Any = None,
) -> TaskSelection:
    """Validate a selection before anything runs.

    * ``split``: the manifest's tasks of that split; ids that are not registered yet are
      skipped with a warning (``strict=True`` makes that an error).
    * ``env_ids``: each must be a manifest id (else `UnknownTaskError` with close
      matches), registered and supported by the wrapper chain; duplicates are an error.

    ``registered`` (default: `registered_env_ids`) and ``warn`` (default: print to
    stderr) are injectable for tests.
    """
    if (split is None) == (not env_ids):
        raise BenchError("choose the tasks with exactly one of --split or --task")
    if split is not None:
        _canonical_split(split)  # a bad split fails before the slow registry import
    manifest = load_benchmark_tasks(csv_path)
    if registered is None:
        registered = registered_env_ids()
    if warn is None:

        def warn(msg: str) -> None:
            print(f"warning: {msg}", file=sys.stderr)

    if split is not None:
        canon = _canonical_split(split)
        tasks = select_benchmark_tasks(split=canon, csv_path=csv_path)
        missing = [t.env_id for t in tasks if t.env_id not in registered]
        if missing:
            msg = (
                f"{len(missing)} of the {len(tasks)} tasks of split {canon!r} are not "
                f"registered yet (not implemented in mikasa-envs): {', '.join(missing)}"
            )
            if strict:
                raise UnknownTaskError(msg + " (--strict makes this an error)")
            warn(msg + "; skipping them (pass --strict to make this an error)")
        runnable = [t for t in tasks if t.env_id in registered]
        if not runnable:
            raise UnknownTaskError(f"no task of split {canon!r} is registered yet")
        return TaskSelection(runnable, split=canon, skipped_unregistered=missing)

    ids = list(env_ids or ())
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise BenchError(f"env ids given more than once: {', '.join(dup)}")
    by_id = {t.env_id: t for t in manifest}
    supported = set(supported_env_ids())
    out = []
    for env_id in ids:
        if env_id not in by_id:
            raise _unknown_id(env_id, by_id)
        if env_id not in registered:
            raise UnknownTaskError(
                f"env id {env_id!r} is in the manifest but not registered yet (its task is "
                f"not implemented in mikasa-envs); expected a registered id — see "
                f"`mikasa-bench list` (column 'registered')"
            )
        if env_id not in supported:
            raise UnknownTaskError(
                f"env id {env_id!r} has no configuration in the canonical wrapper chain "
                f"(mikasa_wrappers.VLA_WRAPPER_CONFIGS)"
            )
        out.append(by_id[env_id])
    return TaskSelection(out, env_ids=ids)
