"""Writing LeRobotDataset v3 (RLDS -> LeRobot, NPZ -> LeRobot) with lerobot's public API
only: ``LeRobotDataset.create`` / ``add_frame`` / ``save_episode`` / ``finalize``, and
``aggregate_datasets`` to join parallel writers. Format and features:
:mod:`mikasa_datasets.lerobot_format`; reading: :mod:`mikasa_datasets.lerobot`, which also
exports every public name here.

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

This module holds the public functions and the constants; the writing itself (one dataset
per process, the image statistics, the writer processes and their aggregation) is in
:mod:`mikasa_datasets.lerobot_write_parts`.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets import rlds_read
from mikasa_datasets.conversion import (
    ConversionResult,
    DatasetFormatError,
    commit_output,
    new_staging_dir,
    npz_task_files,
    output_action,
    remove_stale_staging,
)
from mikasa_datasets.lerobot_format import (
    DEFAULT_FPS,
    DEFAULT_VCODEC,
    ROBOT_TYPE,
    SOURCE_METADATA_NAME,
    lerobot_dataset_class,
)
from mikasa_datasets.lerobot_write_parts import (
    EpisodeRange,
    fix_image_stats,
    prefetch,
    write_in_parts,
    write_part,
)
from mikasa_datasets.naming import env_id_to_dataset_name
from mikasa_datasets.npz import EpisodeFormatError, read_episode, read_metadata
from mikasa_datasets.rlds_format import import_tfds

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
    n_eps, n_frames, counts = write_part(
        episodes,
        root,
        repo_id,
        fps=fps,
        robot_type=robot_type,
        use_videos=use_videos,
        vcodec=vcodec,
        default_task=default_task,
        video_file_size_mb=VIDEO_FILE_SIZE_IN_MB,
        progress=progress,
    )
    fix_image_stats(root, counts, n_frames)
    if source_metadata is not None and Path(source_metadata).is_file():
        shutil.copyfile(source_metadata, root / SOURCE_METADATA_NAME)
    return n_eps, n_frames


def writer_count(workers: int | None, num_episodes: int) -> int:
    """Writer processes for ``num_episodes``: ``workers``, or by default one per core with
    at least `EPISODES_PER_WORKER` episodes each; never more than the episodes."""
    if workers is None:
        workers = min(os.cpu_count() or 1, num_episodes // EPISODES_PER_WORKER)
    elif workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    return max(1, min(workers, num_episodes))


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
        "video_file_size_mb": VIDEO_FILE_SIZE_IN_MB,
    }
    report = None if progress is None else (lambda done: progress(done, num_episodes))
    try:
        if n_writers == 1:
            n_eps, n_frames, counts = write_part(
                prefetch(episodes(0, num_episodes)),
                staging,
                repo_id,
                progress=report,
                **write_kwargs,
            )
        else:
            # Each share's instruction fallback starts from the default: a share cannot see
            # the instructions before it (the NPZ schema requires one in every episode).
            n_eps, n_frames, counts = write_in_parts(
                episodes, num_episodes, n_writers, staging, repo_id, write_kwargs, report
            )
        fix_image_stats(staging, counts, n_frames)
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
    import_tfds()  # import TF before lerobot's timer starts (see _convert)
    vdir = rlds_read.find_version_dir(rlds_task_dir)
    task_dir = vdir.parent  # <rlds_root>/<task>/<X.Y.Z>; <task> may be an env id (spec §8)
    info = json.loads((vdir / "dataset_info.json").read_text(encoding="utf-8"))
    total = rlds_read.num_examples(info)
    n = total if max_episodes is None else min(total, max_episodes)
    meta_path = vdir / "metadata.json"
    env_id = task_dir.name
    if meta_path.is_file():
        env_id = str(json.loads(meta_path.read_text(encoding="utf-8")).get("env_id", env_id))

    def episodes(start: int, stop: int) -> Iterator[dict[str, np.ndarray]]:
        return rlds_read.iter_episodes(vdir, start, stop)

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
