"""Read any of the three dataset formats back into per-episode numpy dicts.

Every loader yields episodes in the NPZ schema of datasets spec §3 (``rgb`` (T,128,128,6)
uint8, ``proprio``/``action`` (T,7) float32, ``reward`` float32, ``success``/``done``
int32, ``language_instruction`` 0-d unicode, ``success_once``, ``episode_length``,
``episode_seed``), so the same code consumes raw, RLDS and LeRobot data:

* NPZ: exact (it *is* the format);
* RLDS: exact (PNG is lossless; every NPZ field has an RLDS counterpart, see
  :mod:`mikasa_datasets.rlds`);
* LeRobot: exact for state, action, reward, success, done and instruction; the camera
  frames went through a lossy video codec (see :mod:`mikasa_datasets.lerobot`).

What the converters share (their errors, the lazy import of optional format libraries,
the "write to a temporary path, rename when complete" output protocol behind
``--overwrite`` / ``--resume``) lives in :mod:`mikasa_datasets.conversion`; its names are
importable from here too. This module imports only numpy and :mod:`mikasa_datasets` at
module level; tensorflow / lerobot are imported on first use.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.conversion import (
    SETUP_HINT,  # noqa: F401 (re-exported: defined here before the split)
    DatasetFormatError,
    MissingDependencyError,
    OutputExistsError,
    commit_output,
    new_staging_dir,
    npz_task_files,  # noqa: F401 (re-exported: defined here before the split)
    output_action,
    remove_stale_staging,
    require,
)
from mikasa_datasets.naming import env_id_to_dataset_name
from mikasa_datasets.npz import list_episode_files, read_episode

__all__ = [
    "DatasetFormatError",
    "MissingDependencyError",
    "OutputExistsError",
    "commit_output",
    "detect_format",
    "find_task_dir",
    "iter_episodes",
    "iter_lerobot_episodes",
    "iter_npz_episodes",
    "iter_rlds_episodes",
    "load_episodes",
    "new_staging_dir",
    "output_action",
    "remove_stale_staging",
    "require",
    "synthetic_episode",
    "write_synthetic_task",
]


# --------------------------------------------------------------------------- task directories
def find_task_dir(root: str | os.PathLike[str], task: str) -> Path:
    """The directory of ``task`` under a dataset root, for either spelling of its name.

    Local conversions name task directories by dataset name; the published releases use
    the env id (spec §8). Tries ``root/task`` as given, then ``root/<dataset name>``;
    returns the dataset-name path when neither exists (so errors show the local spelling).
    """
    root = Path(root)
    for candidate in (root / task, root / env_id_to_dataset_name(task)):
        if candidate.is_dir():
            return candidate
    return root / env_id_to_dataset_name(task)


# --------------------------------------------------------------------------- format detection
def detect_format(path: str | os.PathLike[str]) -> str:
    """``"npz"``, ``"rlds"`` or ``"lerobot"`` for a dataset path, else DatasetFormatError.

    Recognised: an ``.npz`` file or a directory of ``train_data_<i>.npz`` (NPZ); a TFDS
    version directory (``dataset_info.json`` + ``features.json``) or a task directory
    holding ``X.Y.Z`` version sub-directories (RLDS); a directory with ``meta/info.json``
    (LeRobot).
    """
    p = Path(path)
    if not p.exists():
        raise DatasetFormatError(p, "no such file or directory")
    if p.is_file():
        if p.suffix == ".npz":
            return "npz"
        raise DatasetFormatError(p, "not a dataset: expected an .npz file or a dataset directory")
    if (p / "meta" / "info.json").is_file():
        return "lerobot"
    if (p / "dataset_info.json").is_file() or (p / "features.json").is_file():
        return "rlds"
    if any(_is_version(c.name) and c.is_dir() for c in p.iterdir()):
        return "rlds"
    if list_episode_files(p) or (p / "metadata.json").is_file():
        return "npz"
    raise DatasetFormatError(
        p,
        "not a recognised dataset directory (expected train_data_<i>.npz files, a TFDS "
        "version directory with dataset_info.json, a directory of X.Y.Z versions, or "
        "meta/info.json of a LeRobot dataset)",
    )


def _is_version(name: str) -> bool:
    parts = name.split(".")
    return len(parts) == 3 and all(x.isdigit() for x in parts)


# --------------------------------------------------------------------------- loaders
def iter_npz_episodes(task_dir: str | os.PathLike[str]) -> Iterator[dict[str, Any]]:
    """Episodes of an NPZ task directory (or one ``.npz`` file), in index order."""
    p = Path(task_dir)
    files = [p] if p.is_file() else list_episode_files(p)
    for f in files:
        yield read_episode(f)


def iter_rlds_episodes(path: str | os.PathLike[str]) -> Iterator[dict[str, Any]]:
    """Episodes of an RLDS task or version directory, in stored order (needs tensorflow)."""
    from mikasa_datasets import rlds

    yield from rlds.iter_episodes(path)


def iter_lerobot_episodes(path: str | os.PathLike[str]) -> Iterator[dict[str, Any]]:
    """Episodes of a LeRobot v3 dataset root, in episode order (needs pyarrow + av)."""
    from mikasa_datasets import lerobot

    yield from lerobot.iter_episodes(path)


def iter_episodes(path: str | os.PathLike[str], fmt: str | None = None) -> Iterator[dict[str, Any]]:
    """Episodes of any supported dataset at ``path`` (format auto-detected unless given)."""
    fmt = fmt or detect_format(path)
    loader = {
        "npz": iter_npz_episodes,
        "rlds": iter_rlds_episodes,
        "lerobot": iter_lerobot_episodes,
    }
    if fmt not in loader:
        raise ValueError(f"unknown format {fmt!r}; expected one of {sorted(loader)}")
    yield from loader[fmt](path)


def load_episodes(path: str | os.PathLike[str], fmt: str | None = None) -> list[dict[str, Any]]:
    """All episodes of the dataset at ``path`` as a list (see :func:`iter_episodes`)."""
    return list(iter_episodes(path, fmt))


# --------------------------------------------------------------------------- synthetic data
def synthetic_episode(
    rng: np.random.Generator, length: int, instruction: str, seed: int
) -> dict[str, Any]:
    """A schema-valid episode with render-like frames (for tests, benchmarks, smoke runs).

    Frames are a smooth background with a few flat-coloured blocks that move every step:
    no noise, like a rasterised scene, so video-codec quality on them is representative.
    Proprio/action/reward are random floats (action in [-1, 1]); the episode ends in
    success at its last step, as collected data does.
    """
    yy, xx = np.mgrid[0:128, 0:128].astype(np.float32)
    base = rng.uniform(40, 200, size=3).astype(np.float32)
    background = np.stack([base[0] + 0.3 * xx, base[1] + 0.2 * yy, base[2] + 0.1 * (xx + yy)], -1)
    blocks = [
        (rng.integers(8, 100, 2), rng.integers(-3, 4, 2), rng.integers(0, 256, 3)) for _ in range(3)
    ]
    rgb = np.empty((length, 128, 128, 6), dtype=np.uint8)
    for t in range(length):
        frame = background.copy()
        for (y, x), (vy, vx), colour in blocks:
            y0, x0 = int(np.clip(y + vy * t, 0, 104)), int(np.clip(x + vx * t, 0, 104))
            frame[y0 : y0 + 24, x0 : x0 + 24] = colour
        top = np.clip(frame, 0, 255).astype(np.uint8)
        rgb[t, :, :, :3] = top
        rgb[t, :, :, 3:] = top[::-1, ::-1]  # a different but related "wrist" view
    done = np.zeros(length, np.int32)
    done[-1] = 1
    return {
        "rgb": rgb,
        "proprio": rng.standard_normal((length, 7)).astype(np.float32),
        "action": rng.uniform(-1, 1, (length, 7)).astype(np.float32),
        "reward": rng.uniform(0, 1, length).astype(np.float32),
        "success": done.copy(),
        "done": done,
        "language_instruction": np.array(instruction),
        "success_once": np.array(True),
        "episode_length": np.array(length, dtype=np.int32),
        "episode_seed": np.array(seed, dtype=np.int64),
    }


def write_synthetic_task(
    npz_root: str | os.PathLike[str],
    env_id: str,
    lengths: list[int],
    *,
    instruction: str | list[str] = "Remember the colour of the cube, then touch the matching one.",
    seed: int = 0,
) -> Path:
    """Write ``len(lengths)`` synthetic episodes + metadata.json as an NPZ task directory.

    ``<npz_root>/<dataset_name>/train_data_<i>.npz`` with episode seeds ``seed + i``;
    ``instruction`` may be one string or one per episode. Returns the task directory.
    """
    from mikasa_datasets.npz import summarize_episode, write_episode, write_metadata

    d = Path(npz_root) / env_id_to_dataset_name(env_id)
    rng = np.random.default_rng(seed)
    summaries = []
    for i, length in enumerate(lengths):
        text = instruction[i] if isinstance(instruction, list) else instruction
        ep = synthetic_episode(rng, length, text, seed + i)
        path = write_episode(d / f"train_data_{i}.npz", ep)
        summaries.append(summarize_episode(ep, path))
    write_metadata(d, env_id, summaries)
    return d
