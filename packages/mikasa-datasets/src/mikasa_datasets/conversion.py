"""What the converters share: their errors, the lazy import of optional format libraries,
the "build in a staging directory, rename when complete" output protocol behind
``--overwrite`` / ``--resume``, and :class:`ConversionResult`.

A leaf of the package's converters: :mod:`mikasa_datasets.rlds`,
:mod:`mikasa_datasets.lerobot`, :mod:`mikasa_datasets.loaders` and
:mod:`mikasa_datasets.validate` build on it, and it imports only the NPZ layout
(:mod:`mikasa_datasets.npz`). Its names are importable from :mod:`mikasa_datasets.loaders`
too, where they were defined first.
"""

from __future__ import annotations

import importlib
import os
import secrets
import shutil
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

from mikasa_datasets.npz import list_episode_files

__all__ = [
    "SETUP_HINT",
    "ConversionResult",
    "DatasetFormatError",
    "MissingDependencyError",
    "OutputExistsError",
    "commit_output",
    "new_staging_dir",
    "npz_task_files",
    "output_action",
    "remove_stale_staging",
    "require",
]

SETUP_HINT = (
    "install the conversion environment with scripts/setup_datasets_envs.sh and run "
    ".venv-datasets/bin/mikasa-datasets (or pip install 'mikasa-datasets[{extra}]')"
)


# --------------------------------------------------------------------------- errors
class DatasetFormatError(ValueError):
    """A dataset on disk does not match its schema; the message starts with the path.

    ``path`` is the most specific file or directory at fault, ``problem`` the rest.
    """

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")

    def __reduce__(self) -> tuple[Any, ...]:
        # Picklable (errors of a converter's worker process reach the caller), notes too.
        return type(self), (self.path, self.problem), self.__dict__


def npz_task_files(
    npz_task_dir: str | os.PathLike[str], max_episodes: int | None = None
) -> list[Path]:
    """The ``train_data_<i>.npz`` files of an NPZ task directory in index order (the first
    ``max_episodes`` of them); a missing or empty directory is a `DatasetFormatError`."""
    src = Path(npz_task_dir)
    if not src.is_dir():
        raise DatasetFormatError(src, "NPZ task directory does not exist")
    files = list_episode_files(src)
    if not files:
        raise DatasetFormatError(src, "no train_data_<i>.npz episode files")
    return files if max_episodes is None else files[:max_episodes]


class MissingDependencyError(ImportError):
    """An optional format library (tensorflow-datasets, lerobot, ...) is not installed."""


class OutputExistsError(FileExistsError):
    """The destination of a conversion already exists and neither ``overwrite`` nor
    ``resume`` was requested."""


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` or raise :class:`MissingDependencyError` saying how to get it.

    The converters import their format library lazily so that the package (and the CLI's
    ``--help`` and NPZ validation) work in an environment without them.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(
            f"{module} is needed for this operation but cannot be imported ({exc}); "
            + SETUP_HINT.format(extra=extra)
        ) from exc


# --------------------------------------------------------------------------- output protocol
_STAGING_MARK = ".tmp-"


def new_staging_dir(final: Path) -> Path:
    """A fresh, not yet existing sibling of ``final`` to build an output in.

    Named ``.<final name>.tmp-<pid>-<random>`` in the same directory, so the final
    :func:`os.replace` is a same-filesystem rename and concurrent conversions of different
    tasks never share a staging directory.
    """
    final.parent.mkdir(parents=True, exist_ok=True)
    return final.parent / f".{final.name}{_STAGING_MARK}{os.getpid()}-{secrets.token_hex(4)}"


def remove_stale_staging(final: Path) -> list[Path]:
    """Delete staging directories of ``final`` left by interrupted runs; return them.

    Only call this while no other process converts the same task.
    """
    removed = []
    if final.parent.is_dir():
        for p in final.parent.glob(f".{final.name}{_STAGING_MARK}*"):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


def output_action(final: Path, *, overwrite: bool, resume: bool, is_complete: Any = None) -> str:
    """Decide what to do with an existing destination: ``"build"`` or ``"skip"``.

    * nothing there -> ``"build"``;
    * ``overwrite`` -> ``"build"`` (the old output is replaced only once the new one is
      complete, see :func:`commit_output`);
    * ``resume`` -> ``"skip"`` if ``is_complete(final)`` (default: it exists) else
      ``"build"``;
    * neither -> :class:`OutputExistsError` naming the path.

    Outputs appear under their final name only when complete, so under ``resume`` an
    existing destination is a finished conversion; ``is_complete`` additionally checks it
    still matches its source (e.g. the episode count), so a grown source is redone.
    """
    if overwrite and resume:
        raise ValueError("overwrite and resume are mutually exclusive")
    if not final.exists():
        return "build"
    if overwrite:
        return "build"
    if resume:
        return "skip" if (is_complete is None or is_complete(final)) else "build"
    raise OutputExistsError(
        f"{final}: already exists; pass --overwrite to replace it or --resume to keep it"
    )


def commit_output(staging: Path, final: Path) -> Path:
    """Move the complete output ``staging`` to ``final``, replacing an old ``final``.

    The old output is first renamed aside and deleted only after the new one is in
    place, so at every instant ``final`` is either the old or the new complete output.
    """
    old = None
    if final.exists():
        old = final.parent / f".{final.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        os.replace(final, old)
    os.replace(staging, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return final


# --------------------------------------------------------------------------- result
@dataclass
class ConversionResult:
    """What a conversion did: where, how much, how long; ``skipped`` under ``resume``."""

    path: Path
    episodes: int
    frames: int
    seconds: float
    skipped: bool = False

    @property
    def frames_per_second(self) -> float:
        """Converted frames per wall-clock second (0 when skipped)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0
