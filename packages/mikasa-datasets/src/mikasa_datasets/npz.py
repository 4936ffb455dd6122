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
"""

from __future__ import annotations

import io
import json
import os
import re
import secrets
import struct
import zipfile
import zlib
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from mikasa_datasets.naming import env_id_to_dataset_name

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

IMAGE_SIZE = 128
RGB_CHANNELS = 6
PROPRIO_DIM = 7
ACTION_DIM = 7

Episode = dict[str, np.ndarray]
"""An episode in memory: schema key -> numpy array (see :data:`SCHEMA`)."""


# --------------------------------------------------------------------------- schema
@dataclass(frozen=True)
class KeySpec:
    """One row of the schema table: key, dtype, shape and meaning.

    ``shape`` uses the string ``"T"`` for the episode length. ``dtype`` is ``None`` for the
    language instruction, whose only requirement is a numpy unicode string (``<U…``) whose
    width depends on the text.
    """

    name: str
    dtype: np.dtype | None
    shape: tuple[int | str, ...]
    description: str

    @property
    def per_step(self) -> bool:
        """Whether the key holds one entry per step (leading axis ``T``)."""
        return bool(self.shape) and self.shape[0] == "T"

    def dtype_text(self) -> str:
        """Human-readable expected dtype, for error messages and docs."""
        return "unicode string (<U…)" if self.dtype is None else str(self.dtype)

    def shape_text(self) -> str:
        """Human-readable expected shape, e.g. ``(T, 7)``."""
        inner = ", ".join(str(d) for d in self.shape)
        return f"({inner},)" if len(self.shape) == 1 else f"({inner})"


# Entries the VLA and RL episode files share.
_RGB_SPEC = KeySpec(
    "rgb",
    np.dtype(np.uint8),
    ("T", IMAGE_SIZE, IMAGE_SIZE, RGB_CHANNELS),
    "channels 0-2 base_camera, 3-5 hand_camera; observation before step t",
)
_REWARD_SPEC = KeySpec("reward", np.dtype(np.float32), ("T",), "normalized_dense reward of step t")

SCHEMA: dict[str, KeySpec] = {
    spec.name: spec
    for spec in (
        _RGB_SPEC,
        KeySpec(
            "proprio",
            np.dtype(np.float32),
            ("T", PROPRIO_DIM),
            "[x, y, z, roll, pitch, yaw, gripper]",
        ),
        KeySpec(
            "action",
            np.dtype(np.float32),
            ("T", ACTION_DIM),
            "pd_ee_delta_pose action clipped to [-1, 1]",
        ),
        _REWARD_SPEC,
        KeySpec("success", np.dtype(np.int32), ("T",), "info['success'] after step t (0/1)"),
        KeySpec(
            "done",
            np.dtype(np.int32),
            ("T",),
            "terminated | truncated | success after step t (0/1)",
        ),
        KeySpec("language_instruction", None, (), "the episode's instruction"),
        KeySpec("success_once", np.dtype(np.bool_), (), "always True in saved data"),
        KeySpec("episode_length", np.dtype(np.int32), (), "T"),
        KeySpec("episode_seed", np.dtype(np.int64), (), "seed given to env.reset"),
    )
}
"""Every key of an episode file, in the order they are written (spec §3)."""

EPISODE_KEYS: tuple[str, ...] = tuple(SCHEMA)
STEP_KEYS: tuple[str, ...] = tuple(k for k, s in SCHEMA.items() if s.per_step)

RL_JOINTS_DIM = 25
RL_ACTION_DIM = 8

RL_SCHEMA: dict[str, KeySpec] = {
    spec.name: spec
    for spec in (
        _RGB_SPEC,
        KeySpec(
            "joints",
            np.dtype(np.float32),
            ("T", RL_JOINTS_DIM),
            "[tcp_pose (x, y, z, qw, qx, qy, qz), qpos 9, qvel 9] before step t",
        ),
        KeySpec("action", np.dtype(np.float32), ("T", RL_ACTION_DIM), "pd_joint_delta_pos action"),
        _REWARD_SPEC,
        KeySpec("success", np.dtype(np.int64), ("T",), "info['success'] after step t (0/1)"),
        KeySpec(
            "done",
            np.dtype(np.int64),
            ("T",),
            "terminated | truncated after step t, terminations ignored (1 only at T-1)",
        ),
    )
}
"""The RL release's episode files (``<path>/MIKASA-Robo/unbatched/<env_id>/train_data_<n>.npz``,
written by ``mikasa-rl-collect``): every step up to the task's horizon, every episode kept,
no language or metadata. Told apart from :data:`SCHEMA` by its key set."""
RL_EPISODE_KEYS: tuple[str, ...] = tuple(RL_SCHEMA)

METADATA_KEYS: tuple[str, ...] = (
    "env_id",
    "num_episodes",
    "episode_lengths",
    "success_once",
    "reward_sums",
    "episode_seeds",
    "batched_source_dir",
    "unbatched_dir",
)
"""Keys of ``metadata.json``, in the order they are written (spec §3.4)."""


class EpisodeFormatError(ValueError):
    """An episode (file or in-memory dict) does not match the schema or is unreadable.

    ``path`` is the file (or ``None`` for an in-memory episode); the message starts with it.
    """

    def __init__(self, path: str | os.PathLike[str] | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = problem
        super().__init__(problem if path is None else f"{path}: {problem}")

    def __reduce__(self) -> tuple[Any, ...]:
        # Picklable (errors of a converter's worker process reach the caller), notes too.
        return type(self), (self.path, self.problem), self.__dict__


class EpisodeInvariantError(EpisodeFormatError):
    """The arrays match the schema but break a §3.1 invariant (alignment, done, success)."""


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


# --------------------------------------------------------------------------- schema checks
def _check_array(
    key: str,
    dtype: np.dtype,
    shape: tuple[int, ...],
    source: Any,
    schema: Mapping[str, KeySpec] = SCHEMA,
) -> int | None:
    """Check one key's dtype/shape against the schema; return its ``T`` (if per step)."""
    spec = schema[key]
    if spec.dtype is None:
        if dtype.kind != "U":
            raise EpisodeFormatError(
                source, f"key {key!r} has dtype {dtype}; expected {spec.dtype_text()}"
            )
    elif dtype != spec.dtype:
        raise EpisodeFormatError(
            source, f"key {key!r} has dtype {dtype}; expected {spec.dtype_text()}"
        )
    if len(shape) != len(spec.shape) or any(
        want != "T" and got != want for got, want in zip(shape, spec.shape, strict=True)
    ):
        raise EpisodeFormatError(
            source, f"key {key!r} has shape {tuple(shape)}; expected {spec.shape_text()}"
        )
    return int(shape[0]) if spec.per_step else None


def _check_keys(keys: Sequence[str], source: Any, schema: Mapping[str, KeySpec] = SCHEMA) -> None:
    missing = [k for k in schema if k not in keys]
    if missing:
        raise EpisodeFormatError(
            source,
            f"missing key(s) {', '.join(map(repr, missing))}; an episode has {', '.join(schema)}",
        )
    extra = sorted(k for k in keys if k not in schema)
    if extra:
        raise EpisodeFormatError(source, f"unexpected key(s) {', '.join(map(repr, extra))}")


def _check_lengths(lengths: Mapping[str, int], episode_length: int | None, source: Any) -> int:
    distinct = set(lengths.values())
    if len(distinct) > 1:
        detail = ", ".join(f"{k}: {n}" for k, n in lengths.items())
        raise EpisodeFormatError(
            source, f"per-step arrays disagree on the episode length ({detail})"
        )
    t = distinct.pop()
    if episode_length is not None and t != episode_length:
        raise EpisodeFormatError(
            source, f"episode_length is {episode_length} but the per-step arrays have {t} steps"
        )
    if t < 1:
        raise EpisodeFormatError(source, "episode has no steps (T = 0)")
    return t


def check_schema(
    episode: Mapping[str, Any], *, source: str | os.PathLike[str] | None = None
) -> int:
    """Check keys, dtypes and shapes of an in-memory episode; return its length ``T``.

    Arrays must already have the schema's dtypes (no silent casting: use
    :func:`make_episode` to build an episode from raw rollout data). ``source`` names the
    episode in error messages.
    """
    return _check_in_memory(episode, source, SCHEMA)


def _check_in_memory(episode: Mapping[str, Any], source: Any, schema: Mapping[str, KeySpec]) -> int:
    _check_keys(list(episode), source, schema)
    lengths: dict[str, int] = {}
    for key in schema:
        value = episode[key]
        if not isinstance(value, np.ndarray):
            raise EpisodeFormatError(
                source, f"key {key!r} is a {type(value).__name__}, expected a numpy array"
            )
        t = _check_array(key, value.dtype, value.shape, source, schema)
        if t is not None:
            lengths[key] = t
    length = int(episode["episode_length"]) if "episode_length" in schema else None
    return _check_lengths(lengths, length, source)


def validate_episode(
    episode: Mapping[str, Any],
    *,
    source: str | os.PathLike[str] | None = None,
    max_episode_steps: int | None = None,
    min_length: int = 1,
    require_final_success: bool = True,
) -> int:
    """Check the schema and the §3.1 invariants of an episode; return ``T``.

    Invariants: one length ``T == episode_length`` for every per-step array;
    ``success_once`` is True; ``done`` is 0 before the last step and 1 on it (the rollout
    stops at the first terminated/truncated/success step); ``success``/``done`` are 0/1
    and a success step is a done step; the last step is a success
    (``require_final_success``); ``min_length <= T <= max_episode_steps``; actions lie in
    [-1, 1]; float arrays are finite; the instruction is not empty.

    Raises :class:`EpisodeFormatError` (schema) or :class:`EpisodeInvariantError`.
    """
    t = check_schema(episode, source=source)

    def fail(problem: str) -> None:
        raise EpisodeInvariantError(source, problem)

    if not bool(episode["success_once"]):
        fail("success_once is False; only successful episodes are stored")
    done, success = episode["done"], episode["success"]
    for key, arr in (("done", done), ("success", success)):
        if not np.isin(arr, (0, 1)).all():
            fail(f"{key} holds values other than 0/1: {sorted(set(np.unique(arr).tolist()))}")
    if done[-1] != 1:
        fail(f"done[T-1] is 0 (T = {t}); the last stored step must end the episode")
    early = np.flatnonzero(done[:-1])
    if early.size:
        fail(
            f"done is 1 at step {int(early[0])} before the last step {t - 1}; the rollout must stop there"
        )
    if (success > done).any():
        fail(f"success is 1 at step {int(np.flatnonzero(success > done)[0])} where done is 0")
    if require_final_success and success[-1] != 1:
        fail("success[T-1] is 0; a stored episode ends at its first success step")
    if t < min_length:
        fail(f"episode has {t} steps; at least {min_length} are required")
    if max_episode_steps is not None and t > max_episode_steps:
        fail(f"episode has {t} steps; the task allows at most {max_episode_steps}")
    for key in ("proprio", "action", "reward"):
        if not np.isfinite(episode[key]).all():
            fail(f"{key} contains NaN or infinite values")
    action = episode["action"]
    if (np.abs(action) > 1.0).any():
        fail(
            f"action leaves [-1, 1] (min {float(action.min()):.4g}, max {float(action.max()):.4g})"
        )
    if not str(episode["language_instruction"]).strip():
        fail("language_instruction is empty")
    return t


def validate_rl_episode(
    episode: Mapping[str, Any],
    *,
    source: str | os.PathLike[str] | None = None,
    max_episode_steps: int | None = None,
) -> int:
    """Check an RL episode (:data:`RL_SCHEMA`) and its invariants; return ``T``.

    Invariants: one length ``T`` for every array; ``success``/``done`` are 0/1; ``done``
    is 1 exactly at the last step (terminations are ignored: the episode runs to its
    timeout); ``T <= max_episode_steps`` when given; float arrays are finite. Actions are
    not range-checked (a policy's raw actions may leave [-1, 1]; the controller clips).
    """
    t = _check_in_memory(episode, source, RL_SCHEMA)

    def fail(problem: str) -> None:
        raise EpisodeInvariantError(source, problem)

    done, success = episode["done"], episode["success"]
    for key, arr in (("done", done), ("success", success)):
        if not np.isin(arr, (0, 1)).all():
            fail(f"{key} holds values other than 0/1: {sorted(set(np.unique(arr).tolist()))}")
    if done[-1] != 1:
        fail(f"done[T-1] is 0 (T = {t}); an RL episode is recorded up to its timeout")
    early = np.flatnonzero(done[:-1])
    if early.size:
        fail(
            f"done is 1 at step {int(early[0])} before the last step {t - 1}; terminations are "
            "ignored, only the timeout ends an RL episode"
        )
    if max_episode_steps is not None and t > max_episode_steps:
        fail(f"episode has {t} steps; the task allows at most {max_episode_steps}")
    for key in ("joints", "action", "reward"):
        if not np.isfinite(episode[key]).all():
            fail(f"{key} contains NaN or infinite values")
    return t


def make_episode(
    *,
    rgb: Any,
    proprio: Any,
    action: Any,
    reward: Any,
    success: Any,
    done: Any,
    language_instruction: str,
    episode_seed: int,
    success_once: bool = True,
) -> Episode:
    """Build a schema-conforming episode from per-step data (lists or arrays).

    Casts to the schema dtypes, clips ``action`` to [-1, 1] (what the EE controller
    effectively receives) and derives ``episode_length``. Does not check the invariants;
    :func:`write_episode` does.
    """
    ep: Episode = {
        "rgb": np.ascontiguousarray(np.asarray(rgb, dtype=np.uint8)),
        "proprio": np.ascontiguousarray(np.asarray(proprio, dtype=np.float32)),
        "action": np.ascontiguousarray(np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)),
        "reward": np.ascontiguousarray(np.asarray(reward, dtype=np.float32)),
        "success": np.ascontiguousarray(np.asarray(success, dtype=np.int32)),
        "done": np.ascontiguousarray(np.asarray(done, dtype=np.int32)),
        "language_instruction": np.array(str(language_instruction)),
        "success_once": np.array(bool(success_once)),
        "episode_length": np.array(len(np.asarray(reward)), dtype=np.int32),
        "episode_seed": np.array(int(episode_seed), dtype=np.int64),
    }
    return ep


# --------------------------------------------------------------------------- write / read
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
        _check_in_memory(episode, path, RL_SCHEMA)
    arrays = {key: np.ascontiguousarray(episode[key]) for key in RL_EPISODE_KEYS}
    with _atomic_writer(path) as f:
        np.savez(f, **arrays)
    return path


def _read_header(fp: IO[bytes]) -> tuple[tuple[int, ...], bool, np.dtype]:
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(fp)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(fp)
    # Version 3.0 (utf-8 headers) has no public reader; numpy's own loader uses this.
    return np.lib.format._read_array_header(fp, version)  # type: ignore[attr-defined]


def _read_into_bytearray(path: Path) -> bytearray:
    """The whole file, read straight into a bytearray (one copy fewer than bytes)."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = bytearray(size)
        got = f.readinto(data)
    del data[got:]  # a file that shrank meanwhile
    return data


def _zlib_module() -> Any:
    """Intel ISA-L's zlib-compatible module (``isal``, the ``rlds`` extra) where installed,
    else zlib: the same streams and checksums, 3-5x faster here (CRC-32, deflate,
    inflate). NPZ CRC checks and the RLDS PNG codec use it."""
    try:
        from isal import isal_zlib
    except ImportError:
        return zlib
    return isal_zlib


fast_zlib = _zlib_module()
_crc32 = fast_zlib.crc32


def _array_from_npy_bytes(
    payload: memoryview, shape: tuple[int, ...], fortran_order: bool, dtype: np.dtype, start: int
) -> np.ndarray:
    """The array of a whole ``.npy`` file in memory (its header already parsed: ``start``
    is where the data begins), viewing the data without a copy."""
    if dtype.hasobject:
        raise ValueError(f"holds Python objects (dtype {dtype})")
    count = int(np.prod(shape, dtype=np.int64))
    size = count * dtype.itemsize
    if len(payload) - start != size:
        raise ValueError(f"array data is {len(payload) - start} bytes, its header says {size}")
    arr = np.frombuffer(payload, dtype=dtype, count=count, offset=start)
    if not arr.flags.aligned:  # the member sits anywhere in the zip; small arrays: copy
        arr = arr.copy()
    return arr.reshape(shape, order="F" if fortran_order else "C")


class _Archive:
    """An NPZ file opened for schema-checked access; every error names the file.

    The file is read into memory once. Members stored uncompressed (``numpy.savez``, what
    this package writes) are checked (CRC-32) and viewed in place, without zipfile's
    chunked stream reads; compressed members go through zipfile.
    """

    def __init__(self, path: Path, schema: Mapping[str, KeySpec] = SCHEMA) -> None:
        self.path = path
        self.schema = schema
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such episode file")
        try:
            self.data = _read_into_bytearray(path)  # writable: arrays viewing it are too
            self.zf = zipfile.ZipFile(path)  # reads the central directory only
            names = self.zf.namelist()
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError) as exc:
            raise EpisodeFormatError(
                path, f"not a readable NPZ archive (truncated or corrupt?): {exc}"
            ) from exc
        bad = [n for n in names if not n.endswith(".npy")]
        if bad:
            self.close()
            raise EpisodeFormatError(path, f"archive member(s) {bad} are not .npy arrays")
        self.members = {n[: -len(".npy")]: n for n in names}
        self._stored: dict[str, memoryview] = {}
        self._headers: dict[str, tuple[tuple[int, ...], bool, np.dtype, int]] = {}
        try:
            _check_keys(list(self.members), path, schema)
        except BaseException:
            self.close()
            raise

    def _stored_bytes(self, key: str) -> memoryview | None:
        """The CRC-checked bytes of an uncompressed member (None for a compressed one)."""
        if key in self._stored:
            return self._stored[key]
        info = self.zf.getinfo(self.members[key])
        if info.compress_type != zipfile.ZIP_STORED:
            return None
        offset = info.header_offset
        local = bytes(self.data[offset : offset + 30])
        if len(local) < 30 or local[:4] != b"PK\x03\x04":
            raise ValueError("bad local file header")
        name_length, extra_length = struct.unpack("<HH", local[26:30])
        start = offset + 30 + name_length + extra_length
        payload = memoryview(self.data)[start : start + info.compress_size]
        if len(payload) != info.compress_size:
            raise EOFError(f"member data ends after {len(payload)} of {info.compress_size} bytes")
        if _crc32(payload) != info.CRC:
            raise zipfile.BadZipFile(f"bad CRC-32 for file {info.filename!r}")
        self._stored[key] = payload
        return payload

    def _stored_header(self, key: str, payload: memoryview) -> tuple[tuple[int, ...], bool, np.dtype, int]:
        """(shape, fortran order, dtype, data offset) of an uncompressed member, parsed once."""
        if key not in self._headers:
            stream = io.BytesIO(payload[:4096])  # headers are at most a few hundred bytes
            shape, fortran_order, dtype = _read_header(stream)
            self._headers[key] = (tuple(shape), fortran_order, dtype, stream.tell())
        return self._headers[key]

    def header(self, key: str) -> tuple[tuple[int, ...], np.dtype]:
        try:
            payload = self._stored_bytes(key)
            if payload is not None:
                shape, _, dtype, _ = self._stored_header(key, payload)
            else:
                with self.zf.open(self.members[key]) as fp:
                    shape, _, dtype = _read_header(fp)
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
            raise EpisodeFormatError(
                self.path, f"key {key!r} cannot be read (corrupt or truncated?): {exc}"
            ) from exc
        return tuple(shape), dtype

    def array(self, key: str) -> np.ndarray:
        try:
            payload = self._stored_bytes(key)
            if payload is not None:
                arr = _array_from_npy_bytes(payload, *self._stored_header(key, payload))
            else:
                with self.zf.open(self.members[key]) as fp:
                    # Reading to the member's end makes zipfile verify its CRC-32.
                    arr = np.lib.format.read_array(fp, allow_pickle=False)
                    if fp.read(1):
                        raise ValueError("trailing bytes after the array data")
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
            raise EpisodeFormatError(
                self.path, f"key {key!r} cannot be read (corrupt or truncated?): {exc}"
            ) from exc
        return arr

    def checked_headers(self) -> int:
        """Check every key's dtype/shape from the array headers; return the step count."""
        lengths: dict[str, int] = {}
        for key, spec in self.schema.items():
            shape, dtype = self.header(key)
            if dtype.hasobject:
                raise EpisodeFormatError(
                    self.path,
                    f"key {key!r} holds Python objects (dtype {dtype}); expected {spec.dtype_text()}",
                )
            t = _check_array(key, dtype, shape, self.path, self.schema)
            if t is not None:
                lengths[key] = t
        length = int(self.array("episode_length")) if "episode_length" in self.schema else None
        return _check_lengths(lengths, length, self.path)

    def close(self) -> None:
        self.zf.close()


def read_episode(
    path: str | os.PathLike[str],
    *,
    validate: bool = False,
    max_episode_steps: int | None = None,
) -> Episode:
    """Load one episode file, checking it against the schema.

    Raises :class:`EpisodeFormatError` naming ``path`` for a truncated or corrupt file
    (including a CRC mismatch in any array), a missing or unexpected key, or a wrong
    dtype or shape; ``FileNotFoundError`` if it does not exist. With ``validate`` the §3.1
    invariants are checked too (:func:`validate_episode`).
    """
    path = Path(path)
    archive = _Archive(path)
    try:
        archive.checked_headers()
        episode = {key: archive.array(key) for key in EPISODE_KEYS}
    finally:
        archive.close()
    if validate:
        validate_episode(episode, source=path, max_episode_steps=max_episode_steps)
    return episode


def is_rl_episode_file(path: str | os.PathLike[str]) -> bool:
    """Whether the NPZ file at ``path`` holds exactly the :data:`RL_SCHEMA` keys (the RL
    release's layout) rather than :data:`SCHEMA`'s; ``False`` for an unreadable file."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError):
        return False
    return sorted(names) == sorted(f"{k}.npy" for k in RL_EPISODE_KEYS)


def read_rl_episode(
    path: str | os.PathLike[str],
    *,
    validate: bool = False,
    max_episode_steps: int | None = None,
) -> Episode:
    """Load one RL episode file (:data:`RL_SCHEMA`), checking keys, dtypes and shapes
    (CRC-checked); with ``validate`` also :func:`validate_rl_episode`'s invariants."""
    path = Path(path)
    archive = _Archive(path, RL_SCHEMA)
    try:
        archive.checked_headers()
        episode = {key: archive.array(key) for key in RL_EPISODE_KEYS}
    finally:
        archive.close()
    if validate:
        validate_rl_episode(episode, source=path, max_episode_steps=max_episode_steps)
    return episode


def read_rl_episode_headers(path: str | os.PathLike[str]) -> int:
    """Check an RL episode file's keys, dtypes and shapes from the array headers only
    (frames not read); return its length ``T``."""
    archive = _Archive(Path(path), RL_SCHEMA)
    try:
        return archive.checked_headers()
    finally:
        archive.close()


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
    archive = _Archive(path)
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
