"""LeRobotDataset v3 export (RLDS -> LeRobot, NPZ -> LeRobot) and reading (datasets spec
§7), through lerobot's public API only (lerobot 0.4.x); nothing of lerobot is patched, so a
lerobot upgrade can change speed or defaults but not break what this code relies on
silently. Writing lives in :mod:`mikasa_datasets.lerobot_write`, the format's names and
lerobot's import in :mod:`mikasa_datasets.lerobot_format`; this module holds the reader and
re-exports the names of both, so every name is importable from here.

A written dataset is what lerobot produces: ``meta/info.json`` (``codebase_version``
v3.0), ``meta/stats.json``, ``meta/tasks.parquet``, ``meta/episodes/...``,
``data/chunk-XXX/file-XXX.parquet`` and one MP4 stream per camera under ``videos/``. It
loads offline with ``LeRobotDataset(repo_id, root=<dataset root>)``; `iter_episodes` and
`read_tables` read it that way (``meta``, ``hf_dataset`` and lerobot's video decoder).

Features (spec §7.2, plus the outcome columns, see below)::

    observation.images.top    video (128,128,3)  rgb[..., 0:3]  / steps/observation/image
    observation.images.wrist  video (128,128,3)  rgb[..., 3:6]  / steps/observation/wrist_image
    observation.state         float32 (7,)       proprio        / steps/observation/proprio
    action                    float32 (7,)       action         / steps/action
    next.reward               float32 (1,)       reward         / steps/reward
    next.success              bool (1,)          success        / steps/is_terminal
    next.done                 bool (1,)          done           / steps/is_last
    task (per frame)          the episode's language instruction

Decision on spec §9.3: the upstream converter exported only images/state/action; we also
write reward, success and done under LeRobot's conventional ``next.*`` names so that the
LeRobot release is self-contained (RL fine-tuning and success filtering need them) and
round-trips exactly. Consumers that read only the upstream four features are unaffected.
``fps`` defaults to 10 (spec §7.1), the codec to lerobot's default AV1 (`DEFAULT_VCODEC`;
why, and what the writer corrects after lerobot: :mod:`mikasa_datasets.lerobot_write`). Video is lossy (the tests assert
>= 28 dB per camera and episode); everything else round-trips exactly. The source
``metadata.json`` (NPZ or RLDS, same content) is copied to
``<dataset root>/source_rlds_metadata.json``; the reader takes episode seeds and
``success_once`` from it.

Environment notes (see the package README): lerobot 0.4.x pins torch<2.11 but its
dataset code runs on the repository's torch 2.13 CPU; PyPI's torchvision wheels are CUDA
builds whose C++ ops cannot load next to a CPU torch, which breaks ``import torchvision``
(needed by lerobot only for ``torchvision.transforms``).
:mod:`mikasa_datasets.torchvision_cpu` works around that: in ``.venv-datasets`` as a
start-up hook the setup script installs, elsewhere through
:func:`ensure_torchvision_importable`. Hugging Face Hub access is switched off
(``HF_HUB_OFFLINE=1``) before lerobot is imported: everything here is local.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from mikasa_datasets.conversion import ConversionResult, DatasetFormatError, require
from mikasa_datasets.lerobot_format import (
    ACTION_KEY,
    CAMERA_KEYS,
    DEFAULT_FPS,
    DEFAULT_VCODEC,
    DONE_KEY,
    IMAGE_SHAPE,  # noqa: F401 (re-exported: defined here before the split)
    LEROBOT_DIRNAME,
    REWARD_KEY,
    ROBOT_TYPE,
    SOURCE_METADATA_NAME,
    STATE_KEY,
    SUCCESS_KEY,
    TOP_KEY,
    WRIST_KEY,
    ensure_torchvision_importable,
    lerobot_dataset_class,
    lerobot_features,
)
from mikasa_datasets.lerobot_write import (
    EPISODES_PER_WORKER,
    VIDEO_FILE_SIZE_IN_MB,
    convert_npz_to_lerobot,
    convert_rlds_to_lerobot,
    write_lerobot,
    writer_count,
)

__all__ = [
    "ACTION_KEY",
    "ensure_torchvision_importable",
    "DEFAULT_FPS",
    "DEFAULT_VCODEC",
    "DONE_KEY",
    "EPISODES_PER_WORKER",
    "LEROBOT_DIRNAME",
    "REWARD_KEY",
    "ROBOT_TYPE",
    "SOURCE_METADATA_NAME",
    "STATE_KEY",
    "SUCCESS_KEY",
    "TOP_KEY",
    "VIDEO_FILE_SIZE_IN_MB",
    "WRIST_KEY",
    "ConversionResult",
    "convert_npz_to_lerobot",
    "convert_rlds_to_lerobot",
    "iter_episodes",
    "lerobot_dataset_class",
    "lerobot_features",
    "psnr",
    "read_info",
    "read_tables",
    "write_lerobot",
    "writer_count",
]


# --------------------------------------------------------------------------- reading
def read_info(root: str | os.PathLike[str]) -> dict[str, Any]:
    """``meta/info.json`` of a LeRobot dataset root, through lerobot's ``load_info``
    (feature shapes as tuples); DatasetFormatError if missing or unreadable."""
    path = Path(root) / "meta" / "info.json"
    if not path.is_file():
        raise DatasetFormatError(path, "missing; not a LeRobot dataset root")
    lerobot_dataset_class()
    from lerobot.datasets.utils import load_info

    try:
        return load_info(Path(root))
    except (OSError, ValueError) as exc:
        raise DatasetFormatError(path, f"unreadable: {exc}") from exc


def _open_dataset(root: Path) -> Any:
    """``LeRobotDataset(<root name>, root=root)``, loaded offline; a failure is reported as
    a DatasetFormatError naming the file at fault (`_diagnose`)."""
    read_info(root)  # first: LeRobotDataset creates a missing root and asks the Hub for it
    cls = lerobot_dataset_class()
    try:
        with contextlib.redirect_stderr(io.StringIO()):  # datasets' loading progress bars
            return cls(root.name, root=root)
    except Exception as exc:
        _diagnose(root, exc)


def _diagnose(root: Path, exc: Exception) -> NoReturn:
    """Raise a DatasetFormatError naming the file that made ``LeRobotDataset`` fail.

    lerobot reports a corrupt parquet file as an Arrow error without its path, and a
    missing video as a failed Hub download; it has no API that checks a dataset's files,
    so each is opened here with pyarrow, and the listed videos are looked up through
    ``LeRobotDatasetMetadata.get_video_file_path``.
    """
    pq = require("pyarrow.parquet", "lerobot")
    groups = (
        ("episode metadata", root / "meta" / "episodes"),
        ("frame data", root / "data"),
    )
    for what, folder in groups:
        files = sorted(folder.glob("*/*.parquet"))
        if not files:
            raise DatasetFormatError(folder, f"no {what} parquet files") from exc
        for path in files:
            try:
                pq.read_table(path)
            except Exception as bad:
                raise DatasetFormatError(
                    path, f"unreadable {what} parquet file (corrupt or truncated?): {bad}"
                ) from exc
    tasks = root / "meta" / "tasks.parquet"
    try:
        pq.read_table(tasks)
    except FileNotFoundError:
        raise DatasetFormatError(tasks, "missing") from exc
    except Exception as bad:
        raise DatasetFormatError(tasks, f"unreadable (corrupt or truncated?): {bad}") from exc
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    try:
        meta = LeRobotDatasetMetadata(root.name, root=root)
    except Exception as bad:
        raise DatasetFormatError(root / "meta", f"lerobot cannot load it: {bad}") from exc
    for index in range(meta.total_episodes):
        for key in meta.video_keys:
            path = root / meta.get_video_file_path(index, key)
            if not path.is_file():
                raise DatasetFormatError(path, "video file listed in meta/episodes is missing")
    raise DatasetFormatError(root, f"LeRobotDataset cannot load it: {exc}") from exc


def read_tables(root: str | os.PathLike[str]) -> tuple[dict[str, Any], Any, Any, dict[int, str]]:
    """``(info, episodes, frames, tasks)`` of a LeRobot dataset, loaded by ``LeRobotDataset``.

    ``info`` is ``meta.info``, ``episodes`` the ``meta.episodes`` table (pandas, without the
    per-episode statistics, sorted by episode index), ``frames`` ``hf_dataset`` as pandas
    (sorted by global ``index``; video frames are not in it), ``tasks`` task index -> task
    string. Errors name the offending file.
    """
    dataset = _open_dataset(Path(root))
    episodes = dataset.meta.episodes.to_pandas()
    episodes = episodes.sort_values("episode_index").reset_index(drop=True)
    frames = dataset.hf_dataset.with_format(None).to_pandas()
    frames = frames.sort_values("index").reset_index(drop=True)
    return dataset.meta.info, episodes, frames, _tasks(dataset)


def _tasks(dataset: Any) -> dict[int, str]:
    """task index -> task string, from ``meta.tasks`` (indexed by the task string)."""
    tasks = dataset.meta.tasks
    return {int(i): str(t) for t, i in zip(tasks.index, tasks["task_index"], strict=True)}


def _source_metadata(root: Path) -> dict[str, Any]:
    path = root / SOURCE_METADATA_NAME
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetFormatError(path, f"unreadable: {exc}") from exc


def _episode_video(
    dataset: Any, index: int, key: str, timestamps: np.ndarray, cache: Any
) -> np.ndarray:
    """Episode ``index``'s frames of camera ``key`` (T,H,W,3 uint8), decoded by lerobot's
    ``decode_video_frames`` at the episode's timestamps, as ``LeRobotDataset.__getitem__``
    does frame by frame. With torchcodec, through a decoder cache of our own: lerobot's
    default cache keeps every file it opened open for the life of the process, and would
    serve a dataset rewritten at the same path from the old file."""
    import torch
    from lerobot.datasets.video_utils import decode_video_frames, decode_video_frames_torchcodec

    episode = dataset.meta.episodes[index]
    path = dataset.root / dataset.meta.get_video_file_path(index, key)
    if not path.is_file():
        raise DatasetFormatError(path, "video file listed in meta/episodes is missing")
    start = float(episode[f"videos/{key}/from_timestamp"])
    query = [start + float(t) for t in timestamps]
    try:
        if dataset.video_backend == "torchcodec":
            frames = decode_video_frames_torchcodec(
                path, query, dataset.tolerance_s, decoder_cache=cache
            )
        else:
            frames = decode_video_frames(path, query, dataset.tolerance_s, dataset.video_backend)
    except Exception as exc:
        raise DatasetFormatError(
            path,
            f"video cannot be decoded (corrupt or truncated?) for episode {index} "
            f"({len(query)} frames from {start:.3f}s): {exc}",
        ) from exc
    # lerobot hands frames out as float32 in [0, 1] (uint8 / 255): exactly invertible.
    return (frames * 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()


def iter_episodes(path: str | os.PathLike[str]) -> Iterator[dict[str, np.ndarray]]:
    """Episodes of a LeRobot v3 dataset root in the NPZ schema, in episode order, read
    through ``LeRobotDataset``.

    State, action, reward, success, done and instruction are exact; ``rgb`` holds the
    decoded video frames (lossy codec) or the stored images (``--no-videos``).
    ``episode_seed``/``success_once`` come from ``source_rlds_metadata.json`` (-1 / True
    without it).
    """
    from lerobot.datasets.video_utils import VideoDecoderCache

    root = Path(path)
    dataset = _open_dataset(root)
    frames = dataset.hf_dataset.with_format("numpy")
    tasks = _tasks(dataset)
    source = _source_metadata(root)
    seeds = source.get("episode_seeds", [])
    success_once = source.get("success_once", [])
    cache = VideoDecoderCache()
    try:
        for index in range(dataset.meta.total_episodes):
            episode = dataset.meta.episodes[index]
            lo, hi = int(episode["dataset_from_index"]), int(episode["dataset_to_index"])
            rows = frames[lo:hi]
            if int(episode["episode_index"]) != index or not (
                np.array_equal(rows["index"], np.arange(lo, hi))
                and (rows["episode_index"] == index).all()
            ):
                raise DatasetFormatError(
                    root / "data", f"episode {index}'s frames are not rows {lo}..{hi - 1}"
                )
            cameras = [
                _episode_video(dataset, index, key, rows["timestamp"], cache)
                if key in dataset.meta.video_keys
                else np.asarray(rows[key], dtype=np.uint8)
                for key in CAMERA_KEYS
            ]
            length = hi - lo
            yield {
                "rgb": np.concatenate(cameras, axis=-1),
                "proprio": np.asarray(rows[STATE_KEY], dtype=np.float32).reshape(length, 7),
                "action": np.asarray(rows[ACTION_KEY], dtype=np.float32).reshape(length, 7),
                "reward": np.asarray(rows[REWARD_KEY], dtype=np.float32).reshape(length),
                "success": np.asarray(rows[SUCCESS_KEY]).reshape(length).astype(np.int32),
                "done": np.asarray(rows[DONE_KEY]).reshape(length).astype(np.int32),
                "language_instruction": np.array(tasks.get(int(rows["task_index"][0]), "")),
                "success_once": np.array(
                    bool(success_once[index]) if index < len(success_once) else True
                ),
                "episode_length": np.array(length, dtype=np.int32),
                "episode_seed": np.array(
                    int(seeds[index]) if index < len(seeds) else -1, dtype=np.int64
                ),
            }
    finally:
        cache.clear()


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two uint8 arrays (inf when identical)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)
