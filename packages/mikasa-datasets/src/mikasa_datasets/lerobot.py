"""RLDS -> LeRobotDataset v3 and NPZ -> LeRobotDataset v3 export, and LeRobot reading
(datasets spec §7).

Writing goes through lerobot's own API (``LeRobotDataset.create`` / ``add_frame`` /
``save_episode`` / ``finalize``, lerobot 0.4.x), so the result is exactly what lerobot
produces: ``meta/info.json`` (``codebase_version`` v3.0), ``meta/stats.json``,
``meta/tasks.parquet``, ``meta/episodes/...``, ``data/chunk-XXX/file-XXX.parquet`` and one
MP4 stream per camera under ``videos/``. It loads offline with
``LeRobotDataset(repo_id, root=<dataset root>)``.

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

Videos: codec pinned to AV1 (``libsvtav1``, lerobot's default; yuv420p, crf 30, GOP 2),
encoded while frames are added (lerobot's streaming encoder, with a queue large enough
that no frame is ever dropped). Video is lossy: frames come back within a PSNR tolerance
(>= 30 dB on rendered scenes; the tests assert it), everything else is exact. ``fps``
defaults to 10 (spec §7.1). The source ``metadata.json`` (NPZ or RLDS, same content) is
copied to ``<dataset root>/source_rlds_metadata.json``; the loader takes episode seeds
and ``success_once`` from it.

Three fixes to lerobot 0.4.4's writer apply while we write (`_lerobot_writer_fixes`,
restored after): image statistics computed from each frame's value counts, which is
right where lerobot's uint8 arithmetic wrapped (stats.json had a wrong image std; upstream
fixed it later, huggingface/lerobot#3697) and ~20x cheaper than its per-pixel histogram
update; ``embed_images``, a no-op for video features that cost ~4 ms per frame, skipped;
video files cut at `VIDEO_FILE_SIZE_IN_MB` so that appending an episode (a re-mux of the
whole current file) stays cheap. Together: 1.6x faster conversion of the synthetic
benchmark task.

Environment notes (see the package README): lerobot 0.4.x pins torch<2.11 but its
dataset code runs on the repository's torch 2.13 CPU; PyPI's torchvision wheels are CUDA
builds whose C++ ops cannot load next to a CPU torch, which breaks ``import torchvision``
(needed by lerobot only for ``torchvision.transforms``). :func:`_ensure_torchvision`
works around that. Hugging Face Hub access is switched off (``HF_HUB_OFFLINE=1``) before
lerobot is imported: everything here is local.
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import json
import os
import queue
import shutil
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.loaders import (
    DatasetFormatError,
    commit_output,
    new_staging_dir,
    output_action,
    remove_stale_staging,
    require,
)
from mikasa_datasets.naming import env_id_to_dataset_name
from mikasa_datasets.npz import EpisodeFormatError, list_episode_files, read_episode, read_metadata
from mikasa_datasets.rlds import ConversionResult

__all__ = [
    "ACTION_KEY",
    "DEFAULT_FPS",
    "DEFAULT_VCODEC",
    "DONE_KEY",
    "LEROBOT_DIRNAME",
    "REWARD_KEY",
    "ROBOT_TYPE",
    "SOURCE_METADATA_NAME",
    "STATE_KEY",
    "SUCCESS_KEY",
    "TOP_KEY",
    "WRIST_KEY",
    "convert_npz_to_lerobot",
    "convert_rlds_to_lerobot",
    "iter_episodes",
    "lerobot_dataset_class",
    "lerobot_features",
    "psnr",
    "write_lerobot",
]

LEROBOT_DIRNAME = "data_lerobot"
DEFAULT_FPS = 10
ROBOT_TYPE = "mikasa_robo"
DEFAULT_VCODEC = "libsvtav1"
SOURCE_METADATA_NAME = "source_rlds_metadata.json"

TOP_KEY = "observation.images.top"
WRIST_KEY = "observation.images.wrist"
STATE_KEY = "observation.state"
ACTION_KEY = "action"
REWARD_KEY = "next.reward"
SUCCESS_KEY = "next.success"
DONE_KEY = "next.done"
CAMERA_KEYS = (TOP_KEY, WRIST_KEY)
STREAMING_DEFAULT = True
IMAGE_SHAPE = (128, 128, 3)


# --------------------------------------------------------------------------- lerobot import
_TORCHVISION_OPS_LIB: Any = None  # keeps the placeholder op library alive


def _ensure_torchvision() -> None:
    """Make ``import torchvision`` work with a CPU torch and PyPI's CUDA torchvision.

    torchvision's ``_C`` ops library links against libtorch_cuda, so with the CPU build of
    torch it fails to load (torchvision tolerates that), and then its import dies
    registering fake kernels for ``torchvision::nms``/``qnms``, ops that only ``_C``
    defines. Declaring those two schemas first lets the pure-Python parts (transforms,
    which lerobot uses) import; the detection ops stay unusable, and nothing here calls
    them. A torchvision whose ``_C`` loads is left untouched.
    """
    global _TORCHVISION_OPS_LIB
    try:
        import torchvision  # noqa: F401
    except RuntimeError as exc:
        if "torchvision::" not in str(exc):
            raise
        for name in [m for m in sys.modules if m == "torchvision" or m.startswith("torchvision.")]:
            del sys.modules[name]
        import torch

        _TORCHVISION_OPS_LIB = torch.library.Library("torchvision", "DEF")
        _TORCHVISION_OPS_LIB.define(
            "nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor"
        )
        _TORCHVISION_OPS_LIB.define(
            "qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor"
        )
        import torchvision  # noqa: F401,F811


@functools.cache
def lerobot_dataset_class() -> type:
    """``lerobot.datasets.lerobot_dataset.LeRobotDataset``, imported offline and quietly."""
    # Must precede the first huggingface_hub / datasets import: both read it at import.
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")  # datasets imports TF when present
    os.environ.setdefault("TF_ENABLE_ONEDNN_OPTS", "0")
    require("torch", "lerobot")
    _ensure_torchvision()
    module = require("lerobot.datasets.lerobot_dataset", "lerobot")
    # datasets' per-episode "Map" progress bars and SVT-AV1's banner go to the terminal
    # on every episode; a converter reports through its own progress callback.
    try:
        import datasets

        datasets.disable_progress_bars()
    except Exception:  # pragma: no cover - cosmetic only
        pass
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    return module.LeRobotDataset


def lerobot_features(*, use_videos: bool = True) -> dict[str, dict[str, Any]]:
    """The LeRobot ``features`` mapping written by the converters (module docstring)."""
    cam = {
        "dtype": "video" if use_videos else "image",
        "shape": IMAGE_SHAPE,
        "names": ["height", "width", "channel"],
    }
    return {
        TOP_KEY: dict(cam),
        WRIST_KEY: dict(cam),
        STATE_KEY: {"dtype": "float32", "shape": (7,), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (7,), "names": None},
        REWARD_KEY: {"dtype": "float32", "shape": (1,), "names": None},
        SUCCESS_KEY: {"dtype": "bool", "shape": (1,), "names": None},
        DONE_KEY: {"dtype": "bool", "shape": (1,), "names": None},
    }


# --------------------------------------------------------------------------- writing
VIDEO_FILE_SIZE_IN_MB = 4.0
"""Video files are cut at this size (lerobot's default: 200 MB). lerobot appends each
episode to the current file by re-muxing the whole file, so an episode costs time in
proportion to that file's size; at 128x128 a 200 MB file holds thousands of episodes and
a task's conversion became quadratic in its episode count."""


def _update_from_value_counts(stats: Any, rows: np.ndarray) -> None:
    """``RunningQuantileStats.update`` for uint8 ``rows`` [N, C], computed from each
    channel's 256 value counts: the state lerobot's update reaches on the rows promoted to
    floats (mean and mean of squares exact, in float64; the same histogram bins and
    counts), in a fraction of the time."""
    n, channels = rows.shape
    counts = np.stack([np.bincount(rows[:, c], minlength=256) for c in range(channels)])
    values = np.arange(256, dtype=np.float64)
    present = counts > 0
    batch_min = values[present.argmax(axis=1)]
    batch_max = values[255 - present[:, ::-1].argmax(axis=1)]
    batch_mean, batch_mean_of_squares = counts @ values / n, counts @ (values * values) / n
    bins = stats._num_quantile_bins
    if stats._count == 0:
        stats._mean, stats._mean_of_squares = batch_mean.copy(), batch_mean_of_squares.copy()
        stats._min, stats._max = batch_min, batch_max
        stats._histograms = [np.zeros(bins) for _ in range(channels)]
        stats._bin_edges = [
            np.linspace(lo - 1e-10, hi + 1e-10, bins + 1) for lo, hi in zip(batch_min, batch_max, strict=True)
        ]
    else:
        if channels != stats._mean.size:
            raise ValueError("The length of new vectors does not match the initialized vector length.")
        changed = bool(np.any(batch_max > stats._max) or np.any(batch_min < stats._min))
        stats._max, stats._min = np.maximum(stats._max, batch_max), np.minimum(stats._min, batch_min)
        if changed:
            stats._adjust_histograms()
    stats._count += n
    stats._mean += (batch_mean - stats._mean) * (n / stats._count)
    stats._mean_of_squares += (batch_mean_of_squares - stats._mean_of_squares) * (n / stats._count)
    for c in range(channels):
        hist, _ = np.histogram(values, bins=stats._bin_edges[c], weights=counts[c])
        stats._histograms[c] += hist


def _patch_running_stats(stats_class: type) -> Callable[[], None]:
    """Route uint8 batches (camera frames) of lerobot's ``RunningQuantileStats.update``
    through `_update_from_value_counts`; return the undo.

    Two reasons. lerobot 0.4.x squares uint8 pixels in uint8, the values wrap, and
    stats.json got a wrong image std (0.04-0.16 for 0.11-0.21 here; upstream fixed it by
    promoting to float32, huggingface/lerobot#3697). And its streaming encoder updates the
    statistics for every frame of every camera, in Python, with the GIL held: ~4 ms per
    camera-frame, ~45% of a conversion's CPU time.
    """
    original_update = stats_class.update
    probe = stats_class()
    if not all(hasattr(probe, name) for name in ("_adjust_histograms", "_num_quantile_bins", "_count")):
        return lambda: None  # another lerobot: left as it is

    @functools.wraps(original_update)
    def update(self: Any, batch: np.ndarray) -> None:
        batch = np.asarray(batch)
        if batch.dtype != np.uint8 or batch.size == 0:
            return original_update(self, batch)
        _update_from_value_counts(self, batch.reshape(-1, batch.shape[-1]))

    stats_class.update = update
    return lambda: setattr(stats_class, "update", original_update)


_FIXES_LOCK = threading.Lock()
_fixes_depth = 0
_undo_fixes: list[Callable[[], None]] = []


@contextlib.contextmanager
def _lerobot_writer_fixes() -> Iterator[None]:
    """Fixes to lerobot's writer, for the duration of a write, restored after:

    * image statistics right, and computed faster (`_patch_running_stats`);
    * ``embed_images`` (a ``datasets`` map over every frame of every episode that embeds
      image files into the parquet table) skipped for episodes without image features:
      with cameras stored as videos it changes nothing and cost ~4 ms per frame.

    The patches are lerobot's module attributes, so writes in several threads share them:
    the first to enter applies them, the last to leave undoes them.
    """
    global _fixes_depth
    with _FIXES_LOCK:
        if _fixes_depth == 0:
            _undo_fixes[:] = _apply_writer_fixes()
        _fixes_depth += 1
    try:
        yield
    finally:
        with _FIXES_LOCK:
            _fixes_depth -= 1
            if _fixes_depth == 0:
                for undo in reversed(_undo_fixes):
                    undo()
                _undo_fixes.clear()


def _apply_writer_fixes() -> list[Callable[[], None]]:
    """Apply the fixes of `_lerobot_writer_fixes`; return their undos."""
    from lerobot.datasets import compute_stats
    from lerobot.datasets import lerobot_dataset as lerobot_module

    original_embed = lerobot_module.embed_images

    def embed_images(dataset: Any) -> Any:
        import datasets

        if any(isinstance(feature, datasets.Image) for feature in dataset.features.values()):
            return original_embed(dataset)
        return dataset

    undo_stats = _patch_running_stats(compute_stats.RunningQuantileStats)
    lerobot_module.embed_images = embed_images
    return [undo_stats, lambda: setattr(lerobot_module, "embed_images", original_embed)]


def write_lerobot(
    episodes: Iterable[dict[str, np.ndarray]],
    root: str | os.PathLike[str],
    repo_id: str,
    *,
    fps: int = DEFAULT_FPS,
    robot_type: str = ROBOT_TYPE,
    use_videos: bool = True,
    vcodec: str = DEFAULT_VCODEC,
    default_task: str = "",
    source_metadata: str | os.PathLike[str] | None = None,
    progress: Callable[[int], None] | None = None,
    streaming: bool = STREAMING_DEFAULT,
    image_writer_threads: int = 2,
) -> tuple[int, int]:
    """Write NPZ-schema ``episodes`` as a new LeRobot v3 dataset at ``root``.

    ``root`` must not exist (lerobot creates it). One ``save_episode`` per episode, then
    ``finalize``. ``task`` per frame is the episode instruction, stripped; an empty one
    falls back to the last non-empty instruction seen (initially ``default_task``), as in
    the upstream converter. Returns ``(episodes, frames)`` written.
    """
    cls = lerobot_dataset_class()
    kwargs: dict[str, Any] = {
        "repo_id": repo_id,
        "fps": fps,
        "features": lerobot_features(use_videos=use_videos),
        "root": root,
        "robot_type": robot_type,
        "use_videos": use_videos,
        "vcodec": vcodec,
    }
    supported = inspect.signature(cls.create).parameters
    if not (use_videos and streaming and "streaming_encoding" in supported):
        # Frames go to PNG files through lerobot's image-writer threads and are encoded
        # per episode in save_episode.
        kwargs["image_writer_threads"] = image_writer_threads
    else:
        # Encode while frames arrive instead of writing PNGs and re-reading them; the queue
        # must never fill up: lerobot drops frames (with a warning) when it does.
        kwargs.update(streaming_encoding=True, encoder_queue_maxsize=1_000_000)
        if "encoder_threads" in supported:
            # Two camera encoders run side by side; one SVT-AV1 thread pool each avoids
            # oversubscribing small machines.
            kwargs["encoder_threads"] = max(1, (os.cpu_count() or 2) // 2)
    dataset = cls.create(**{k: v for k, v in kwargs.items() if k in supported})
    if "video_files_size_in_mb" in dataset.meta.info:
        dataset.meta.info["video_files_size_in_mb"] = VIDEO_FILE_SIZE_IN_MB
    save_kwargs = (
        {"parallel_encoding": False}
        if "parallel_encoding" in inspect.signature(dataset.save_episode).parameters
        else {}
    )
    last_task = default_task
    n_eps = n_frames = 0
    import datasets

    # lerobot turns every episode into a datasets.Dataset and maps over it; with caching on,
    # datasets fingerprints each step by pickling the transform (~8% of the conversion).
    # Nothing here is ever reloaded from datasets' cache, so random fingerprints suffice.
    caching = datasets.is_caching_enabled()
    datasets.disable_caching()
    completed = False
    fixes = contextlib.ExitStack()
    try:
        fixes.enter_context(_lerobot_writer_fixes())
        # lerobot's histogram stats cast the bool next.* columns to uint8 and warn each time.
        warnings.filterwarnings(
            "ignore", message="Converting input from bool", category=RuntimeWarning
        )
        for ep in episodes:
            text = str(ep["language_instruction"]).strip()
            if text:
                last_task = text
            rgb, proprio, action = ep["rgb"], ep["proprio"], ep["action"]
            reward = ep["reward"].reshape(-1, 1).astype(np.float32, copy=False)
            success = ep["success"].reshape(-1, 1).astype(bool)
            done = ep["done"].reshape(-1, 1).astype(bool)
            for t in range(int(ep["episode_length"])):
                dataset.add_frame(
                    {
                        TOP_KEY: rgb[t, :, :, 0:3],
                        WRIST_KEY: rgb[t, :, :, 3:6],
                        STATE_KEY: proprio[t],
                        ACTION_KEY: action[t],
                        REWARD_KEY: reward[t],
                        SUCCESS_KEY: success[t],
                        DONE_KEY: done[t],
                        "task": last_task,
                    }
                )
            dataset.save_episode(**save_kwargs)
            n_eps += 1
            n_frames += int(ep["episode_length"])
            if progress is not None:
                progress(n_eps)
        completed = True
    finally:
        fixes.close()
        if caching:
            datasets.enable_caching()
        # Parquet footers are written here; without it nothing is loadable. After an error
        # (the staging directory is discarded by the caller anyway) a failure to finalize
        # must not mask the original exception, which names the bad input.
        try:
            dataset.finalize()
        except Exception:
            if completed:
                raise
    if source_metadata is not None and Path(source_metadata).is_file():
        shutil.copyfile(source_metadata, Path(root) / SOURCE_METADATA_NAME)
    return n_eps, n_frames


def _prefetch(items: Iterator[Any], depth: int = 3) -> Iterator[Any]:
    """Yield from ``items`` while a background thread reads up to ``depth`` ahead.

    Reading an episode (NPZ CRC checks, RLDS record parsing and PNG decoding, which release
    the GIL) then overlaps with lerobot's writing instead of adding to it. An exception in
    the reader is re-raised in the consumer, at the position it occurred.
    """
    done = object()
    buffer: queue.Queue[Any] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def produce() -> None:
        try:
            for item in items:
                while not stop.is_set():
                    try:
                        buffer.put((True, item), timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            buffer.put((True, done))
        except BaseException as exc:  # handed to the consumer
            buffer.put((False, exc))

    thread = threading.Thread(target=produce, name="mikasa-datasets-reader", daemon=True)
    thread.start()
    try:
        while True:
            ok, item = buffer.get()
            if not ok:
                raise item
            if item is done:
                return
            yield item
    finally:
        stop.set()
        thread.join(timeout=5)


def _convert(
    episodes: Callable[[], Iterator[dict[str, np.ndarray]]],
    *,
    name: str,
    num_episodes: int,
    lerobot_root: str | os.PathLike[str],
    repo_id_template: str,
    source_metadata: Path | None,
    default_task: str,
    overwrite: bool,
    resume: bool,
    fps: int,
    robot_type: str,
    use_videos: bool,
    vcodec: str,
    progress: Callable[[int, int], None] | None,
) -> ConversionResult:
    lerobot_dataset_class()  # import first: library start-up is not conversion time
    t0 = time.perf_counter()
    if "{task}" not in repo_id_template:
        raise ValueError(f"repo id template {repo_id_template!r} must contain '{{task}}'")
    repo_id = repo_id_template.format(task=name)
    final = Path(lerobot_root).joinpath(*repo_id.split("/"))

    def complete(existing: Path) -> bool:
        try:
            info = json.loads((existing / "meta" / "info.json").read_text())
            return int(info["total_episodes"]) == num_episodes and int(info["fps"]) == fps
        except (OSError, ValueError, KeyError):
            return False

    if output_action(final, overwrite=overwrite, resume=resume, is_complete=complete) == "skip":
        return ConversionResult(final, num_episodes, 0, time.perf_counter() - t0, skipped=True)
    remove_stale_staging(final)
    staging = new_staging_dir(final)
    try:
        n_eps, n_frames = write_lerobot(
            _prefetch(episodes()),
            staging,
            repo_id,
            fps=fps,
            robot_type=robot_type,
            use_videos=use_videos,
            vcodec=vcodec,
            default_task=default_task,
            source_metadata=source_metadata,
            progress=None if progress is None else (lambda done: progress(done, num_episodes)),
        )
        commit_output(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return ConversionResult(final, n_eps, n_frames, time.perf_counter() - t0)


def convert_npz_to_lerobot(
    npz_task_dir: str | os.PathLike[str],
    lerobot_root: str | os.PathLike[str],
    *,
    repo_id_template: str = "{task}",
    overwrite: bool = False,
    resume: bool = False,
    max_episodes: int | None = None,
    fps: int = DEFAULT_FPS,
    robot_type: str = ROBOT_TYPE,
    use_videos: bool = True,
    vcodec: str = DEFAULT_VCODEC,
    progress: Callable[[int, int], None] | None = None,
) -> ConversionResult:
    """Convert an NPZ task directory straight to ``<lerobot_root>/<repo id>/``.

    Each episode is read with the schema check and §3.1 invariants (errors name the
    file). Built in a hidden staging directory, renamed into place when finalized.
    ``overwrite``/``resume`` as in :func:`mikasa_datasets.rlds.convert_npz_to_rlds`
    (resume keeps an output with the same episode count and fps).
    """
    src = Path(npz_task_dir)
    if not src.is_dir():
        raise DatasetFormatError(src, "NPZ task directory does not exist")
    files = list_episode_files(src)
    if not files:
        raise DatasetFormatError(src, "no train_data_<i>.npz episode files")
    if max_episodes is not None:
        files = files[:max_episodes]
    meta_path = src / "metadata.json"
    env_id = str(read_metadata(src).get("env_id", src.name)) if meta_path.is_file() else src.name

    def episodes() -> Iterator[dict[str, np.ndarray]]:
        for f in files:
            try:
                yield read_episode(f, validate=True)
            except EpisodeFormatError:
                raise
            except Exception as exc:
                raise DatasetFormatError(f, f"cannot be read: {exc}") from exc

    return _convert(
        episodes,
        name=env_id_to_dataset_name(src.name),
        num_episodes=len(files),
        lerobot_root=lerobot_root,
        repo_id_template=repo_id_template,
        source_metadata=meta_path if meta_path.is_file() else None,
        default_task=env_id,
        overwrite=overwrite,
        resume=resume,
        fps=fps,
        robot_type=robot_type,
        use_videos=use_videos,
        vcodec=vcodec,
        progress=progress,
    )


def convert_rlds_to_lerobot(
    rlds_task_dir: str | os.PathLike[str],
    lerobot_root: str | os.PathLike[str],
    *,
    repo_id_template: str = "{task}",
    overwrite: bool = False,
    resume: bool = False,
    max_episodes: int | None = None,
    fps: int = DEFAULT_FPS,
    robot_type: str = ROBOT_TYPE,
    use_videos: bool = True,
    vcodec: str = DEFAULT_VCODEC,
    progress: Callable[[int, int], None] | None = None,
) -> ConversionResult:
    """Convert an RLDS task directory (latest ``X.Y.Z``) or version directory to LeRobot.

    The task name is the RLDS task directory's name (normalised to a dataset name).
    Corrupt shards raise an error naming the shard. Needs tensorflow and lerobot in one
    environment (``.venv-datasets``).
    """
    from mikasa_datasets import rlds

    rlds._tfds()  # import TF before lerobot's timer starts (see _convert)
    vdir = rlds.find_version_dir(rlds_task_dir)
    task_dir = vdir.parent  # <rlds_root>/<task>/<X.Y.Z>; <task> may be an env id (spec §8)
    info = json.loads((vdir / "dataset_info.json").read_text(encoding="utf-8"))
    total = rlds._num_examples(info)
    n = total if max_episodes is None else min(total, max_episodes)
    meta_path = vdir / "metadata.json"
    env_id = task_dir.name
    if meta_path.is_file():
        env_id = str(json.loads(meta_path.read_text(encoding="utf-8")).get("env_id", env_id))

    def episodes() -> Iterator[dict[str, np.ndarray]]:
        for i, ep in enumerate(rlds.iter_episodes(vdir)):
            if i >= n:
                return
            yield ep

    return _convert(
        episodes,
        name=env_id_to_dataset_name(task_dir.name),
        num_episodes=n,
        lerobot_root=lerobot_root,
        repo_id_template=repo_id_template,
        source_metadata=meta_path if meta_path.is_file() else None,
        default_task=env_id,
        overwrite=overwrite,
        resume=resume,
        fps=fps,
        robot_type=robot_type,
        use_videos=use_videos,
        vcodec=vcodec,
        progress=progress,
    )


# --------------------------------------------------------------------------- reading
def read_info(root: str | os.PathLike[str]) -> dict[str, Any]:
    """``meta/info.json`` of a LeRobot dataset root (DatasetFormatError if unreadable)."""
    path = Path(root) / "meta" / "info.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise DatasetFormatError(path, "missing; not a LeRobot dataset root") from exc
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetFormatError(path, f"unreadable: {exc}") from exc


def _read_parquet(path: Path, what: str) -> Any:
    pq = require("pyarrow.parquet", "lerobot")
    try:
        return pq.read_table(path).to_pandas()
    except Exception as exc:
        raise DatasetFormatError(
            path, f"unreadable {what} parquet file (corrupt or truncated?): {exc}"
        ) from exc


def read_tables(root: str | os.PathLike[str]) -> tuple[dict[str, Any], Any, Any, dict[int, str]]:
    """``(info, episodes, frames, tasks)`` of a LeRobot dataset as pandas objects.

    ``episodes`` is the concatenated ``meta/episodes`` table sorted by episode index,
    ``frames`` the concatenated ``data`` table sorted by global ``index``, ``tasks`` maps
    task index -> task string. Errors name the offending file.
    """
    root = Path(root)
    pd = require("pandas", "lerobot")
    info = read_info(root)
    ep_files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not ep_files:
        raise DatasetFormatError(root / "meta" / "episodes", "no episode metadata parquet files")
    episodes = pd.concat(
        [_read_parquet(f, "episode metadata") for f in ep_files], ignore_index=True
    )
    episodes = episodes.sort_values("episode_index").reset_index(drop=True)
    data_files = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    if not data_files:
        raise DatasetFormatError(root / "data", "no data parquet files")
    frames = pd.concat([_read_parquet(f, "frame data") for f in data_files], ignore_index=True)
    frames = frames.sort_values("index").reset_index(drop=True)
    tasks_path = root / "meta" / "tasks.parquet"
    if not tasks_path.is_file():
        raise DatasetFormatError(tasks_path, "missing")
    tasks_df = _read_parquet(tasks_path, "tasks")
    if "task_index" not in tasks_df.columns:
        raise DatasetFormatError(tasks_path, "has no task_index column")
    names = tasks_df["task"] if "task" in tasks_df.columns else tasks_df.index
    tasks = {int(i): str(t) for t, i in zip(names, tasks_df["task_index"], strict=True)}
    return info, episodes, frames, tasks


class _VideoReader:
    """Sequential frame reader over one camera's MP4 files (PyAV, decoded in order).

    LeRobot appends episodes to a video file in episode order, so reading episodes in
    order only ever moves forward: each file is decoded once, start to end.
    """

    def __init__(self, root: Path, info: dict[str, Any], key: str) -> None:
        self.root, self.info, self.key = root, info, key
        self.fps = int(info["fps"])
        self._path: Path | None = None
        self._frames: Iterator[Any] | None = None
        self._container: Any = None
        self._next_index = 0  # index in the current file of the next decoded frame

    def _open(self, path: Path) -> None:
        av = require("av", "lerobot")
        self.close()
        try:
            self._container = av.open(str(path))
            self._frames = self._container.decode(video=0)
        except Exception as exc:
            raise DatasetFormatError(
                path, f"unreadable video (corrupt or truncated?): {exc}"
            ) from exc
        self._path, self._next_index = path, 0

    def read(self, chunk: int, file: int, from_ts: float, length: int) -> np.ndarray:
        """``length`` frames (T,H,W,3 uint8) starting at ``from_ts`` s in the given file."""
        path = self.root / self.info["video_path"].format(
            video_key=self.key, chunk_index=chunk, file_index=file
        )
        first = int(round(from_ts * self.fps))
        if path != self._path or first < self._next_index:
            if not path.is_file():
                raise DatasetFormatError(path, "video file listed in meta/episodes is missing")
            self._open(path)
        out = np.empty((length, *IMAGE_SHAPE), dtype=np.uint8)
        got = 0
        try:
            while got < length:
                frame = next(self._frames)  # type: ignore[arg-type]
                index = self._next_index
                self._next_index += 1
                if frame.pts is not None and frame.time_base is not None:
                    # Trust timestamps over counting: robust to a missing leading frame.
                    index = int(round(float(frame.pts * frame.time_base) * self.fps))
                    self._next_index = index + 1
                if index < first:
                    continue
                out[got] = frame.to_ndarray(format="rgb24")
                got += 1
        except StopIteration:
            raise DatasetFormatError(
                path,
                f"video ends after {got} of {length} frames of an episode starting at {from_ts:.3f}s",
            ) from None
        except DatasetFormatError:
            raise
        except Exception as exc:
            raise DatasetFormatError(
                path, f"video cannot be decoded (corrupt or truncated?): {exc}"
            ) from exc
        return out

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container = self._frames = self._path = None


def _source_metadata(root: Path) -> dict[str, Any]:
    path = root / SOURCE_METADATA_NAME
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetFormatError(path, f"unreadable: {exc}") from exc


def iter_episodes(path: str | os.PathLike[str]) -> Iterator[dict[str, np.ndarray]]:
    """Episodes of a LeRobot v3 dataset root in the NPZ schema, in episode order.

    State, action, reward, success, done and instruction are exact; ``rgb`` holds the
    decoded video frames (lossy codec) or the stored images (``--no-videos``).
    ``episode_seed``/``success_once`` come from ``source_rlds_metadata.json`` (-1 / True
    without it).
    """
    root = Path(path)
    info, episodes, frames, tasks = read_tables(root)
    source = _source_metadata(root)
    seeds = source.get("episode_seeds", [])
    success_once = source.get("success_once", [])
    features = info.get("features", {})
    readers = {
        k: _VideoReader(root, info, k)
        for k in CAMERA_KEYS
        if features.get(k, {}).get("dtype") == "video"
    }
    by_episode = frames.groupby("episode_index", sort=True)
    try:
        for _, ep in episodes.iterrows():
            index = int(ep["episode_index"])
            rows = by_episode.get_group(index)
            length = len(rows)
            cams = []
            for key in CAMERA_KEYS:
                if key in readers:
                    cams.append(
                        readers[key].read(
                            int(ep[f"videos/{key}/chunk_index"]),
                            int(ep[f"videos/{key}/file_index"]),
                            float(ep[f"videos/{key}/from_timestamp"]),
                            length,
                        )
                    )
                else:
                    cams.append(_decode_images(rows[key]))
            task_index = int(rows["task_index"].iloc[0])
            yield {
                "rgb": np.concatenate(cams, axis=-1),
                "proprio": np.stack(rows[STATE_KEY].to_numpy()).astype(np.float32),
                "action": np.stack(rows[ACTION_KEY].to_numpy()).astype(np.float32),
                "reward": _column(rows, REWARD_KEY, np.float32),
                "success": _column(rows, SUCCESS_KEY, np.int32),
                "done": _column(rows, DONE_KEY, np.int32),
                "language_instruction": np.array(tasks.get(task_index, "")),
                "success_once": np.array(
                    bool(success_once[index]) if index < len(success_once) else True
                ),
                "episode_length": np.array(length, dtype=np.int32),
                "episode_seed": np.array(
                    int(seeds[index]) if index < len(seeds) else -1, dtype=np.int64
                ),
            }
    finally:
        for r in readers.values():
            r.close()


def _column(rows: Any, key: str, dtype: Any) -> np.ndarray:
    """A (1,)-shaped per-frame column as a flat array (scalars or 1-element lists)."""
    values = rows[key].to_numpy()
    if len(values) and isinstance(values[0], (list, np.ndarray)):
        values = np.concatenate([np.asarray(v).reshape(-1) for v in values])
    return np.asarray(values).astype(dtype)


def _decode_images(column: Any) -> np.ndarray:
    """Image-mode cameras: parquet cells ``{"bytes": png, "path": ...}`` -> (T,H,W,3)."""
    import io

    from PIL import Image

    return np.stack(
        [np.asarray(Image.open(io.BytesIO(cell["bytes"])).convert("RGB")) for cell in column]
    )


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two uint8 arrays (inf when identical)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0**2 / mse)
