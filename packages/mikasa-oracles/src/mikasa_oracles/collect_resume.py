"""The task directory of ``mikasa-collect``: its lock, its staging area and the resume checks
(used by :func:`mikasa_oracles.collect.collect`)."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mikasa_oracles.collect_attempts import STAGED_PREFIX
from mikasa_oracles.collect_errors import CollectError

__all__ = ["clean_staging", "existing_episodes", "locked_directory"]


@contextmanager
def locked_directory(directory: Path) -> Iterator[None]:
    """Exclusive advisory lock on the task directory: two collectors into one directory
    would interleave indices."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise CollectError(f"another mikasa-collect is writing to {directory}") from None
        yield
    finally:
        os.close(fd)


def clean_staging(staging: Path) -> None:
    """Remove this collector's staged and temporary files, then empty staging dirs."""
    from mikasa_datasets.npz import is_temp_file

    if staging.is_dir():
        for p in staging.iterdir():
            if p.is_file() and (
                is_temp_file(p) or (p.name.startswith(STAGED_PREFIX) and p.suffix == ".npz")
            ):
                p.unlink(missing_ok=True)
    for d in (staging, staging.parent):
        try:
            d.rmdir()  # only if empty: other tasks may be staging next to us
        except OSError:
            pass


def existing_episodes(directory: Path, env_id: str, start_seed: int) -> list[Any]:
    """Check the episodes already in ``directory`` and return their summaries (resume)."""
    from mikasa_datasets.npz import (
        METADATA_FILENAME,
        EpisodeFormatError,
        read_metadata,
        summarize_directory,
    )

    try:
        existing = summarize_directory(directory)
    except EpisodeFormatError as exc:
        raise CollectError(
            f"cannot resume: {exc}. Delete that file and every later train_data_<i>.npz "
            f"(they are re-collected identically), or use another --out"
        ) from None
    if (directory / METADATA_FILENAME).exists():
        try:
            meta_env = read_metadata(directory)["env_id"]
        except ValueError:
            meta_env = env_id  # unreadable metadata is rewritten below
        if meta_env != env_id:
            raise CollectError(f"{directory} holds episodes of {meta_env!r}, not {env_id!r}")
    seeds = [e.episode_seed for e in existing]
    if any(b <= a for a, b in zip(seeds, seeds[1:], strict=False)):
        raise CollectError(
            f"cannot resume: episode seeds in {directory} are not increasing: {seeds}"
        )
    if seeds and seeds[0] < start_seed:
        raise CollectError(
            f"cannot resume: {directory} was collected from seed {seeds[0]} or lower, but "
            f"--start-seed is {start_seed}; pass --start-seed {seeds[0]} or use another --out"
        )
    return existing
