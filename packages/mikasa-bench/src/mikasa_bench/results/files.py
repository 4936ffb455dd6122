"""The files of a run directory: their names, and atomic writes that never leave half a file.

Layout of a run directory::

    <run_dir>/<env_id>.json        per-task result (benchmark.md §7.1 keys, then extensions)
    <run_dir>/summary.json         summary of the finished tasks (§7.2 keys, then extensions)
    <run_dir>/meta/run.json        what the run is: tasks, policy, protocol, sessions
    <run_dir>/meta/episodes.jsonl  journal: one line per finished episode (fsync'ed)
    <run_dir>/videos/<env_id>/episode_<i:04d>.mp4   with ``save_videos`` (written before
                                   the episode's journal line)

Every JSON file is replaced atomically (temp file + ``os.replace``), so a reader never
sees half a file.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError

__all__ = [
    "SUMMARY_FILENAME",
    "META_DIRNAME",
    "RUN_META_FILENAME",
    "JOURNAL_FILENAME",
    "atomic_write_bytes",
    "atomic_write_json",
    "read_json",
]

SUMMARY_FILENAME = "summary.json"
META_DIRNAME = "meta"
RUN_META_FILENAME = "run.json"
JOURNAL_FILENAME = "episodes.jsonl"


def _json_safe(x: Any) -> Any:
    """NaN/inf are not JSON: write them as null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` via a temp file in the same directory, fsync, then ``os.replace``:
    readers (and a crash at any point) see the old file or the new one, never a mix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The temp name starts with '.' and ends in '.tmp': globs for *.json never see it.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp creates 0600; results and videos get the usual umask-based mode so
        # others can read a shared results directory.
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def atomic_write_json(path: str | Path, data: Any) -> None:
    """Write ``data`` atomically as indented UTF-8 JSON (keys in insertion order, trailing
    newline; NaN/inf become null)."""
    text = json.dumps(_json_safe(data), indent=2, ensure_ascii=False) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))


def read_json(path: Path) -> Any:
    """The JSON file at ``path``; `BenchError` naming it if it is unreadable or malformed."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise BenchError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BenchError(f"{path} is not valid JSON ({exc})") from None
