"""The LeRobot writer's parts (see :mod:`mikasa_datasets.lerobot_write`, whose public
functions use them): writing episodes as one LeRobot dataset with lerobot's public API
(`write_part`), the exact camera statistics that replace lerobot's (`fix_image_stats`),
reading ahead in a thread (`prefetch`), and the forked writer processes whose datasets
lerobot's ``aggregate_datasets`` joins (`write_in_parts`).
"""

from __future__ import annotations

import contextlib
import io
import queue
import shutil
import threading
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.lerobot_format import (
    ACTION_KEY,
    CAMERA_KEYS,
    DONE_KEY,
    REWARD_KEY,
    STATE_KEY,
    SUCCESS_KEY,
    TOP_KEY,
    WRIST_KEY,
    lerobot_dataset_class,
    lerobot_features,
)


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence what lerobot's writer prints per episode, restored after: ``datasets``'
    "Map" progress bars, numpy's warning each time lerobot histograms a bool column, and
    FFmpeg's info log (lerobot's encoder threads hand FFmpeg its default printer, and x264
    then prints a statistics block per video). All are those libraries' public switches."""
    import av.logging
    import datasets

    bars_were_off = datasets.are_progress_bars_disabled()
    datasets.disable_progress_bars()
    av.logging.set_libav_level(av.logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Converting input from bool")
            yield
    finally:
        # FFmpeg's level cannot be read back: set its default (info) again.
        av.logging.set_libav_level(av.logging.INFO)
        if not bars_were_off:
            datasets.enable_progress_bars()


# --------------------------------------------------------------------------- image statistics
_PIXEL_VALUES = np.arange(256, dtype=np.float64)


def _value_counts(frames: np.ndarray) -> np.ndarray:
    """[3, 256] counts of each value 0..255 per channel of uint8 ``frames`` [..., 3], by
    PIL's histogram (one pass in C over the interleaved pixels)."""
    from PIL import Image

    rows = np.ascontiguousarray(frames).reshape(-1, 3)
    if not len(rows):
        return np.zeros((3, 256), dtype=np.int64)
    image = Image.frombuffer("RGB", (len(rows), 1), rows, "raw", "RGB", 0, 1)
    return np.asarray(image.histogram(), dtype=np.int64).reshape(3, 256)


def _image_stats(counts: np.ndarray, frames: int) -> dict[str, np.ndarray]:
    """A camera's ``stats.json`` entry in lerobot's layout (values in [0, 1], shape (3,1,1);
    ``count`` = frames, as lerobot's ``compute_episode_stats``) from its [3, 256] pixel
    value counts: exact min, max, mean and std over every pixel of every frame; quantile
    q is the smallest value whose cumulative share reaches q (numpy's "inverted_cdf").
    lerobot's own quantiles are count-weighted means of per-episode histogram estimates."""
    from lerobot.datasets.compute_stats import DEFAULT_QUANTILES

    n = counts.sum(axis=1, keepdims=True).astype(np.float64)
    present = counts > 0
    mean = (counts @ _PIXEL_VALUES) / n[:, 0]
    var = (counts @ (_PIXEL_VALUES**2)) / n[:, 0] - mean**2
    cumulative = np.cumsum(counts, axis=1) / n
    stats = {
        "min": present.argmax(axis=1).astype(np.float64),
        "max": 255.0 - present[:, ::-1].argmax(axis=1),
        "mean": mean,
        "std": np.sqrt(np.maximum(var, 0.0)),
    }
    for q in DEFAULT_QUANTILES:
        stats[f"q{int(q * 100):02d}"] = np.array(
            [np.searchsorted(c, q - 1e-12) for c in cumulative], dtype=np.float64
        )
    out = {k: (v / 255.0).reshape(3, 1, 1) for k, v in stats.items()}
    out["count"] = np.array([frames])
    return out


def fix_image_stats(root: Path, counts: dict[str, np.ndarray], frames: int) -> None:
    """Replace the camera entries of ``root``'s ``meta/stats.json`` by `_image_stats`."""
    from lerobot.datasets.utils import load_stats, write_stats

    stats = load_stats(root)
    if stats is None or not frames:
        return
    for key, value_counts in counts.items():
        stats[key] = _image_stats(value_counts, frames)
    write_stats(stats, root)


# --------------------------------------------------------------------------- writing
def write_part(
    episodes: Iterable[dict[str, np.ndarray]],
    root: Path,
    repo_id: str,
    *,
    fps: int,
    robot_type: str,
    use_videos: bool,
    vcodec: str,
    default_task: str,
    video_file_size_mb: float,
    progress: Callable[[int], None] | None,
) -> tuple[int, int, dict[str, np.ndarray]]:
    """Write ``episodes`` as a new LeRobot dataset at ``root`` with lerobot's public API
    (video files of up to ``video_file_size_mb``); return ``(episodes, frames, pixel value
    counts per camera)``."""
    cls = lerobot_dataset_class()
    dataset = cls.create(
        repo_id=repo_id,
        fps=fps,
        features=lerobot_features(use_videos=use_videos),
        root=root,
        robot_type=robot_type,
        use_videos=use_videos,
        vcodec=vcodec,
        # Frames go straight to one encoder thread per camera instead of PNG files that are
        # read back to encode (that path gave ~30% fewer frames/s here). lerobot drops
        # frames when an encoder's queue is full; an episode's frames always fit in this one.
        streaming_encoding=use_videos,
        encoder_queue_maxsize=1_000_000,
        encoder_threads=1,
    )
    dataset.meta.update_chunk_settings(video_files_size_in_mb=video_file_size_mb)
    counts = {key: np.zeros((3, 256), dtype=np.int64) for key in CAMERA_KEYS}
    last_task = default_task
    n_eps = n_frames = 0
    completed = False
    try:
        with _quiet():
            for ep in episodes:
                text = str(ep["language_instruction"]).strip()
                if text:
                    last_task = text
                length = int(ep["episode_length"])
                columns = {
                    TOP_KEY: ep["rgb"][:length, :, :, 0:3],
                    WRIST_KEY: ep["rgb"][:length, :, :, 3:6],
                    STATE_KEY: ep["proprio"][:length],
                    ACTION_KEY: ep["action"][:length],
                    REWARD_KEY: ep["reward"][:length].reshape(-1, 1).astype(np.float32),
                    SUCCESS_KEY: ep["success"][:length].reshape(-1, 1).astype(bool),
                    DONE_KEY: ep["done"][:length].reshape(-1, 1).astype(bool),
                }
                for key in CAMERA_KEYS:
                    counts[key] += _value_counts(columns[key])
                for t in range(length):
                    frame = {key: value[t] for key, value in columns.items()}
                    dataset.add_frame({**frame, "task": last_task})
                dataset.save_episode()
                n_eps += 1
                n_frames += length
                if progress is not None:
                    progress(n_eps)
        completed = True
    finally:
        # Parquet footers are written here; without it nothing is loadable. After an error
        # (the staging directory is discarded by the caller anyway) a failure to finalize
        # must not mask the original exception, which names the bad input.
        try:
            dataset.finalize()
        except Exception:
            if completed:
                raise
    _remove_empty_dirs(root)
    return n_eps, n_frames, counts


def _remove_empty_dirs(root: Path) -> None:
    """Remove the empty folders lerobot leaves in a finished dataset (``images/<camera>/``
    after it deletes each episode's PNG frames in ``--no-videos`` mode)."""
    for path in sorted(root.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        if path.is_dir() and not any(path.iterdir()):
            path.rmdir()


def prefetch(items: Iterator[Any], depth: int = 3) -> Iterator[Any]:
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


EpisodeRange = Callable[[int, int], Iterator[dict[str, np.ndarray]]]
"""``episodes(start, stop)``: the source's episodes ``start..stop-1``, in order."""


def _part_writer(
    conn: Any,
    episodes: EpisodeRange,
    start: int,
    stop: int,
    root: Path,
    repo_id: str,
    write_kwargs: dict[str, Any],
) -> None:
    """(Forked writer process) read episodes ``start`` to ``stop`` and write them as one
    LeRobot dataset at ``root``; report ``("episode", n)`` on ``conn`` after each and
    finally ``("done", (episodes, frames, counts))`` or ``("error", exception)``."""
    try:
        written = write_part(
            prefetch(episodes(start, stop)),
            root,
            repo_id,
            progress=lambda n: conn.send(("episode", n)),
            **write_kwargs,
        )
        conn.send(("done", written))
    except BaseException as exc:  # reported to the parent, which raises it
        # the traceback stays in this process: the parent's shows only its own frames
        where = f"in LeRobot writer process {repo_id}:\n{traceback.format_exc()}"
        try:
            exc.add_note(where)
            conn.send(("error", exc))
        except Exception:  # an exception that does not pickle
            conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}\n{where}")))


def write_in_parts(
    episodes: EpisodeRange,
    num_episodes: int,
    workers: int,
    root: Path,
    repo_id: str,
    write_kwargs: dict[str, Any],
    progress: Callable[[int], None] | None,
) -> tuple[int, int, dict[str, np.ndarray]]:
    """Write episodes ``0..num_episodes`` with ``workers`` writer processes, each reading
    and writing a contiguous share as a LeRobot dataset of its own, then join the shares
    into one at ``root`` with lerobot's ``aggregate_datasets`` (episode order kept).

    Writers are forked: they start at once with lerobot already imported. Reading a share
    runs no TensorFlow op (NPZ files; RLDS shards through `rlds.read_tfrecords` and TFDS's
    numpy parser), so it is safe in a process forked from one that ran TensorFlow.
    """
    import multiprocessing
    from multiprocessing.connection import wait

    bounds = [num_episodes * i // workers for i in range(workers + 1)]
    parts = [root.with_name(f"{root.name}-part{i}") for i in range(workers)]
    part_ids = [f"{repo_id}-part{i}" for i in range(workers)]
    context = multiprocessing.get_context("fork")
    writers, conns = [], []
    try:
        for i in range(workers):
            ours, theirs = context.Pipe(duplex=False)
            args = (theirs, episodes, bounds[i], bounds[i + 1], parts[i], part_ids[i], write_kwargs)
            writer = context.Process(
                target=_part_writer, args=args, name=f"mikasa-lerobot-writer-{i}", daemon=True
            )
            writer.start()
            theirs.close()
            writers.append(writer)
            conns.append(ours)
        done_per_part = [0] * workers
        results: dict[int, tuple[int, int, dict[str, np.ndarray]]] = {}
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
        from lerobot.datasets.aggregate import aggregate_datasets

        # Its tqdm progress bars go to stderr; a converter reports through ``progress``.
        with _quiet(), contextlib.redirect_stderr(io.StringIO()):
            aggregate_datasets(
                part_ids,
                repo_id,
                roots=parts,
                aggr_root=root,
                video_files_size_in_mb=write_kwargs["video_file_size_mb"],
            )
        counts = {key: sum(r[2][key] for r in results.values()) for key in CAMERA_KEYS}
        return (
            sum(r[0] for r in results.values()),
            sum(r[1] for r in results.values()),
            counts,
        )
    finally:
        for writer in writers:
            if writer.is_alive():
                writer.terminate()
            writer.join()
        for conn in conns:
            conn.close()
        for part in parts:
            shutil.rmtree(part, ignore_errors=True)
