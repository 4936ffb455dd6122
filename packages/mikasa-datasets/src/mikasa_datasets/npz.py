"""The raw NPZ episode format as code (datasets spec §2-§3).

One successful episode per file, ``<root>/data_npz/<dataset_name>/train_data_<i>.npz``
(``i`` = 0, 1, ... without zero padding), plus one ``metadata.json`` per task directory.
Files are written with plain :func:`numpy.savez` (uncompressed, no object arrays), so
``numpy.load(path)`` reads them without ``allow_pickle``.

Writes are atomic: the bytes go to a hidden temporary file in the destination directory
(``.<name>.<pid>.<random>.tmp``), are flushed to disk and only then renamed onto the final
name. A crash therefore never leaves a partial file under a final name; at most a stray
temporary file, which :func:`remove_stale_temp_files` deletes and every reader ignores.

Reading checks the archive against :data:`SCHEMA` (keys, dtypes, shapes, one common
episode length) before any frame data is trusted; every problem raises
:class:`EpisodeFormatError` whose message starts with the offending file's path.

The RL release's episodes (``mikasa-rl-collect``) have their own, smaller schema,
:data:`RL_SCHEMA` (``rgb``/``joints``/``action``/``reward``/``success``/``done``, every step
to the timeout, no language or metadata): :func:`write_rl_episode`, :func:`read_rl_episode`
and :func:`validate_rl_episode` are its writer, reader and checker.

The code is split by what it does: :mod:`mikasa_datasets.npz_schema` holds the schema
tables, the errors and the checks/invariants, :mod:`mikasa_datasets.npz_read` the checked
file reader; this module holds the file layout, the atomic writers, episode summaries and
``metadata.json``, and re-exports the other two, so every name is importable from here.
"""

from __future__ import annotations

import json
import os
import re
import secrets
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from mikasa_datasets.naming import env_id_to_dataset_name
from mikasa_datasets.npz_read import (
    NpzArchive,
    fast_zlib,  # noqa: F401 (re-exported: defined here before the split)
    is_rl_episode_file,
    read_episode,
    read_rl_episode,
    read_rl_episode_headers,
)
from mikasa_datasets.npz_schema import (
    ACTION_DIM,
    EPISODE_KEYS,
    IMAGE_SIZE,
    METADATA_KEYS,
    PROPRIO_DIM,
    RGB_CHANNELS,
    RL_ACTION_DIM,  # noqa: F401 (re-exported: defined here before the split)
    RL_EPISODE_KEYS,
    RL_JOINTS_DIM,  # noqa: F401 (re-exported: defined here before the split)
    RL_SCHEMA,
    SCHEMA,
    STEP_KEYS,
    Episode,
    EpisodeFormatError,
    EpisodeInvariantError,
    KeySpec,
    check_in_memory,
    check_schema,
    make_episode,
    validate_episode,
    validate_rl_episode,
)

__all__ = [
    "ACTION_DIM",
    "BATCHED_TMP_SUBDIR",
    "DATA_NPZ_DIRNAME",
    "EPISODE_KEYS",
    "IMAGE_SIZE",
    "METADATA_FILENAME",
    "METADATA_KEYS",
    "PROPRIO_DIM",
    "RGB_CHANNELS",
    "RL_EPISODE_KEYS",
    "RL_SCHEMA",
    "SCHEMA",
    "STEP_KEYS",
    "Episode",
    "EpisodeFormatError",
    "EpisodeInvariantError",
    "EpisodeSummary",
    "KeySpec",
    "batched_dir",
    "build_metadata",
    "check_schema",
    "episode_file_name",
    "episode_index",
    "is_rl_episode_file",
    "is_temp_file",
    "list_episode_files",
    "make_episode",
    "read_episode",
    "read_episode_summary",
    "read_metadata",
    "read_rl_episode",
    "read_rl_episode_headers",
    "remove_stale_temp_files",
    "summarize_directory",
    "summarize_episode",
    "task_dir",
    "validate_episode",
    "validate_rl_episode",
    "write_episode",
    "write_metadata",
    "write_rl_episode",
]

# --------------------------------------------------------------------------- layout
DATA_NPZ_DIRNAME = "data_npz"
"""Directory under the dataset root holding one sub-directory per task (spec §2)."""
BATCHED_TMP_SUBDIR = "_batched"
"""Staging directory under ``data_npz`` (starts with ``_``: never a task)."""
METADATA_FILENAME = "metadata.json"
EPISODE_FILE_PREFIX = "train_data_"
_EPISODE_FILE = re.compile(r"train_data_(\d+)\.npz")
TEMP_PREFIX = "."
TEMP_SUFFIX = ".tmp"


# --------------------------------------------------------------------------- names
def episode_file_name(index: int) -> str:
    """``train_data_<index>.npz`` (unpadded, spec §2)."""
    if index < 0:
        raise ValueError(f"episode index must be >= 0, got {index}")
    return f"{EPISODE_FILE_PREFIX}{int(index)}.npz"


def episode_index(path: str | os.PathLike[str]) -> int | None:
    """The integer ``i`` of a ``train_data_<i>.npz`` path, ``None`` for any other name."""
    match = _EPISODE_FILE.fullmatch(Path(path).name)
    return int(match.group(1)) if match else None


def list_episode_files(directory: str | os.PathLike[str]) -> list[Path]:
    """The ``train_data_<i>.npz`` files of ``directory`` sorted by ``i`` numerically.

    Lexicographic order would put ``train_data_10`` before ``train_data_2``. Temporary
    files and other names are ignored; a missing directory gives ``[]``.
    """
    d = Path(directory)
    if not d.is_dir():
        return []
    found = [(episode_index(p), p) for p in d.iterdir() if p.is_file()]
    return [p for i, p in sorted((i, p) for i, p in found if i is not None)]


def task_dir(root: str | os.PathLike[str], env_id: str) -> Path:
    """``<root>/data_npz/<dataset_name>``: where a task's final episode files live."""
    return Path(root) / DATA_NPZ_DIRNAME / env_id_to_dataset_name(env_id)


def batched_dir(root: str | os.PathLike[str], env_id: str) -> Path:
    """``<root>/data_npz/_batched/<dataset_name>``: a collector's staging directory."""
    return Path(root) / DATA_NPZ_DIRNAME / BATCHED_TMP_SUBDIR / env_id_to_dataset_name(env_id)


def is_temp_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is named like a temporary file of :func:`write_episode` /
    :func:`write_metadata` (``.<final name>.<pid>.<random>.tmp``)."""
    name = Path(path).name
    return name.startswith(TEMP_PREFIX) and name.endswith(TEMP_SUFFIX) and len(name) > 5


def remove_stale_temp_files(directory: str | os.PathLike[str]) -> list[Path]:
    """Delete temporary files left in ``directory`` by an interrupted writer.

    Only call this while no other process writes into ``directory``. Returns the paths
    removed.
    """
    d = Path(directory)
    removed: list[Path] = []
    if d.is_dir():
        for p in sorted(d.iterdir()):
            if p.is_file() and is_temp_file(p):
                p.unlink(missing_ok=True)
                removed.append(p)
    return removed


# --------------------------------------------------------------------------- atomic writes
@contextmanager
def _atomic_writer(path: Path) -> Iterator[IO[bytes]]:
    """Yield a binary file that becomes ``path`` only if the block completes.

    The temporary file lives in the destination directory so the final ``os.replace`` is
    a same-filesystem rename (atomic on POSIX). It is created with mode 0666 & ~umask,
    like a normal file, so published datasets are not owner-only.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(
        f"{TEMP_PREFIX}{path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}"
    )
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            # Durable before it becomes visible under the final name.
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def _fsync_dir(directory: Path) -> None:
    # Makes the rename itself durable; not supported everywhere (e.g. some network FSs).
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- write
def write_episode(
    path: str | os.PathLike[str],
    episode: Mapping[str, Any],
    *,
    validate: bool = True,
    max_episode_steps: int | None = None,
    min_length: int = 1,
) -> Path:
    """Write ``episode`` to ``path`` with :func:`numpy.savez`, atomically.

    The schema (and with ``validate`` the §3.1 invariants) is checked first, so an invalid
    episode never reaches disk. Keys are written in :data:`SCHEMA` order; ``numpy.savez``
    stores fixed zip timestamps, so equal episodes give byte-identical files.
    """
    path = Path(path)
    if validate:
        validate_episode(
            episode, source=path, max_episode_steps=max_episode_steps, min_length=min_length
        )
    else:
        check_schema(episode, source=path)
    arrays = {key: episode[key] for key in EPISODE_KEYS}
    with _atomic_writer(path) as f:
        np.savez(f, **arrays)
    return path


def write_rl_episode(
    path: str | os.PathLike[str], episode: Mapping[str, Any], *, validate: bool = True
) -> Path:
    """Write an RL episode (:data:`RL_SCHEMA`, exact dtypes) to ``path`` atomically.

    Like :func:`write_episode`: checked first (with ``validate`` the invariants of
    :func:`validate_rl_episode`), keys in schema order, fixed zip timestamps, so equal
    episodes give byte-identical files.
    """
    path = Path(path)
    if validate:
        validate_rl_episode(episode, source=path)
    else:
        check_in_memory(episode, path, RL_SCHEMA)
    arrays = {key: np.ascontiguousarray(episode[key]) for key in RL_EPISODE_KEYS}
    with _atomic_writer(path) as f:
        np.savez(f, **arrays)
    return path


@dataclass(frozen=True)
class EpisodeSummary:
    """What ``metadata.json`` and a resuming collector need from one episode file."""

    path: Path | None
    episode_length: int
    episode_seed: int
    reward_sum: float
    success_once: bool
    language_instruction: str


def summarize_episode(
    episode: Mapping[str, Any], path: str | os.PathLike[str] | None = None
) -> EpisodeSummary:
    """The :class:`EpisodeSummary` of an in-memory episode."""
    return EpisodeSummary(
        path=None if path is None else Path(path),
        episode_length=int(episode["episode_length"]),
        episode_seed=int(episode["episode_seed"]),
        # float64 accumulation: the value must not depend on how the sum is chunked.
        reward_sum=float(np.sum(np.asarray(episode["reward"], dtype=np.float64))),
        success_once=bool(episode["success_once"]),
        language_instruction=str(episode["language_instruction"]),
    )


def read_episode_summary(path: str | os.PathLike[str]) -> EpisodeSummary:
    """Check an episode file cheaply and return its summary.

    Keys, dtypes and shapes of every array are checked from the array headers, and the
    small arrays are loaded (CRC-checked), but the frames are not read: fast enough to run
    over a whole task directory when a collection resumes. Use :func:`read_episode` for a
    full check.
    """
    path = Path(path)
    archive = NpzArchive(path)
    try:
        archive.checked_headers()
        small = {
            key: archive.array(key)
            for key in EPISODE_KEYS
            if key not in ("rgb", "proprio", "action")
        }
    finally:
        archive.close()
    return summarize_episode(small, path)


def summarize_directory(directory: str | os.PathLike[str]) -> list[EpisodeSummary]:
    """Summaries of ``train_data_0.npz`` ... ``train_data_<n-1>.npz`` of ``directory``.

    Raises :class:`EpisodeFormatError` if the indices are not exactly ``0..n-1`` (a hole
    or a gap) or a file is unreadable.
    """
    files = list_episode_files(directory)
    for expected, f in enumerate(files):
        if episode_index(f) != expected:
            raise EpisodeFormatError(
                f,
                f"episode files are not numbered 0..{len(files) - 1}: "
                f"{episode_file_name(expected)} is missing",
            )
    return [read_episode_summary(f) for f in files]


# --------------------------------------------------------------------------- metadata
def build_metadata(
    env_id: str,
    episodes: Sequence[EpisodeSummary],
    *,
    batched_source_dir: str | os.PathLike[str],
    unbatched_dir: str | os.PathLike[str],
) -> dict[str, Any]:
    """The ``metadata.json`` mapping (spec §3.4), keys in spec order; ``episodes`` in
    index order."""
    return {
        "env_id": env_id,
        "num_episodes": len(episodes),
        "episode_lengths": [int(e.episode_length) for e in episodes],
        "success_once": [bool(e.success_once) for e in episodes],
        "reward_sums": [float(e.reward_sum) for e in episodes],
        "episode_seeds": [int(e.episode_seed) for e in episodes],
        "batched_source_dir": str(batched_source_dir),
        "unbatched_dir": str(unbatched_dir),
    }


def write_metadata(
    directory: str | os.PathLike[str],
    env_id: str,
    episodes: Sequence[EpisodeSummary],
    *,
    batched_source_dir: str | os.PathLike[str] | None = None,
    unbatched_dir: str | os.PathLike[str] | None = None,
) -> Path:
    """Write ``<directory>/metadata.json`` atomically (UTF-8, ``indent=2``, non-ASCII kept).

    ``unbatched_dir`` defaults to ``directory`` and ``batched_source_dir`` to the sibling
    ``_batched/<name>`` directory, both as given (relative paths stay relative, so the
    same command writes the same bytes).
    """
    d = Path(directory)
    meta = build_metadata(
        env_id,
        episodes,
        batched_source_dir=batched_source_dir
        if batched_source_dir is not None
        else d.parent / BATCHED_TMP_SUBDIR / d.name,
        unbatched_dir=unbatched_dir if unbatched_dir is not None else d,
    )
    text = json.dumps(meta, ensure_ascii=False, indent=2) + "\n"
    path = d / METADATA_FILENAME
    with _atomic_writer(path) as f:
        f.write(text.encode("utf-8"))
    return path


def read_metadata(directory: str | os.PathLike[str]) -> dict[str, Any]:
    """Load ``<directory>/metadata.json``; ``ValueError`` naming the file if it is invalid
    JSON or lacks a spec key."""
    path = Path(directory) / METADATA_FILENAME
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from exc
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(meta).__name__}")
    missing = [k for k in METADATA_KEYS if k not in meta]
    if missing:
        raise ValueError(f"{path}: missing key(s) {', '.join(missing)}")
    return meta
