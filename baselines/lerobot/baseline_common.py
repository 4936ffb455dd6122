"""What every part of the LeRobot baseline driver shares: paths, logging, files, the clock,
and running one command until it exits or the call's time limit stops it.

Standard library plus ``mikasa_bench.results.files.atomic_write_json`` (a light import: it loads
neither the simulator nor torch).
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mikasa_bench.results.files import atomic_write_json as write_json

__all__ = [
    "REPO",
    "HERE",
    "DRIVER_CALL",
    "log",
    "now",
    "write_json",
    "write_text",
    "read_json",
    "rel",
    "display",
    "dir_size_mb",
    "Deadline",
    "TimeUp",
    "UnitFailed",
    "RunResult",
    "run_until",
]

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent

_T0 = time.monotonic()


def log(msg: str) -> None:
    """A progress line with the wall clock and the time since the call started."""
    clock = dt.datetime.now().strftime("%H:%M:%S")
    print(f"[{clock} +{time.monotonic() - _T0:6.0f}s] {msg}", flush=True)


def now() -> str:
    """The local time to the second (ISO 8601), as records and the table note it."""
    return dt.datetime.now().isoformat(timespec="seconds")


def write_text(path: Path, text: str) -> None:
    """Write text atomically (temp file, rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def read_json(path: Path) -> Any:
    """Parsed JSON, or None when the file is missing or unreadable."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def rel(path: Path | str) -> str:
    """``path`` relative to the repository when inside it (commands in the docs stay short)."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(REPO))
    except ValueError:
        return str(p)


def display(argv: Sequence[str]) -> str:
    """A shell-quoted command line with repository paths made relative."""
    root = str(REPO) + os.sep
    return shlex.join(a.replace(root, "") for a in argv)


DRIVER_CALL = display([sys.executable, *sys.argv])
"""This process's command line (recorded with every unit it finishes)."""


def dir_size_mb(path: Path) -> float:
    """Total size of the files under ``path`` in MB (symlinks not followed)."""
    total = sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())
    return round(total / 1e6, 2)


class Deadline:
    """The call's time limit (monotonic clock)."""

    def __init__(self, limit_s: float | None) -> None:
        self.end = None if limit_s is None else time.monotonic() + limit_s

    def remaining(self) -> float:
        """Seconds left (infinite without a limit)."""
        return math.inf if self.end is None else self.end - time.monotonic()

    def expired(self) -> bool:
        """Whether the limit has passed."""
        return self.remaining() <= 0


class TimeUp(Exception):
    """The time limit stopped the call; the next call goes on."""


class UnitFailed(Exception):
    """A unit's command failed; its log tail is in the message."""


@dataclass
class RunResult:
    """A finished subprocess: exit status (None when stopped at the deadline) and wall time."""

    rc: int | None
    wall_s: float


def run_until(
    argv: Sequence[str],
    log_path: Path,
    env: Mapping[str, str],
    deadline: Deadline,
    grace_s: float,
    tick: Callable[[], None] | None = None,
    tick_s: float = 60.0,
    stop: Callable[[], bool] | None = None,
    first_signal: int = signal.SIGINT,
) -> RunResult:
    """Run ``argv`` (output appended to ``log_path``, cwd the repository) until it exits or
    ``deadline`` passes (or ``stop()``, polled every second, says so); then send
    ``first_signal`` (SIGINT) to its process group, SIGTERM after ``grace_s`` (unless the
    first was SIGTERM), SIGKILL 10 s after that. ``tick`` is called every ``tick_s`` while it
    runs (progress lines)."""
    t0 = time.monotonic()
    with open(log_path, "a", encoding="utf-8") as fh:
        fh.write(f"\n# {now()}\n$ {display(argv)}\n")
        fh.flush()
        proc = subprocess.Popen(
            list(argv),
            stdout=fh,
            stderr=subprocess.STDOUT,
            cwd=REPO,
            env=dict(env),
            start_new_session=True,  # its own group: a stop reaches its workers too
        )
        stop_at: float | None = None
        signals = [(0.0, first_signal)]
        if first_signal != signal.SIGTERM:
            signals.append((grace_s, signal.SIGTERM))
        signals.append((signals[-1][0] + 10, signal.SIGKILL))
        last_tick = time.monotonic()
        while True:
            try:
                rc = proc.wait(timeout=1.0)
                break
            except subprocess.TimeoutExpired:
                pass
            t = time.monotonic()
            if tick is not None and t - last_tick >= tick_s:
                last_tick = t
                tick()
            if stop_at is None and (deadline.expired() or (stop is not None and stop())):
                stop_at = t
            if stop_at is not None:
                while signals and t - stop_at >= signals[0][0]:
                    _, sig = signals.pop(0)
                    try:
                        os.killpg(proc.pid, sig)
                    except ProcessLookupError:
                        pass
    return RunResult(None if stop_at is not None else rc, time.monotonic() - t0)


def calls_wall_s(calls: Sequence[Mapping[str, Any]]) -> float:
    """The wall time summed over a unit's calls."""
    return round(sum(c.get("wall_s", 0) for c in calls), 1)
