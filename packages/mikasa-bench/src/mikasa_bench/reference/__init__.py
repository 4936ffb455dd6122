"""Reference results shipped with mikasa-bench: the full canonical protocol (every task of
the manifest x 50 episodes, rgb observations) run for the built-in policies, so that a new
run can be compared with them without re-running anything::

    mikasa-bench compare reference:oracle results/mine
    mikasa-bench report reference:oracle results/mine --out results/mine_vs_oracle

Each ``<name>/`` folder here is a results directory as `mikasa-bench run` writes it
(``<env_id>.json`` per task, ``summary.json``), without the episode journal. How and on
which machine each set was made: ``docs/reference_results/README.md`` in the repository.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from ..errors import BenchError

__all__ = ["PREFIX", "is_reference", "reference_names", "resolve_reference"]

PREFIX = "reference:"
_ROOT = Path(str(files(__name__)))


def is_reference(spec: str | Path) -> bool:
    """Whether ``spec`` names a shipped result set (``reference:<name>``)."""
    return isinstance(spec, str) and spec.startswith(PREFIX)


def reference_names() -> list[str]:
    """The names of the shipped result sets, sorted."""
    return sorted(p.name for p in _ROOT.iterdir() if (p / "summary.json").is_file())


def resolve_reference(spec: str) -> Path:
    """The directory of the shipped result set ``reference:<name>``.

    Raises `BenchError` naming the accepted values when there is no such set.
    """
    name = spec[len(PREFIX) :]
    if name not in reference_names():
        accepted = ", ".join(PREFIX + n for n in reference_names())
        raise BenchError(f"unknown reference result set {spec!r}; accepted: {accepted}")
    return _ROOT / name
