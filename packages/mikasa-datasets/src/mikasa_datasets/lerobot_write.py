"""Writing LeRobotDataset v3 (RLDS -> LeRobot, NPZ -> LeRobot) with lerobot's public API
only: ``LeRobotDataset.create`` / ``add_frame`` / ``save_episode`` / ``finalize``, and
``aggregate_datasets`` to join parallel writers. Format, features and reading:
:mod:`mikasa_datasets.lerobot`, which also exports every public name here.

Speed comes from processes, not from changing lerobot: a large conversion runs several
writer processes (`writer_count`), each writing a contiguous share of the episodes as a
LeRobot dataset of its own, and lerobot's ``aggregate_datasets`` joins the shares in
episode order. Episodes, frames and videos are the same for any number of writers (each
episode's video is encoded on its own); what depends on it is how episodes are grouped into
files and lerobot's combined quantiles of the non-image features.

Videos: lerobot's public API chooses only the codec (``vcodec``); everything else is its
streaming encoder at fixed settings (crf 30, GOP 2, yuv420p; SVT-AV1 at preset 12, libx264
at its default preset). We keep lerobot's default, ``vcodec="libsvtav1"`` (AV1;
``video.codec`` in ``meta/info.json`` records it): on collected renders it gave 30.5 dB
PSNR (worst camera-episode 29.1), libx264 at lerobot's crf 30 28.9 dB (worst 27.9, below
the 28 dB bar) for 0-20% less conversion CPU, since lerobot's per-frame bookkeeping,
not the encoder, dominates (figures: the package README). ``vcodec="h264"`` is accepted.
One encoder thread per camera (``encoder_threads=1``), so the video bits do not depend on
the machine's core count.

One correction, made after the fact with lerobot's public ``load_stats`` / ``write_stats``:
lerobot 0.4.4 squares uint8 pixels in uint8, so the image ``std`` it writes is wrong
(huggingface/lerobot#3697, fixed upstream later). The writers count each camera's pixel
values (256 per channel) as they feed the frames, and the camera entries of
``meta/stats.json`` are replaced by the exact statistics of all frames (`_image_stats`).
The per-episode image statistics in ``meta/episodes`` keep lerobot's values: lerobot has no
public API to rewrite them.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import queue
import shutil
import threading
import time
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.lerobot import (
    ACTION_KEY,
    CAMERA_KEYS,
    DEFAULT_FPS,
    DEFAULT_VCODEC,
    DONE_KEY,
    REWARD_KEY,
    ROBOT_TYPE,
    SOURCE_METADATA_NAME,
    STATE_KEY,
    SUCCESS_KEY,
    TOP_KEY,
    WRIST_KEY,
    lerobot_dataset_class,
    lerobot_features,
)
from mikasa_datasets.loaders import (
    DatasetFormatError,
    commit_output,
    new_staging_dir,
    npz_task_files,
    output_action,
    remove_stale_staging,
)
from mikasa_datasets.naming import env_id_to_dataset_name
from mikasa_datasets.npz import EpisodeFormatError, read_episode, read_metadata
from mikasa_datasets.rlds import ConversionResult

__all__ = [
    "EPISODES_PER_WORKER",
    "VIDEO_FILE_SIZE_IN_MB",
    "convert_npz_to_lerobot",
    "convert_rlds_to_lerobot",
    "write_lerobot",
    "writer_count",
]

VIDEO_FILE_SIZE_IN_MB = 200.0
"""Video files hold consecutive episodes up to this size (lerobot's default, the spec's
value), applied through ``meta.update_chunk_settings`` and ``aggregate_datasets``. lerobot
appends each episode by re-muxing the whole current file, so a writer's cost grows with the
square of its episode count; several writers split that too."""

EPISODES_PER_WORKER = 8
"""Default writer processes: one per core, each with at least this many episodes (a
parallel write ends with lerobot's aggregation, ~1 s here)."""


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


def _fix_image_stats(root: Path, counts: dict[str, np.ndarray], frames: int) -> None:
    """Replace the camera entries of ``root``'s ``meta/stats.json`` by `_image_stats`."""
    from lerobot.datasets.utils import load_stats, write_stats

    stats = load_stats(root)
    if stats is None or not frames:
        return
    for key, value_counts in counts.items():
        stats[key] = _image_stats(value_counts, frames)
    write_stats(stats, root)


# --------------------------------------------------------------------------- writing
def _write_part(
    episodes: Iterable[dict[str, np.ndarray]],
    root: Path,
    repo_id: str,
    *,
    fps: int,
    robot_type: str,
    use_videos: bool,
    vcodec: str,
    default_task: str,
    progress: Callable[[int], None] | None,
) -> tuple[int, int, dict[str, np.ndarray]]:
    """Write ``episodes`` as a new LeRobot dataset at ``root`` with lerobot's public API;
    return ``(episodes, frames, pixel value counts per camera)``."""
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
    dataset.meta.update_chunk_settings(video_files_size_in_mb=VIDEO_FILE_SIZE_IN_MB)
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
) -> tuple[int, int]:
    """Write NPZ-schema ``episodes`` as a new LeRobot v3 dataset at ``root`` in this process.

    ``root`` must not exist (lerobot creates it). ``add_frame`` per frame, ``save_episode``
    per episode, then ``finalize``. ``task`` per frame is the episode instruction,
    stripped; an empty one falls back to the last non-empty instruction seen (initially
    ``default_task``), as in the upstream converter. Returns ``(episodes, frames)``.
    """
    root = Path(root)
    n_eps, n_frames, counts = _write_part(
        episodes,
        root,
        repo_id,
        fps=fps,
        robot_type=robot_type,
        use_videos=use_videos,
        vcodec=vcodec,
        default_task=default_task,
        progress=progress,
    )
    _fix_image_stats(root, counts, n_frames)
    if source_metadata is not None and Path(source_metadata).is_file():
        shutil.copyfile(source_metadata, root / SOURCE_METADATA_NAME)
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


def writer_count(workers: int | None, num_episodes: int) -> int:
    """Writer processes for ``num_episodes``: ``workers``, or by default one per core with
    at least `EPISODES_PER_WORKER` episodes each; never more than the episodes."""
    if workers is None:
        workers = min(os.cpu_count() or 1, num_episodes // EPISODES_PER_WORKER)
    elif workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return max(1, min(workers, num_episodes))


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
        written = _write_part(
            _prefetch(episodes(start, stop)),
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


def check_numpy_for_writing() -> None:
    """lerobot 0.4's ``save_episode`` calls ``float()`` on each frame's shape-(1,) value
    (the reward, the done flag), which numpy 2.4 turns into a TypeError: say so before
    anything is written."""
    from importlib.metadata import version

    numpy_version = tuple(int(p) for p in np.__version__.split(".")[:2])
    lerobot_version = tuple(int(p) for p in version("lerobot").split(".")[:2])
    if numpy_version >= (2, 4) and lerobot_version < (0, 5):
        raise RuntimeError(
            f"lerobot {version('lerobot')} cannot write datasets with numpy {np.__version__}: "
            "its save_episode converts shape-(1,) arrays with float(), an error since numpy 2.4; "
            "install numpy<2.4 beside it (pip install 'numpy<2.4', as mikasa-datasets[lerobot] pins)"
        )


def _write_in_parts(
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
                video_files_size_in_mb=VIDEO_FILE_SIZE_IN_MB,
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


def _convert(
    episodes: EpisodeRange,
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
    check_numpy_for_writing()
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
            n_eps, n_frames, counts = _write_part(
                _prefetch(episodes(0, num_episodes)),
                staging,
                repo_id,
                progress=report,
                **write_kwargs,
            )
        else:
            # Each share's instruction fallback starts from the default: a share cannot see
            # the instructions before it (the NPZ schema requires one in every episode).
            n_eps, n_frames, counts = _write_in_parts(
                episodes, num_episodes, n_writers, staging, repo_id, write_kwargs, report
            )
        _fix_image_stats(staging, counts, n_frames)
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
    depend on it, only how they are split into files and lerobot's combined quantiles.
    """
    src = Path(npz_task_dir)
    files = npz_task_files(src, max_episodes)
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
