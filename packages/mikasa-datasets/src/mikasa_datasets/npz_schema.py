"""The NPZ episode schema and its checks (datasets spec §3, §3.1).

:data:`SCHEMA` (VLA episodes) and :data:`RL_SCHEMA` (the RL release's episodes) as
:class:`KeySpec` tables, the ``metadata.json`` keys, the errors every reader and writer
raises, the key/dtype/shape checks shared by the in-memory checks and the file reader
(:mod:`mikasa_datasets.npz_read`), the §3.1 invariants (:func:`validate_episode`,
:func:`validate_rl_episode`) and :func:`make_episode`.

Kept apart from :mod:`mikasa_datasets.npz` (paths, atomic writers, summaries,
``metadata.json``) so that the reader builds on it without importing the writer. Import
these names from :mod:`mikasa_datasets.npz`, which re-exports them.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

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


# --------------------------------------------------------------------------- schema checks
def check_array(
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


def check_keys(keys: Sequence[str], source: Any, schema: Mapping[str, KeySpec] = SCHEMA) -> None:
    """Check that ``keys`` are exactly the schema's keys (none missing, none extra)."""
    missing = [k for k in schema if k not in keys]
    if missing:
        raise EpisodeFormatError(
            source,
            f"missing key(s) {', '.join(map(repr, missing))}; an episode has {', '.join(schema)}",
        )
    extra = sorted(k for k in keys if k not in schema)
    if extra:
        raise EpisodeFormatError(source, f"unexpected key(s) {', '.join(map(repr, extra))}")


def check_lengths(lengths: Mapping[str, int], episode_length: int | None, source: Any) -> int:
    """Check that the per-step arrays' lengths agree with each other and with
    ``episode_length`` (when given) and are at least 1; return that length ``T``."""
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
    return check_in_memory(episode, source, SCHEMA)


def check_in_memory(episode: Mapping[str, Any], source: Any, schema: Mapping[str, KeySpec]) -> int:
    """Check keys, array types, dtypes and shapes of an in-memory episode against
    ``schema`` (:data:`SCHEMA` or :data:`RL_SCHEMA`); return its length ``T``."""
    check_keys(list(episode), source, schema)
    lengths: dict[str, int] = {}
    for key in schema:
        value = episode[key]
        if not isinstance(value, np.ndarray):
            raise EpisodeFormatError(
                source, f"key {key!r} is a {type(value).__name__}, expected a numpy array"
            )
        t = check_array(key, value.dtype, value.shape, source, schema)
        if t is not None:
            lengths[key] = t
    length = int(episode["episode_length"]) if "episode_length" in schema else None
    return check_lengths(lengths, length, source)


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
    t = check_in_memory(episode, source, RL_SCHEMA)

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
