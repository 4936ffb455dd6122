"""RLDS -> LeRobotDataset v3 and NPZ -> LeRobotDataset v3 export, and LeRobot reading
(datasets spec §7).

Writing goes through lerobot's own API (``LeRobotDataset.create`` / ``save_episode`` with
each whole episode / ``finalize``, and ``aggregate_datasets`` joining parallel writers;
lerobot 0.4.x), so the result is what lerobot produces: ``meta/info.json``
(``codebase_version`` v3.0), ``meta/stats.json``, ``meta/tasks.parquet``,
``meta/episodes/...``, ``data/chunk-XXX/file-XXX.parquet`` and one MP4 stream per camera
under ``videos/``. It loads offline with ``LeRobotDataset(repo_id, root=<dataset root>)``.

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

Videos: codec pinned to H.264 (libx264, constant quantiser 23, preset ultrafast, yuv420p,
GOP 2; see `H264_OPTIONS` for why not lerobot's default AV1; ``vcodec="libsvtav1"`` gives
AV1), encoded by `_EpisodeVideoEncoder` in place of lerobot's streaming encoder (one
encoder per camera for the whole write, one file per episode). Video is lossy: frames
come back within a PSNR tolerance (29.5-32 dB on rendered scenes; the tests assert >= 28),
everything else is exact. ``fps`` defaults to 10 (spec §7.1). The source
``metadata.json`` (NPZ or RLDS, same content) is copied to
``<dataset root>/source_rlds_metadata.json``; the loader takes episode seeds and
``success_once`` from it.

Fixes to lerobot 0.4.4's writer apply while we write (`_lerobot_writer_fixes`, restored
after): image statistics computed from each frame's value counts, which is right where
lerobot's uint8 arithmetic wrapped (stats.json had a wrong image std; upstream fixed it
later, huggingface/lerobot#3697) and ~15x cheaper than its per-pixel histogram update; the
other per-episode statistics with their per-channel loops vectorised (same numbers);
``embed_images``, a no-op for video features, skipped; random fingerprints for lerobot's
per-episode ``datasets`` tables; the pinned H.264 options; FFmpeg's info logging off;
``meta/info.json`` and ``meta/stats.json`` written once at the end instead of after every
episode. Episode videos are written one file each and joined once at the end
(`join_episode_videos`) instead of lerobot's per-episode re-mux of the growing file, and
large conversions run in several writer processes joined by lerobot's aggregation
(`writer_count`). Measured figures: the package README.

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
from fractions import Fraction
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
DEFAULT_VCODEC = "h264"
H264_OPTIONS = {"qp": "23", "preset": "ultrafast"}
"""libx264 settings pinned for ``vcodec="h264"`` (lerobot's own: crf 30, x264's default
preset "medium"). On rendered 128x128 scenes, per camera-frame on one core of this
machine: crf 23 / ultrafast 0.6 ms, 31.3 dB, 3.5 kB; lerobot's h264 settings 1.8 ms,
28.9 dB, 1.1 kB; lerobot's AV1 (SVT-AV1 preset 12, crf 30) 6.1 ms, 30.4 dB, 2.3 kB. A
constant quantiser (qp 23: the same PSNR as crf 23 within 0.1 dB, 7% smaller) rather than
crf: x264's crf carries rate-control state from frame to frame, so with one encoder per
camera for a whole write (`_EpisodeVideoEncoder`) an episode's video would depend on the
episodes encoded before it; at a constant quantiser it depends on its own frames only, and
a conversion gives the same frames for any number of writers. GOP 2 and yuv420p stay
lerobot's."""
H264_CODECS = ("h264", "libx264")
"""Codec names that select libx264 (and `H264_OPTIONS`)."""
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
VIDEO_FILE_SIZE_IN_MB = 200.0
"""Video files hold episodes up to this size (lerobot's default, the spec's value).

lerobot appends each episode to the current file by re-muxing the whole file, which made a
task's conversion quadratic in its episode count and cost ~30% of the time on short
episodes. The writer therefore gives every episode its own file while writing and joins
consecutive episodes into files of this size at the end, one re-mux pass per file
(`join_episode_videos`); the result is laid out as lerobot's own appends lay it out."""

_ONE_EPISODE_PER_FILE = 1e-9
"""A video file size no two episodes fit in: lerobot then moves each episode's video into
a file of its own instead of re-muxing it onto the current one."""


_PIXEL_VALUES = np.arange(256, dtype=np.float64)


def _value_bins(stats: Any, channel: int) -> tuple[np.ndarray, np.ndarray]:
    """(bin of each pixel value 0..255, whether it falls in the histogram at all) under
    ``channel``'s current bin edges: ``np.histogram``'s rule (bins closed on the left, the
    last one on both sides). Cached until the edges are replaced."""
    edges = stats._bin_edges[channel]
    cache = stats.__dict__.setdefault("_mikasa_value_bins", {})
    hit = cache.get(channel)
    if hit is not None and hit[0] is edges:
        return hit[1], hit[2]
    bins = np.searchsorted(edges, _PIXEL_VALUES, side="right") - 1
    bins[_PIXEL_VALUES == edges[-1]] = len(edges) - 2
    inside = (_PIXEL_VALUES >= edges[0]) & (_PIXEL_VALUES <= edges[-1])
    cache[channel] = (edges, bins, inside)
    return bins, inside


def _adjust_histograms(stats: Any) -> None:
    """``RunningQuantileStats._adjust_histograms`` without its Python loop over 5,000 bins
    per channel: every old bin's count moves to the new bin holding its centre, added in
    the same order (the counts are whole numbers, so the sums are exact either way)."""
    bins = stats._num_quantile_bins
    for i, (old_edges, old_hist) in enumerate(
        zip(stats._bin_edges, stats._histograms, strict=True)
    ):
        padding = (stats._max[i] - stats._min[i]) * 1e-10
        new_edges = np.linspace(stats._min[i] - padding, stats._max[i] + padding, bins + 1)
        filled = np.flatnonzero(old_hist > 0)
        centres = (old_edges[:-1][filled] + old_edges[1:][filled]) / 2
        target = np.clip(np.searchsorted(new_edges, centres) - 1, 0, bins - 1)
        stats._histograms[i] = np.bincount(target, weights=old_hist[filled], minlength=bins).astype(
            np.float64
        )
        stats._bin_edges[i] = new_edges


def _value_counts(rows: np.ndarray) -> np.ndarray:
    """[C, 256] counts of each value 0..255 per channel of uint8 ``rows`` [N, C]. RGB rows
    are counted by PIL's histogram (one pass in C; ~30% faster than three bincounts)."""
    n, channels = rows.shape
    if channels == 3 and n > 0:
        from PIL import Image

        image = Image.frombuffer("RGB", (n, 1), np.ascontiguousarray(rows), "raw", "RGB", 0, 1)
        return np.asarray(image.histogram(), dtype=np.int64).reshape(3, 256)
    return np.stack([np.bincount(rows[:, c], minlength=256) for c in range(channels)])


def _update_from_value_counts(stats: Any, rows: np.ndarray) -> None:
    """``RunningQuantileStats.update`` for uint8 ``rows`` [N, C], computed from each
    channel's 256 value counts: the state lerobot's update reaches on the rows promoted to
    floats (mean and mean of squares exact, in float64; the same histogram bins and
    counts), in a fraction of the time."""
    n, channels = rows.shape
    counts = _value_counts(rows)
    present = counts > 0
    batch_min = _PIXEL_VALUES[present.argmax(axis=1)]
    batch_max = _PIXEL_VALUES[255 - present[:, ::-1].argmax(axis=1)]
    batch_mean = counts @ _PIXEL_VALUES / n
    batch_mean_of_squares = counts @ (_PIXEL_VALUES * _PIXEL_VALUES) / n
    bins = stats._num_quantile_bins
    if stats._count == 0:
        stats._mean, stats._mean_of_squares = batch_mean.copy(), batch_mean_of_squares.copy()
        stats._min, stats._max = batch_min, batch_max
        stats._histograms = [np.zeros(bins) for _ in range(channels)]
        stats._bin_edges = [
            np.linspace(lo - 1e-10, hi + 1e-10, bins + 1)
            for lo, hi in zip(batch_min, batch_max, strict=True)
        ]
    else:
        if channels != stats._mean.size:
            raise ValueError(
                "The length of new vectors does not match the initialized vector length."
            )
        changed = bool(np.any(batch_max > stats._max) or np.any(batch_min < stats._min))
        stats._max, stats._min = (
            np.maximum(stats._max, batch_max),
            np.minimum(stats._min, batch_min),
        )
        if changed:
            _adjust_histograms(stats)
    stats._count += n
    stats._mean += (batch_mean - stats._mean) * (n / stats._count)
    stats._mean_of_squares += (batch_mean_of_squares - stats._mean_of_squares) * (n / stats._count)
    for c in range(channels):
        value_bins, inside = _value_bins(stats, c)
        stats._histograms[c] += np.bincount(
            value_bins[inside], weights=counts[c][inside], minlength=bins
        )


def _patch_running_stats(stats_class: type) -> Callable[[], None]:
    """Route uint8 batches (camera frames) of lerobot's ``RunningQuantileStats.update``
    through `_update_from_value_counts`; return the undo.

    Two reasons. lerobot 0.4.x squares uint8 pixels in uint8, the values wrap, and
    stats.json got a wrong image std (0.04-0.16 for 0.11-0.21 here; upstream fixed it by
    promoting to float32, huggingface/lerobot#3697). And its streaming encoder updates the
    statistics for every frame of every camera, in Python, with the GIL held: ~4 ms per
    camera-frame, ~45% of a conversion's CPU time.

    Its other per-episode statistics (state, action, reward, indices: one update and one
    read per feature and episode) keep lerobot's arithmetic, with two loops vectorised:
    `_histogram_counts` and `_quantiles` (~30% of a conversion of short episodes).
    """
    names = ("update", "_update_histograms", "_compute_quantiles")
    originals = {name: getattr(stats_class, name, None) for name in names}
    probe = stats_class()
    needed = ("_adjust_histograms", "_num_quantile_bins", "_count", "_quantile_list", "_bin_edges")
    if None in originals.values() or not all(hasattr(probe, name) for name in needed):
        return lambda: None  # another lerobot: left as it is
    original_update = originals["update"]

    @functools.wraps(original_update)
    def update(self: Any, batch: np.ndarray) -> None:
        batch = np.asarray(batch)
        if batch.size == 0:
            return original_update(self, batch)
        if batch.dtype == np.uint8:
            return _update_from_value_counts(self, batch.reshape(-1, batch.shape[-1]))
        if self._count == 0:
            _first_update(self, batch.reshape(-1, batch.shape[-1]))
        else:
            original_update(self, batch)

    def update_histograms(self: Any, batch: np.ndarray) -> None:
        for i in range(batch.shape[1]):
            self._histograms[i] += _histogram_counts(batch[:, i], self._bin_edges[i])

    stats_class.update = update
    stats_class._update_histograms = update_histograms
    stats_class._compute_quantiles = _quantiles

    def undo() -> None:
        for name, value in originals.items():
            setattr(stats_class, name, value)

    return undo


def _first_update(stats: Any, batch: np.ndarray) -> None:
    """lerobot's first ``RunningQuantileStats.update`` (the only one for per-episode
    statistics), with every channel's bin edges and histogram made in one array each
    instead of one call per channel (``np.linspace`` along an axis gives the same values)."""
    n, channels = batch.shape
    bins = stats._num_quantile_bins
    stats._min, stats._max = np.min(batch, axis=0), np.max(batch, axis=0)
    stats._histograms = list(np.zeros((channels, bins)))
    stats._bin_edges = list(np.linspace(stats._min - 1e-10, stats._max + 1e-10, bins + 1, axis=1))
    stats._count = n
    stats._mean = np.mean(batch, axis=0)
    stats._mean_of_squares = np.mean(batch**2, axis=0)
    stats._update_histograms(batch)


def _histogram_counts(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``np.histogram(values, bins=edges)[0]`` for increasing ``edges``: bins closed on the
    left, the last on both sides, values outside dropped; the same counts, without
    sorting the values."""
    nbins = len(edges) - 1
    index = np.searchsorted(edges, values, side="right") - 1
    index[values == edges[-1]] = nbins - 1
    keep = (index >= 0) & (index < nbins)
    return np.bincount(index[keep], minlength=nbins)


def _quantiles(self: Any) -> list[np.ndarray]:
    """``RunningQuantileStats._compute_quantiles`` computing each channel's cumulative
    histogram once instead of once per quantile; the same arithmetic per value."""
    cumulative = [np.cumsum(hist) for hist in self._histograms]
    results = []
    for q in self._quantile_list:
        target = q * self._count
        values = []
        for cumsum, edges in zip(cumulative, self._bin_edges, strict=True):
            idx = int(np.searchsorted(cumsum, target))
            if idx == 0:
                values.append(edges[0])
            elif idx >= len(cumsum):
                values.append(edges[-1])
            else:
                before = cumsum[idx - 1]
                inside = cumsum[idx] - before
                if inside == 0:
                    values.append(edges[idx])
                else:
                    values.append(
                        edges[idx] + (target - before) / inside * (edges[idx + 1] - edges[idx])
                    )
        results.append(np.array(values))
    return results


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
    return [
        undo_stats,
        lambda: setattr(lerobot_module, "embed_images", original_embed),
        _pin_h264_options(),
        _quiet_libav(),
        _random_dataset_fingerprints(),
        _defer_metadata_writes(lerobot_module),
    ]


_PENDING_WRITES: dict[tuple[str, str], tuple[Callable[..., None], Any]] = {}


def _defer_metadata_writes(lerobot_module: Any) -> Callable[[], None]:
    """lerobot rewrites ``meta/info.json`` and ``meta/stats.json`` after every episode (the
    whole aggregated statistics as JSON, ~2 ms an episode); while we write, each write only
    records the latest content per file, and `_flush_metadata_writes` (at the end of a
    write, and in the undo) writes it once. Return the undo."""
    originals = {name: getattr(lerobot_module, name) for name in ("write_info", "write_stats")}

    def deferred(name: str) -> Callable[[Any, Path], None]:
        def record(content: Any, root: Path) -> None:
            _PENDING_WRITES[(str(root), name)] = (originals[name], content)

        return record

    for name in originals:
        setattr(lerobot_module, name, deferred(name))

    def undo() -> None:
        for name, original in originals.items():
            setattr(lerobot_module, name, original)
        _flush_metadata_writes()

    return undo


def _flush_metadata_writes(root: str | os.PathLike[str] | None = None) -> None:
    """Write the deferred metadata of ``root`` (default: of every dataset)."""
    for key in [k for k in _PENDING_WRITES if root is None or k[0] == str(root)]:
        write, content = _PENDING_WRITES.pop(key)
        write(content, Path(key[0]))


def _random_dataset_fingerprints() -> Callable[[], None]:
    """New ``datasets.Dataset`` objects get a random fingerprint instead of a hash of their
    whole state (dill-pickling every episode's table: ~15% of a conversion of short
    episodes); return the undo. A fingerprint only names cache files, and lerobot's
    per-episode tables are written to parquet and never cached."""
    from datasets import arrow_dataset, fingerprint

    original = arrow_dataset.generate_fingerprint
    arrow_dataset.generate_fingerprint = lambda dataset: fingerprint.generate_random_fingerprint()
    return lambda: setattr(arrow_dataset, "generate_fingerprint", original)


def _pin_h264(options: dict[str, str]) -> None:
    """Replace lerobot's H.264 rate control (``crf``, which x264 prefers over ``qp`` when
    both are given) by `H264_OPTIONS`."""
    options.pop("crf", None)
    options.update(H264_OPTIONS)


def _pin_h264_options() -> Callable[[], None]:
    """Make lerobot's encoders use `H264_OPTIONS` for h264; return the undo."""
    from lerobot.datasets import video_utils

    original = video_utils._get_codec_options

    @functools.wraps(original)
    def codec_options(vcodec: str, *args: Any, **kwargs: Any) -> dict:
        options = original(vcodec, *args, **kwargs)
        if vcodec in H264_CODECS:
            _pin_h264(options)
        return options

    video_utils._get_codec_options = codec_options
    return lambda: setattr(video_utils, "_get_codec_options", original)


def _quiet_libav() -> Callable[[], None]:
    """FFmpeg's own log level to errors (lerobot's encoder threads hand logging back to
    FFmpeg's default printer, and x264 prints a statistics block for every encoded
    episode at info level); return the undo, which sets FFmpeg's default (info) again:
    FFmpeg's level cannot be read back."""
    import av.logging

    av.logging.set_libav_level(av.logging.ERROR)
    return lambda: av.logging.set_libav_level(av.logging.INFO)


class _EpisodeVideoEncoder:
    """Encodes an episode's camera videos in the calling thread: stands in for lerobot's
    ``StreamingVideoEncoder`` (same methods and codec settings, one MP4 file per camera and
    episode, the same image statistics), with whole episodes fed at once (`feed_frames`).

    lerobot's encoder starts a thread, a temporary directory and an encoder per camera and
    episode, and hands every frame through a queue to a thread that converts it via PIL and
    updates the statistics holding the GIL. For H.264 this keeps one encoder per camera
    for the whole write instead (x264's start-up cost ~40% of encoding a 15-frame
    episode): zero-latency settings, so every frame's packet comes out at once; each
    episode starts on a forced IDR frame and its packets go to the episode's own file,
    timestamps from 0, so every file decodes on its own (`PERSISTENT_H264_OPTIONS`).
    Other codecs (AV1 has a delay) get a new encoder per episode, as in lerobot.
    """

    PERSISTENT_H264_OPTIONS = {"tune": "zerolatency", "forced-idr": "1", "threads": "1"}
    """Added to the H.264 options of the persistent encoders: no lookahead or frame
    threads (no frame held back); a requested keyframe is an IDR frame; one thread, so the
    video does not depend on the machine's core count (x264's threads change the bitstream;
    parallelism comes from the writer processes, one per core)."""

    def __init__(
        self,
        fps: int,
        vcodec: str,
        pix_fmt: str,
        g: int | None,
        crf: int | None,
        preset: int | None,
        encoder_threads: int | None,
    ) -> None:
        from lerobot.datasets import video_utils

        self.fps, self.vcodec, self.pix_fmt = fps, vcodec, pix_fmt
        self.time_base = Fraction(1, fps)  # of frames; the muxer changes the stream's
        self.options = video_utils._get_codec_options(vcodec, g, crf, preset)
        if encoder_threads is not None:
            if vcodec == "libsvtav1":
                params = self.options.get("svtav1-params")
                lp = f"lp={encoder_threads}"
                self.options["svtav1-params"] = f"{params}:{lp}" if params else lp
            else:
                self.options["threads"] = str(encoder_threads)
        self.persistent = vcodec in H264_CODECS
        if self.persistent:
            _pin_h264(self.options)
            self.options.update(self.PERSISTENT_H264_OPTIONS)
        self._encoders: dict[str, dict[str, Any]] = {}  # camera -> persistent encoder
        self._dir: Path | None = None
        self._cameras: dict[str, dict[str, Any]] = {}  # camera -> this episode's file

    @classmethod
    def replacing(cls, lerobot_encoder: Any) -> _EpisodeVideoEncoder | None:
        """One with the settings of lerobot's ``lerobot_encoder``; None when there is none
        or it is not the 0.4.x ``StreamingVideoEncoder`` this stands in for."""
        names = ("fps", "vcodec", "pix_fmt", "g", "crf", "preset", "encoder_threads")
        if lerobot_encoder is None or not all(hasattr(lerobot_encoder, n) for n in names):
            return None
        return cls(*(getattr(lerobot_encoder, n) for n in names))

    def start_episode(self, video_keys: list[str], temp_dir: Path) -> None:
        """Begin an episode with these cameras; its files go to a new directory in
        ``temp_dir`` (lerobot moves them into the dataset)."""
        import tempfile

        self.cancel_episode()
        self._dir = Path(tempfile.mkdtemp(dir=temp_dir))
        self._cameras = {key: {} for key in video_keys}

    def feed_frame(self, video_key: str, image: np.ndarray) -> None:
        """Encode one HWC uint8 frame of ``video_key`` (lerobot's interface)."""
        self.feed_frames(video_key, np.asarray(image)[None])

    def feed_frames(self, video_key: str, frames: np.ndarray) -> None:
        """Encode ``frames`` [T, H, W, 3] uint8 of ``video_key`` and add each frame to the
        camera's statistics, as lerobot's encoder thread does frame by frame."""
        import av

        if video_key not in self._cameras:
            raise RuntimeError(f"{video_key!r} is not a camera of the current episode")
        frames = np.ascontiguousarray(frames)
        if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3:
            raise ValueError(
                f"{video_key}: frames must be uint8 [T, H, W, 3], got {frames.dtype} {frames.shape}"
            )
        camera = self._cameras[video_key] or self._open(video_key, *frames.shape[1:3])
        encoder, stream, container = camera["encoder"], camera["stream"], camera["container"]
        for frame in frames:
            video_frame = av.VideoFrame.from_numpy_buffer(frame, format="rgb24")
            video_frame.time_base = self.time_base
            if encoder is None:  # an encoder of this episode's file
                video_frame.pts = camera["count"]
                container.mux(stream.encode(video_frame))
            else:
                video_frame.pts = camera["base"] + camera["count"]
                if camera["count"] == 0:
                    video_frame.pict_type = av.video.frame.PictureType.I
                packets = encoder["codec"].encode(video_frame)
                camera["held"] |= not packets
                self._mux(camera, packets)
            _update_from_value_counts(camera["stats"], frame.reshape(-1, 3))
            camera["count"] += 1

    def _open(self, video_key: str, height: int, width: int) -> dict[str, Any]:
        """The episode's file for ``video_key``, its stream, and the encoder feeding it."""
        import av
        from lerobot.datasets.compute_stats import RunningQuantileStats

        name = video_key.replace("/", "_")
        path = self._dir / name / f"{name}_streaming.mp4"  # lerobot removes the folder
        path.parent.mkdir()
        container = av.open(str(path), "w")
        encoder = None
        if self.persistent:
            encoder = self._encoders.get(video_key)
            if encoder is None or encoder["size"] != (height, width):
                encoder = self._encoders[video_key] = self._persistent_encoder(height, width)
            stream = container.add_stream_from_template(encoder["template"], opaque=True)
            stream.codec_context.extradata = encoder["codec"].extradata
            stream.time_base = self.time_base
        else:
            stream = self._add_stream(container, height, width)
        camera = self._cameras[video_key]
        camera.update(
            path=path, container=container, stream=stream, encoder=encoder, count=0,
            held=False, stats=RunningQuantileStats(),
            base=encoder["next_pts"] if encoder else 0,
        )
        return camera

    def _add_stream(self, container: Any, height: int, width: int) -> Any:
        stream = container.add_stream(self.vcodec, self.fps, options=dict(self.options))
        stream.pix_fmt, stream.height, stream.width = self.pix_fmt, height, width
        stream.time_base = self.time_base
        return stream

    def _persistent_encoder(self, height: int, width: int) -> dict[str, Any]:
        """An open H.264 encoder with global headers, and a stream template to give each
        episode's file: an ordinary file of one frame made with the same settings (so the
        same parameter sets), opened for reading, whose stream is copied without opening
        an encoder. Each file's header gets the encoder's own parameter sets."""
        import io

        import av

        buffer = io.BytesIO()
        with av.open(buffer, "w", format="mp4") as container:
            stream = self._add_stream(container, height, width)
            frame = av.VideoFrame.from_ndarray(np.zeros((height, width, 3), np.uint8), "rgb24")
            frame.pts, frame.time_base = 0, self.time_base
            container.mux(stream.encode(frame))
            container.mux(stream.encode())
        buffer.seek(0)
        template = av.open(buffer)
        codec = av.CodecContext.create(self.vcodec, "w")
        codec.width, codec.height, codec.pix_fmt = width, height, self.pix_fmt
        codec.time_base, codec.framerate = self.time_base, self.fps
        codec.options = dict(self.options)
        codec.flags |= av.codec.context.Flags.global_header
        codec.open()
        return {
            "codec": codec, "size": (height, width), "next_pts": 0,
            "template": template.streams.video[0], "template_container": template,
        }

    @staticmethod
    def _mux(camera: dict[str, Any], packets: list[Any]) -> None:
        """Mux a persistent encoder's ``packets`` into the episode's file, timestamps
        counted from the episode's first frame; each lasts one frame (the last one's
        duration is the file's end)."""
        for packet in packets:
            packet.pts -= camera["base"]
            packet.dts -= camera["base"]
            packet.duration = packet.duration or 1
            packet.stream = camera["stream"]
            camera["container"].mux(packet)

    def finish_episode(self) -> dict[str, tuple[Path, dict | None]]:
        """Flush and close the episode's files: ``{camera: (mp4 path, statistics)}``,
        statistics None below two frames (as lerobot's encoder)."""
        results = {}
        for key, camera in self._cameras.items():
            if not camera:
                raise RuntimeError(f"no frames were fed for {key!r}")
            encoder = camera["encoder"]
            if encoder is None:
                camera["container"].mux(camera["stream"].encode())
            elif camera["held"]:
                # A frame was held back after all: flush, which ends this encoder.
                self._mux(camera, encoder["codec"].encode(None))
                del self._encoders[key]
            else:
                encoder["next_pts"] = camera["base"] + camera["count"]
            camera["container"].close()
            stats = camera["stats"].get_statistics() if camera["count"] >= 2 else None
            results[key] = (camera["path"], stats)
        self._cameras, self._dir = {}, None
        return results

    def cancel_episode(self) -> None:
        """Drop the current episode's files, if any."""
        for key, camera in self._cameras.items():
            if camera:
                with contextlib.suppress(Exception):
                    camera["container"].close()
                # Its encoder's state is mid-episode: start the next episode afresh.
                self._encoders.pop(key, None)
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
        self._cameras, self._dir = {}, None

    def close(self) -> None:
        """lerobot calls this in ``finalize``."""
        self.cancel_episode()
        for encoder in self._encoders.values():
            encoder["template_container"].close()
        self._encoders.clear()


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
    join_videos: bool = True,
) -> tuple[int, int]:
    """Write NPZ-schema ``episodes`` as a new LeRobot v3 dataset at ``root``.

    ``root`` must not exist (lerobot creates it). One ``save_episode`` per episode, then
    ``finalize``. ``task`` per frame is the episode instruction, stripped; an empty one
    falls back to the last non-empty instruction seen (initially ``default_task``), as in
    the upstream converter. Videos: one file per episode while writing, joined into files
    of `VIDEO_FILE_SIZE_IN_MB` at the end (``join_videos=False``: left one per episode,
    for a caller that joins later). Returns ``(episodes, frames)`` written.
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
            # Used by encoders other than our persistent H.264 ones (one thread): two
            # cameras' worth of encoder threads, half the cores each.
            kwargs["encoder_threads"] = max(1, (os.cpu_count() or 2) // 2)
    dataset = cls.create(**{k: v for k, v in kwargs.items() if k in supported})
    if "video_files_size_in_mb" in dataset.meta.info:
        dataset.meta.info["video_files_size_in_mb"] = _ONE_EPISODE_PER_FILE
    encoder = _EpisodeVideoEncoder.replacing(getattr(dataset, "_streaming_encoder", None))
    if encoder is not None:
        dataset._streaming_encoder = encoder
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
            length = int(ep["episode_length"])
            columns = {
                STATE_KEY: ep["proprio"][:length],
                ACTION_KEY: ep["action"][:length],
                REWARD_KEY: ep["reward"][:length].reshape(-1, 1).astype(np.float32, copy=False),
                SUCCESS_KEY: ep["success"][:length].reshape(-1, 1).astype(bool),
                DONE_KEY: ep["done"][:length].reshape(-1, 1).astype(bool),
            }
            cameras = {TOP_KEY: ep["rgb"][:length, :, :, 0:3], WRIST_KEY: ep["rgb"][:length, :, :, 3:6]}
            if encoder is not None:
                # The whole episode in one call (lerobot's ``save_episode(episode_data)``):
                # the frame buffer is what ``add_frame`` builds, the videos are encoded here.
                buffer = dataset.create_episode_buffer()
                buffer.update(columns)
                buffer.update(
                    size=length,
                    task=[last_task] * length,
                    frame_index=np.arange(length),
                    timestamp=np.arange(length) / fps,
                )
                encoder.start_episode(list(cameras), dataset.root)
                for key, frames in cameras.items():
                    buffer[key] = [None] * length  # video frames live in the encoder
                    encoder.feed_frames(key, frames)
                dataset.save_episode(episode_data=buffer, **save_kwargs)
            else:
                for t in range(length):
                    frame = {key: value[t] for key, value in {**cameras, **columns}.items()}
                    dataset.add_frame({**frame, "task": last_task})
                dataset.save_episode(**save_kwargs)
            n_eps += 1
            n_frames += int(ep["episode_length"])
            if progress is not None:
                progress(n_eps)
        _flush_metadata_writes(dataset.root)
        completed = True
    finally:
        if encoder is not None:
            encoder.close()  # while FFmpeg is quiet: x264 reports when an encoder ends
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
    if join_videos:
        join_episode_videos(root, VIDEO_FILE_SIZE_IN_MB)
    if source_metadata is not None and Path(source_metadata).is_file():
        shutil.copyfile(source_metadata, Path(root) / SOURCE_METADATA_NAME)
    return n_eps, n_frames


def join_episode_videos(root: str | os.PathLike[str], file_size_in_mb: float) -> None:
    """Join a LeRobot v3 dataset's video files, camera by camera, into files of up to
    ``file_size_in_mb``, keeping episode order; rewrite the video columns of
    ``meta/episodes`` and ``video_files_size_in_mb`` in ``meta/info.json`` to match.

    Consecutive files go into one output while its size stays below the limit (lerobot's
    rule when it appends); each output is written in one pass by lerobot's
    ``concatenate_video_files`` (a re-mux, no re-encoding), and an episode's timestamps
    become offsets in its new file, the sum of the durations before it, as lerobot's
    appends compute them. Used on datasets written one episode per file.
    """
    import pyarrow.parquet as pq
    from lerobot.datasets.utils import write_info
    from lerobot.datasets.video_utils import concatenate_video_files

    root = Path(root)
    info = read_info(root)
    info["video_files_size_in_mb"] = file_size_in_mb
    video_keys = [k for k, f in info["features"].items() if f.get("dtype") == "video"]
    episode_files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    tables = [pq.read_table(f) for f in episode_files]
    frames = [t.to_pandas() for t in tables]
    limit = file_size_in_mb * 1024 * 1024
    chunks_size = int(info["chunks_size"])
    for key in video_keys:
        columns = {
            c: f"videos/{key}/{c}"
            for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")
        }
        rows = sorted(
            (
                (int(df.at[i, "episode_index"]), n, i)
                for n, df in enumerate(frames)
                for i in df.index
            )
        )

        groups: list[list[tuple[int, int]]] = []  # (table, row) per episode, per output file
        group_bytes = 0
        sources: dict[tuple[int, int], Path] = {}
        for _, n, i in rows:
            chunk, file = (int(frames[n].at[i, columns[c]]) for c in ("chunk_index", "file_index"))
            source = root / _video_file(info, key, chunk, file)
            size = source.stat().st_size
            if not groups or group_bytes + size >= limit:
                groups.append([])
                group_bytes = 0
            groups[-1].append((n, i))
            group_bytes += size
            sources[(n, i)] = source
        if all(len(g) == 1 for g in groups):
            continue  # nothing to join (one episode per file was asked for)
        staging = root / f".joined-{key}"
        for g, members in enumerate(groups):
            chunk, file = divmod(g, chunks_size)
            target = staging / _video_file(info, key, chunk, file)
            target.parent.mkdir(parents=True, exist_ok=True)
            if len(members) == 1:
                shutil.copyfile(sources[members[0]], target)
            else:
                loud_libav = _quiet_libav()  # the re-mux reports each pass at info level
                try:
                    concatenate_video_files([sources[m] for m in members], target)
                finally:
                    loud_libav()
            offset = 0.0
            for n, i in members:
                df = frames[n]
                duration = float(df.at[i, columns["to_timestamp"]]) - float(
                    df.at[i, columns["from_timestamp"]]
                )
                df.at[i, columns["chunk_index"]], df.at[i, columns["file_index"]] = chunk, file
                df.at[i, columns["from_timestamp"]] = offset
                offset = offset + duration
                df.at[i, columns["to_timestamp"]] = offset
        videos = root / "videos" / key
        shutil.rmtree(videos)
        os.replace(staging / "videos" / key, videos)
        shutil.rmtree(staging)
    import pyarrow as pa

    for f, table, df in zip(episode_files, tables, frames, strict=True):
        pq.write_table(pa.Table.from_pandas(df, schema=table.schema, preserve_index=False), f)
    write_info(info, root)


def _video_file(info: dict[str, Any], key: str, chunk: int, file: int) -> str:
    """A video file's path in a dataset root, from ``info["video_path"]``."""
    return info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file)


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


EPISODES_PER_WORKER = 8
"""Default writer processes: one per core, each with at least this many episodes (a
parallel write ends with lerobot's aggregation and one video join, ~0.5-1 s here)."""


def writer_count(workers: int | None, num_episodes: int) -> int:
    """Writer processes for ``num_episodes``: ``workers``, or by default one per core with
    at least `EPISODES_PER_WORKER` episodes each; never more than the episodes."""
    if workers is None:
        workers = min(os.cpu_count() or 1, num_episodes // EPISODES_PER_WORKER)
    elif workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return max(1, min(workers, num_episodes))


def _part_writer(
    conn: Any,
    episodes: Callable[[int, int], Iterator[dict[str, np.ndarray]]],
    start: int,
    stop: int,
    root: Path,
    repo_id: str,
    write_kwargs: dict[str, Any],
) -> None:
    """(Forked writer process) read episodes ``start`` to ``stop`` and write them as one
    LeRobot dataset at ``root``; report ``("episode", n)`` on ``conn`` after each and
    finally ``("done", (episodes, frames))`` or ``("error", exception)``."""
    try:
        written = write_lerobot(
            _prefetch(episodes(start, stop)),
            root,
            repo_id,
            progress=lambda n: conn.send(("episode", n)),
            **write_kwargs,
        )
        conn.send(("done", written))
    except BaseException as exc:  # reported to the parent, which raises it
        try:
            conn.send(("error", exc))
        except Exception:  # an exception that does not pickle
            conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))


def _write_in_parts(
    episodes: Callable[[int, int], Iterator[dict[str, np.ndarray]]],
    num_episodes: int,
    workers: int,
    root: Path,
    repo_id: str,
    write_kwargs: dict[str, Any],
    progress: Callable[[int], None] | None,
) -> tuple[int, int]:
    """Write episodes ``0..num_episodes`` with ``workers`` writer processes, each reading
    and writing a contiguous share as a LeRobot dataset of its own, then join the shares
    into one at ``root`` with lerobot's ``aggregate_datasets`` (episode order kept; each
    share's video files kept as they are, statistics combined by lerobot).

    Writers are forked: they start at once with lerobot already imported. Reading a share
    runs no TensorFlow op (NPZ files; RLDS shards through `rlds.read_tfrecords` and TFDS's
    numpy parser), so it is safe in a process forked from one that ran TensorFlow.
    """
    import multiprocessing
    from multiprocessing.connection import wait

    bounds = [num_episodes * i // workers for i in range(workers + 1)]
    parts = [root.with_name(f"{root.name}-part{i}") for i in range(workers)]
    context = multiprocessing.get_context("fork")
    writers, conns = [], []
    try:
        for i in range(workers):
            ours, theirs = context.Pipe(duplex=False)
            writer = context.Process(
                target=_part_writer,
                args=(
                    theirs,
                    episodes,
                    bounds[i],
                    bounds[i + 1],
                    parts[i],
                    f"{repo_id}-part{i}",
                    write_kwargs,
                ),
                name=f"mikasa-lerobot-writer-{i}",
                daemon=True,
            )
            writer.start()
            theirs.close()
            writers.append(writer)
            conns.append(ours)
        done_per_part = [0] * workers
        results: dict[int, tuple[int, int]] = {}
        pending = dict(enumerate(conns))
        while pending:
            for conn in wait(list(pending.values())):
                i = next(k for k, c in pending.items() if c is conn)
                try:
                    kind, value = conn.recv()
                except (EOFError, OSError):
                    raise RuntimeError(
                        f"LeRobot writer process {i} exited (code {writers[i].exitcode}) "
                        "before finishing its episodes"
                    ) from None
                if kind == "episode":
                    done_per_part[i] = value
                    if progress is not None:
                        progress(sum(done_per_part))
                elif kind == "error":
                    raise value
                else:
                    results[i] = value
                    del pending[i]
        _aggregate(parts, [f"{repo_id}-part{i}" for i in range(workers)], root, repo_id)
        return sum(r[0] for r in results.values()), sum(r[1] for r in results.values())
    finally:
        for writer in writers:
            if writer.is_alive():
                writer.terminate()
            writer.join()
        for conn in conns:
            conn.close()
        for part in parts:
            shutil.rmtree(part, ignore_errors=True)


def _aggregate(parts: list[Path], part_ids: list[str], root: Path, repo_id: str) -> None:
    """lerobot's ``aggregate_datasets`` of ``parts`` into a new dataset at ``root``,
    without its progress bars. Each part's video files (joined by its writer) are copied
    as they are: aggregation is told a file size no two files fit in (joining them would
    re-mux them once more); ``video_files_size_in_mb`` in meta/info.json is set back to
    `VIDEO_FILE_SIZE_IN_MB` afterwards. Frame tables are joined as lerobot does (their
    indices change)."""
    from lerobot.datasets import aggregate
    from lerobot.datasets import lerobot_dataset as lerobot_module

    original_tqdm = aggregate.tqdm.tqdm
    aggregate.tqdm.tqdm = functools.partial(original_tqdm, disable=True)
    original_load_episodes = lerobot_module.load_episodes
    lerobot_module.load_episodes = _load_episodes_without_stats
    loud_libav = _quiet_libav()
    try:
        aggregate.aggregate_datasets(
            part_ids,
            repo_id,
            roots=parts,
            aggr_root=root,
            video_files_size_in_mb=_ONE_EPISODE_PER_FILE,
        )
    finally:
        aggregate.tqdm.tqdm = original_tqdm
        lerobot_module.load_episodes = original_load_episodes
        loud_libav()
    from lerobot.datasets.utils import write_info

    info = read_info(root)
    info["video_files_size_in_mb"] = VIDEO_FILE_SIZE_IN_MB
    write_info(info, root)


def _load_episodes_without_stats(root: Path) -> Any:
    """lerobot's ``load_episodes`` (the episode table without its ``stats/`` columns, as a
    ``datasets.Dataset``), read in memory with pyarrow: lerobot's goes through
    ``Dataset.from_parquet``, which prepares an Arrow cache and checks every nested stats
    feature first, ~0.6 s per dataset here (three quarters of an aggregation)."""
    import datasets
    import pyarrow as pa
    import pyarrow.parquet as pq

    paths = sorted((Path(root) / "meta" / "episodes").glob("*/*.parquet"))
    if not paths:
        raise FileNotFoundError(f"no episode metadata parquet files in {root}/meta/episodes")
    columns = [n for n in pq.read_schema(paths[0]).names if not n.startswith("stats/")]
    return datasets.Dataset(pa.concat_tables([pq.read_table(p, columns=columns) for p in paths]))


def _convert(
    episodes: Callable[[int, int], Iterator[dict[str, np.ndarray]]],
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
    workers: int | None,
    progress: Callable[[int, int], None] | None,
) -> ConversionResult:
    lerobot_dataset_class()  # import first: library start-up is not conversion time
    t0 = time.perf_counter()
    if "{task}" not in repo_id_template:
        raise ValueError(f"repo id template {repo_id_template!r} must contain '{{task}}'")
    n_writers = writer_count(workers, num_episodes)
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
    write_kwargs: dict[str, Any] = {
        "fps": fps,
        "robot_type": robot_type,
        "use_videos": use_videos,
        "vcodec": vcodec,
        "default_task": default_task,
    }
    report = None if progress is None else (lambda done: progress(done, num_episodes))
    try:
        if n_writers == 1:
            n_eps, n_frames = write_lerobot(
                _prefetch(episodes(0, num_episodes)),
                staging,
                repo_id,
                progress=report,
                **write_kwargs,
            )
        else:
            # Each share's instruction fallback starts from the default: a share cannot see
            # the instructions before it (the NPZ schema requires one in every episode).
            n_eps, n_frames = _write_in_parts(
                episodes, num_episodes, n_writers, staging, repo_id, write_kwargs, report
            )
        if source_metadata is not None and source_metadata.is_file():
            shutil.copyfile(source_metadata, staging / SOURCE_METADATA_NAME)
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
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ConversionResult:
    """Convert an NPZ task directory straight to ``<lerobot_root>/<repo id>/``.

    Each episode is read with the schema check and §3.1 invariants (errors name the
    file). Built in a hidden staging directory, renamed into place when finalized.
    ``overwrite``/``resume`` as in :func:`mikasa_datasets.rlds.convert_npz_to_rlds`
    (resume keeps an output with the same episode count and fps). ``workers``: writer
    processes (default: `writer_count`); the episodes, frames and videos written do not
    depend on it, only how they are split into files and the combined quantiles.
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

    def episodes(start: int, stop: int) -> Iterator[dict[str, np.ndarray]]:
        for f in files[start:stop]:
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
        workers=workers,
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
    workers: int | None = None,
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

    def episodes(start: int, stop: int) -> Iterator[dict[str, np.ndarray]]:
        return rlds.iter_episodes(vdir, start, stop)

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
        workers=workers,
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
