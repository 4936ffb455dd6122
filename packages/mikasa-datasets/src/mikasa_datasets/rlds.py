"""NPZ -> RLDS (TFDS) export and RLDS reading (datasets spec §6).

Output layout (spec §6.2)::

    <rlds_root>/<dataset_name>/1.0.0/
        mikasa_dataset-train.tfrecord-00000-of-0000N   TFRecord shards (TFDS naming)
        dataset_info.json, features.json               written by TFDS
        metadata.json                                  the NPZ task's metadata, verbatim

readable with ``tfds.builder_from_directory(<version dir>)``. The builder is a real
``tfds.core.GeneratorBasedBuilder`` named ``mikasa_dataset`` (version 1.0.0, split
``train``), run in-process; it is not registered globally, so importing this module has no
side effect on the TFDS registry.

Feature spec (spec §6.3, one RLDS episode per NPZ file)::

    steps/observation/image         Image (128,128,3) uint8 PNG   rgb[t, ..., 0:3] (top)
    steps/observation/wrist_image   Image (128,128,3) uint8 PNG   rgb[t, ..., 3:6] (wrist)
    steps/observation/proprio       float32 (7,)                  proprio[t]
    steps/action                    float32 (7,)                  action[t]
    steps/reward                    float32 ()                    reward[t]
    steps/discount                  float32 ()                    1.0
    steps/is_first                  bool ()                       t == 0
    steps/is_last                   bool ()                       done[t]    (== t == T-1)
    steps/is_terminal               bool ()                       success[t] (== t == T-1)
    steps/language_instruction      Text                          the instruction
    episode_metadata/file_path      Text    source file name train_data_<i>.npz
    episode_metadata/env_id         Text    env id from metadata.json
    episode_metadata/episode_index  int32   i
    episode_metadata/episode_seed   int64   episode_seed
    episode_metadata/episode_length int32   T
    episode_metadata/success_once   bool    success_once

``is_last``/``is_terminal`` are written from ``done``/``success`` (which a valid episode
has set exactly at the last step, so they equal the spec's ``t == T-1``); together with
the metadata this makes NPZ -> RLDS -> NPZ exact, field for field.

Images are PNG-encoded here (numpy "Sub" filter + ISA-L or zlib deflate) and handed to TFDS
as bytes: several times faster than TFDS' own TF-graph encoder, lossless, standard PNG that
``tf.image.decode_png`` reads. Encoding of upcoming episodes runs in a thread pool while
TFDS serialises the current one (the deflate releases the GIL).
"""

from __future__ import annotations

import functools
import io
import json
import os
import shutil
import struct
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.loaders import (
    DatasetFormatError,
    commit_output,
    new_staging_dir,
    npz_task_files,
    output_action,
    remove_stale_staging,
    require,
)
from mikasa_datasets.naming import env_id_to_dataset_name
from mikasa_datasets.npz import (
    EpisodeFormatError,
    fast_zlib,
    read_episode,
    read_metadata,
)

__all__ = [
    "BUILDER_NAME",
    "RLDS_DIRNAME",
    "RLDS_VERSION",
    "SPLIT",
    "ConversionResult",
    "convert_npz_to_rlds",
    "encode_png",
    "episode_from_rlds",
    "episode_to_rlds",
    "find_version_dir",
    "iter_episodes",
    "iter_examples",
    "rlds_features",
    "shard_files",
]

RLDS_DIRNAME = "data_rlds"
BUILDER_NAME = "mikasa_dataset"
RLDS_VERSION = "1.0.0"
SPLIT = "train"
IMAGE_SHAPE = (128, 128, 3)
STATE_DIM = 7

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- libraries
@functools.cache
def _tfds() -> Any:
    """tensorflow_datasets, imported quietly on first use (MissingDependencyError if absent)."""
    # TF logs a screenful of CPU-feature notes at import; keep errors only. The oneDNN
    # note ignores TF_CPP_MIN_LOG_LEVEL; oneDNN kernels only change float maths, which
    # this pipeline does not do (it moves bytes), so turning them off changes nothing.
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
    os.environ.setdefault("TF_ENABLE_ONEDNN_OPTS", "0")
    tf = require("tensorflow", "rlds")
    tfds = require("tensorflow_datasets", "rlds")
    # Conversions are CPU work on small tensors; TF must not grab a GPU if one exists.
    try:
        tf.config.set_visible_devices([], "GPU")
    except (RuntimeError, ValueError):  # already initialised: nothing to do
        pass
    tfds.disable_progress_bar()
    import absl.logging

    absl.logging.set_verbosity(absl.logging.ERROR)  # e.g. "OpenCV is not installed"
    return tfds


def rlds_features() -> Any:
    """The ``tfds.features.FeaturesDict`` of one RLDS episode (module docstring)."""
    tfds = _tfds()
    f = tfds.features

    def image() -> Any:
        return f.Image(shape=IMAGE_SHAPE, dtype=np.uint8, encoding_format="png")

    return f.FeaturesDict(
        {
            "steps": f.Dataset(
                {
                    "observation": f.FeaturesDict(
                        {
                            "image": image(),
                            "wrist_image": image(),
                            "proprio": f.Tensor(shape=(STATE_DIM,), dtype=np.float32),
                        }
                    ),
                    "action": f.Tensor(shape=(STATE_DIM,), dtype=np.float32),
                    "reward": f.Scalar(dtype=np.float32),
                    "discount": f.Scalar(dtype=np.float32),
                    "is_first": f.Scalar(dtype=np.bool_),
                    "is_last": f.Scalar(dtype=np.bool_),
                    "is_terminal": f.Scalar(dtype=np.bool_),
                    "language_instruction": f.Text(),
                }
            ),
            "episode_metadata": f.FeaturesDict(
                {
                    "file_path": f.Text(),
                    "env_id": f.Text(),
                    "episode_index": f.Scalar(dtype=np.int32),
                    "episode_seed": f.Scalar(dtype=np.int64),
                    "episode_length": f.Scalar(dtype=np.int32),
                    "success_once": f.Scalar(dtype=np.bool_),
                }
            ),
        }
    )


# --------------------------------------------------------------------------- PNG
def _deflate_zlib(data: bytes) -> bytes:
    compressor = zlib.compressobj(1, zlib.DEFLATED, 15, 9, zlib.Z_RLE)
    return compressor.compress(data) + compressor.flush()


# zlib streams of PNG's IDAT: Intel ISA-L's where installed (`fast_zlib`), else zlib's.
# Measured on 128x128 MIKASA renders (2-core machine): ISA-L level 1 0.15 ms and 25.9 KB per
# image, zlib level 1 with the RLE strategy 0.55 ms and 25.4 KB; inflating, ISA-L ~2x
# zlib. Either stream decodes to the same pixels.
_deflate = _deflate_zlib if fast_zlib is zlib else functools.partial(fast_zlib.compress, level=1)
_inflate = fast_zlib.decompress


def encode_png(image: np.ndarray) -> bytes:
    """Encode an (H, W, 3) uint8 image as an 8-bit RGB PNG (lossless).

    Every row uses the PNG "Sub" filter (difference to the pixel on the left), computed
    on contiguous rows; the filtered bytes go through `_deflate`. PNG encoding is the bulk
    of NPZ -> RLDS time.
    """
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {image.shape} {image.dtype}")
    h, w, _ = image.shape
    rows = np.ascontiguousarray(image).reshape(h, w * 3)  # a channel slice of the NPZ frame
    raw = np.empty((h, w * 3 + 1), dtype=np.uint8)
    raw[:, 0] = 1  # filter type "Sub"
    raw[:, 1:4] = rows[:, :3]  # the first pixel has no left neighbour
    np.subtract(rows[:, 3:], rows[:, :-3], out=raw[:, 4:])  # uint8 wrap-around == PNG's mod 256
    idat = _deflate(raw.tobytes())

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)  # 8-bit, truecolour, no interlace
    return _PNG_SIGNATURE + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def _png_rows(data: bytes) -> tuple[np.ndarray, int, int] | None:
    """(filtered rows [H, W*3 + 1], H, W) of an 8-bit RGB non-interlaced PNG, chunk CRCs
    checked; None for any other kind of PNG (left to PIL)."""
    if data[:8] != _PNG_SIGNATURE:
        raise ValueError("not a PNG image (bad signature)")
    pos, header, idat = 8, None, []
    while pos + 8 <= len(data):
        (length,), kind = struct.unpack_from(">I", data, pos), data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack_from(">I", data, pos + 8 + length)
        if len(body) != length or zlib.crc32(kind + body) != crc:
            raise ValueError(f"corrupt PNG: chunk {kind!r} is cut or fails its CRC")
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    if header is None or not idat:
        raise ValueError("corrupt PNG: no IHDR or IDAT chunk")
    w, h, depth, colour, _, _, interlace = header
    if (depth, colour, interlace) != (8, 2, 0):
        return None
    raw = _inflate(b"".join(idat))
    if len(raw) != h * (w * 3 + 1):
        raise ValueError(f"corrupt PNG: {len(raw)} bytes of pixel data for {w}x{h} RGB")
    return np.frombuffer(raw, np.uint8).reshape(h, w * 3 + 1), h, w


def decode_pngs(images: list[bytes]) -> np.ndarray:
    """Decode PNG images of one size into a [N, H, W, C] uint8 array.

    8-bit RGB images whose rows use PNG's "None" or "Sub" filter (what `encode_png`
    writes) are decoded here, the "Sub" rows as a running sum along the row (uint8
    addition wraps mod 256, as PNG's does): ~4x faster than PIL. Any other PNG (other
    filters, bit depths, colour types, interlacing) is decoded by PIL.
    """
    from PIL import Image

    out = []
    for data in images:
        parsed = _png_rows(bytes(data))
        filters = None if parsed is None else parsed[0][:, 0]
        if parsed is None or np.any(filters > 1):
            with Image.open(io.BytesIO(data)) as image:
                out.append(np.asarray(image))
            continue
        rows, h, w = parsed
        pixels = rows[:, 1:].reshape(h, w, 3)
        summed = np.cumsum(pixels, axis=1, dtype=np.uint8)
        out.append(summed if filters.all() else np.where(filters[:, None, None] == 1, summed, pixels))
    return np.stack(out) if out else np.zeros((0, *IMAGE_SHAPE), np.uint8)


# --------------------------------------------------------------------------- episode <-> example
def _split_cameras(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The top and wrist frames of a [T, H, W, 6] array, each contiguous [T, H, W, 3].
    Copied as 3-byte pixels (a void view): ~2x faster than copying a channel slice."""
    pixels = np.ascontiguousarray(rgb).view(np.dtype((np.void, 3)))  # [T, H, W, 2]
    shape = (*rgb.shape[:3], 3)
    return tuple(np.ascontiguousarray(pixels[..., c]).view(np.uint8).reshape(shape) for c in (0, 1))


def _join_cameras(top: np.ndarray, wrist: np.ndarray) -> np.ndarray:
    """The [T, H, W, 6] array of two [T, H, W, 3] uint8 camera arrays (`_split_cameras`
    undone), copied as 3-byte pixels: ~3x faster than concatenating along the channels."""
    top, wrist = (np.ascontiguousarray(a, dtype=np.uint8) for a in (top, wrist))
    pixel = np.dtype((np.void, 3))
    joined = np.empty((*top.shape[:3], 2), dtype=pixel)
    joined[..., 0] = top.view(pixel)[..., 0]
    joined[..., 1] = wrist.view(pixel)[..., 0]
    return joined.view(np.uint8).reshape(*top.shape[:3], 6)


def episode_to_rlds(
    episode: dict[str, np.ndarray],
    *,
    file_path: str,
    env_id: str,
    episode_index: int,
) -> dict[str, Any]:
    """One NPZ episode as a TFDS example dict of :func:`rlds_features` (images as PNG)."""
    t = int(episode["episode_length"])
    top, wrist = _split_cameras(episode["rgb"])
    instruction = str(episode["language_instruction"])
    return {
        "steps": {
            "observation": {
                "image": [encode_png(top[i]) for i in range(t)],
                "wrist_image": [encode_png(wrist[i]) for i in range(t)],
                "proprio": episode["proprio"],
            },
            "action": episode["action"],
            "reward": episode["reward"],
            "discount": np.ones(t, dtype=np.float32),
            "is_first": np.arange(t) == 0,
            "is_last": episode["done"].astype(bool),
            "is_terminal": episode["success"].astype(bool),
            "language_instruction": [instruction] * t,
        },
        "episode_metadata": {
            "file_path": file_path,
            "env_id": env_id,
            "episode_index": np.int32(episode_index),
            "episode_seed": np.int64(episode["episode_seed"]),
            "episode_length": np.int32(t),
            "success_once": bool(episode["success_once"]),
        },
    }


def episode_from_rlds(
    steps: dict[str, np.ndarray], metadata: dict[str, Any]
) -> dict[str, np.ndarray]:
    """Rebuild the NPZ-schema episode from stacked RLDS ``steps`` arrays and metadata."""
    obs = steps["observation"]
    instructions = steps["language_instruction"]
    text = _text(instructions[0]) if len(instructions) else ""
    t = len(steps["reward"])
    return {
        "rgb": _join_cameras(obs["image"], obs["wrist_image"]),
        "proprio": np.asarray(obs["proprio"], dtype=np.float32),
        "action": np.asarray(steps["action"], dtype=np.float32),
        "reward": np.asarray(steps["reward"], dtype=np.float32),
        "success": np.asarray(steps["is_terminal"]).astype(np.int32),
        "done": np.asarray(steps["is_last"]).astype(np.int32),
        "language_instruction": np.array(text),
        "success_once": np.array(bool(metadata.get("success_once", True))),
        "episode_length": np.array(int(metadata.get("episode_length", t)), dtype=np.int32),
        "episode_seed": np.array(int(metadata.get("episode_seed", -1)), dtype=np.int64),
    }


def _text(value: Any) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)


# --------------------------------------------------------------------------- builder
@functools.cache
def _builder_class() -> type:
    """The ``mikasa_dataset`` GeneratorBasedBuilder (created once, not registered)."""
    tfds = _tfds()

    class MikasaDataset(tfds.core.GeneratorBasedBuilder, skip_registration=True):
        """MIKASA-Robo-VLA episodes as RLDS; examples come from ``example_source``."""

        VERSION = tfds.core.Version(RLDS_VERSION)
        RELEASE_NOTES = {RLDS_VERSION: "MIKASA-Robo-VLA episodes converted from NPZ."}

        def __init__(
            self, *, example_source: Callable[[], Iterable[tuple[int, dict]]], **kwargs: Any
        ):
            self._example_source = example_source
            super().__init__(**kwargs)

        def _info(self) -> Any:
            return tfds.core.DatasetInfo(
                builder=self,
                description="MIKASA-Robo-VLA memory-intensive manipulation episodes (RLDS).",
                features=rlds_features(),
                homepage="https://github.com/CognitiveAISystems/MIKASA-Robo",
                # Keep the NPZ episode order: episode i of the shards is train_data_<i>.npz.
                disable_shuffling=True,
            )

        def _split_generators(self, dl_manager: Any) -> dict[str, Any]:
            return {SPLIT: self._generate_examples()}

        def _generate_examples(self) -> Iterator[tuple[int, dict]]:
            yield from self._example_source()

        # TFDS prints "Downloading and preparing dataset ..." banners meant for its catalogue
        # datasets; a converter reports through its own ``progress`` callback instead.
        def _log_download_bytes(self) -> None:
            pass

        def _log_download_done(self) -> None:
            pass

    assert MikasaDataset.name == BUILDER_NAME
    return MikasaDataset


@dataclass
class ConversionResult:
    """What a conversion did: where, how much, how long; ``skipped`` under ``resume``."""

    path: Path
    episodes: int
    frames: int
    seconds: float
    skipped: bool = False

    @property
    def frames_per_second(self) -> float:
        """Converted frames per wall-clock second (0 when skipped)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0


def _example_from_file(item: tuple[int, Path, str]) -> tuple[int, dict, int]:
    """(index, TFDS example, length) of the NPZ episode ``item = (index, path, env_id)``."""
    index, path, env_id = item
    try:
        ep = read_episode(path, validate=True)
    except EpisodeFormatError:
        raise
    except Exception as exc:  # anything else while reading is still this file's fault
        raise DatasetFormatError(path, f"cannot be read: {exc}") from exc
    return (
        index,
        episode_to_rlds(ep, file_path=path.name, env_id=env_id, episode_index=index),
        int(ep["episode_length"]),
    )


def _prefetched(items: list[Any], fn: Callable[[Any], Any], workers: int) -> Iterator[Any]:
    """``map(fn, items)`` in order, computed up to ``2 * workers`` items ahead by
    ``workers`` forked processes (threads where fork is unavailable).

    Processes, not threads: building an example is PNG compression (which releases the GIL)
    plus numpy and bytes work (which holds it, as does TFDS's serialisation in the main
    thread); processes measured 10-15% faster on rendered episodes (2 cores). ``fn`` runs
    no TensorFlow op, so forking after TensorFlow's import is safe.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    if workers <= 1:
        yield from map(fn, items)
        return
    if "fork" in multiprocessing.get_all_start_methods():
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"))
    else:
        pool = ThreadPoolExecutor(max_workers=workers)
    try:
        pending = [pool.submit(fn, x) for x in items[: 2 * workers]]
        nxt = len(pending)
        while pending:
            result = pending.pop(0).result()
            if nxt < len(items):
                pending.append(pool.submit(fn, items[nxt]))
                nxt += 1
            yield result
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def convert_npz_to_rlds(
    npz_task_dir: str | os.PathLike[str],
    rlds_root: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    resume: bool = False,
    max_episodes: int | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ConversionResult:
    """Convert one NPZ task directory to ``<rlds_root>/<dataset_name>/1.0.0/``.

    ``npz_task_dir`` is ``.../data_npz/<dataset_name>`` with ``train_data_<i>.npz`` and
    ``metadata.json``. Every episode is read with the schema check and the §3.1 invariants
    (a corrupt, truncated or invalid file raises an error naming it) before anything is
    written. The output is built in a hidden staging directory next to the destination and
    renamed into place only when complete.

    ``overwrite`` replaces an existing output (after the new one is complete); ``resume``
    keeps an existing output whose episode count matches the source and returns
    ``skipped=True``; with neither, an existing output raises OutputExistsError.
    ``max_episodes`` converts only the first N episodes (smoke tests). ``progress(done,
    total)`` is called after each episode is handed to TFDS.
    """
    builder_class = _builder_class()  # imports TF first: not part of the conversion time
    t0 = time.perf_counter()
    src = Path(npz_task_dir)
    files = npz_task_files(src, max_episodes)
    meta_path = src / "metadata.json"
    if not meta_path.is_file():
        raise DatasetFormatError(
            meta_path, "missing; every NPZ task directory has a metadata.json (spec §3.4)"
        )
    meta = read_metadata(src)
    name = env_id_to_dataset_name(src.name)
    env_id = str(meta.get("env_id", name))
    final = Path(rlds_root) / name

    def complete(existing: Path) -> bool:
        try:
            info = json.loads((find_version_dir(existing) / "dataset_info.json").read_text())
            return _num_examples(info) == len(files)
        except (OSError, ValueError, KeyError, DatasetFormatError):
            return False

    if output_action(final, overwrite=overwrite, resume=resume, is_complete=complete) == "skip":
        return ConversionResult(final, len(files), 0, time.perf_counter() - t0, skipped=True)
    remove_stale_staging(final)

    frames = 0

    def source() -> Iterator[tuple[int, dict]]:
        nonlocal frames
        items = [(index, path, env_id) for index, path in enumerate(files)]
        for done, (index, ex, t) in enumerate(
            _prefetched(items, _example_from_file, workers or min(2, os.cpu_count() or 1)), 1
        ):
            frames += t
            yield index, ex
            if progress is not None:
                progress(done, len(items))

    staging = new_staging_dir(final)
    try:
        tfds_dir = staging / "_tfds"
        builder = builder_class(example_source=source, data_dir=str(tfds_dir))
        builder.download_and_prepare(
            download_dir=str(tfds_dir / "downloads"),
            download_config=_tfds().download.DownloadConfig(
                # One process, no Beam; max_examples_per_split honours nothing here (we
                # already cut the file list) but keeps TFDS from computing extra stats.
                compute_stats=_tfds().download.ComputeStatsMode.SKIP,
            ),
        )
        built = tfds_dir / BUILDER_NAME / RLDS_VERSION
        version_dir = staging / RLDS_VERSION
        os.replace(built, version_dir)
        shutil.rmtree(tfds_dir)
        shutil.copyfile(meta_path, version_dir / "metadata.json")
        commit_output(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return ConversionResult(final / RLDS_VERSION, len(files), frames, time.perf_counter() - t0)


# --------------------------------------------------------------------------- reading
def _shard_lengths(version_dir: Path) -> list[int]:
    """Episodes per shard of the train split, from dataset_info.json."""
    info = json.loads((version_dir / "dataset_info.json").read_text(encoding="utf-8"))
    for split in info.get("splits", []):
        if split.get("name") == SPLIT:
            return [int(n) for n in split.get("shardLengths", [])]
    raise DatasetFormatError(version_dir / "dataset_info.json", f"has no {SPLIT!r} split")


def _num_examples(info: dict[str, Any]) -> int:
    """Total number of examples of the ``train`` split in a dataset_info.json mapping."""
    for split in info.get("splits", []):
        if split.get("name") == SPLIT:
            return sum(int(n) for n in split.get("shardLengths", []))
    raise KeyError(f"no {SPLIT!r} split")


def find_version_dir(path: str | os.PathLike[str]) -> Path:
    """The TFDS version directory for ``path``: itself if it holds ``dataset_info.json``,
    else its highest ``X.Y.Z`` sub-directory (numeric order)."""
    p = Path(path)
    if (p / "dataset_info.json").is_file():
        return p
    versions = []
    if p.is_dir():
        for c in p.iterdir():
            parts = c.name.split(".")
            if c.is_dir() and len(parts) == 3 and all(x.isdigit() for x in parts):
                versions.append((tuple(int(x) for x in parts), c))
    if not versions:
        raise DatasetFormatError(
            p, "not an RLDS dataset: no dataset_info.json and no X.Y.Z version directory"
        )
    return max(versions)[1]


def shard_files(version_dir: str | os.PathLike[str]) -> list[Path]:
    """The TFRecord shards of the train split as dataset_info.json lists them.

    Raises DatasetFormatError naming a shard that is listed but missing on disk.
    """
    vdir = Path(version_dir)
    info_path = vdir / "dataset_info.json"
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetFormatError(info_path, f"unreadable: {exc}") from exc
    name = info.get("name", BUILDER_NAME)
    fmt = info.get("fileFormat", "tfrecord")
    for split in info.get("splits", []):
        if split.get("name") == SPLIT:
            n = len(split.get("shardLengths", []))
            files = [vdir / f"{name}-{SPLIT}.{fmt}-{i:05d}-of-{n:05d}" for i in range(n)]
            for f in files:
                if not f.is_file():
                    raise DatasetFormatError(f, "shard listed in dataset_info.json is missing")
            return files
    raise DatasetFormatError(info_path, f"has no {SPLIT!r} split")


def iter_examples(
    path: str | os.PathLike[str], start: int = 0, stop: int | None = None
) -> Iterator[tuple[Path, dict[str, Any], dict[str, Any]]]:
    """``(shard, steps, episode_metadata)`` for the stored episodes ``start`` to ``stop``
    (default: all), in stored order, numpy values.

    ``steps`` holds stacked arrays (``steps["observation"]["image"]`` is (T,128,128,3)).
    Shards are read one by one so that a corrupt or truncated record raises
    DatasetFormatError naming its shard file; shards wholly before ``start`` are not read
    (dataset_info.json gives each shard's length).
    """
    tfds = _tfds()
    vdir = find_version_dir(path)
    try:
        features = tfds.features.FeaturesDict.from_config(str(vdir))
    except Exception as exc:  # TFDS raises assorted errors for a bad features.json
        raise DatasetFormatError(vdir / "features.json", f"cannot be loaded: {exc}") from exc
    steps_feature = features["steps"]
    meta_feature = features["episode_metadata"]
    png_keys = _png_observation_keys(steps_feature)
    # PNG observations are decoded by `decode_pngs`, a whole episode at once.
    decoders = {"steps": {"observation": {k: tfds.decode.SkipDecoding() for k in png_keys}}}
    if stop is not None and stop <= start:
        return
    shards = shard_files(vdir)
    lengths = _shard_lengths(vdir)
    first = 0  # stored index of the shard's first episode
    for shard, length in zip(shards, lengths, strict=True):
        if stop is not None and first >= stop:
            return
        if first + length <= start:
            first += length
            continue
        skip = max(0, start - first)
        take = length - skip if stop is None else min(length, stop - first) - skip
        first += length
        for raw in read_tfrecords(shard, skip, take):
            try:
                example = features.deserialize_example_np(raw, decoders=decoders)
                step_list = list(example["steps"])
                images = {
                    k: decode_pngs([step["observation"].pop(k) for step in step_list])
                    for k in png_keys
                }
                steps = _stack_steps(step_list, steps_feature)
                steps["observation"].update(images)
                metadata = {k: example["episode_metadata"][k] for k in meta_feature.keys()}
            except Exception as exc:
                raise DatasetFormatError(
                    shard, f"record does not match features.json: {exc}"
                ) from exc
            yield shard, steps, metadata


def _png_observation_keys(steps_feature: Any) -> list[str]:
    """The step observations stored as uint8 PNG images."""
    tfds = _tfds()
    try:
        observation = steps_feature.feature["observation"]
        keys = list(observation.keys())
    except (AttributeError, KeyError, TypeError):
        return []
    return [
        k
        for k in keys
        if isinstance(observation[k], tfds.features.Image)
        and observation[k].encoding_format in (None, "png")
        and observation[k].np_dtype == np.uint8
    ]


_TFRECORD_MASK_DELTA = 0xA282EAD8


def _masked_crc32c(data: bytes | memoryview) -> int:
    """TFRecord's checksum: CRC-32C, rotated right by 15 bits, plus a constant."""
    crc = require("google_crc32c", "rlds").value(data)
    return (((crc >> 15) | (crc << 17)) + _TFRECORD_MASK_DELTA) & 0xFFFFFFFF


def read_tfrecords(
    path: str | os.PathLike[str], skip: int = 0, take: int | None = None
) -> Iterator[bytes]:
    """The records of a TFRecord file, from the ``skip``-th, at most ``take`` of them.

    Read in Python (no TensorFlow op runs, so this works in a process forked from one that
    ran TensorFlow), every record's length and data checked against their CRC-32C
    checksums; a cut or corrupt file raises DatasetFormatError naming it. Skipped records
    are stepped over by their lengths, not read.
    """
    path = Path(path)
    size = path.stat().st_size
    with open(path, "rb") as f:
        index = 0
        while take is None or index < skip + take:
            header = f.read(12)
            if not header:
                return
            if len(header) < 12:
                raise DatasetFormatError(
                    path, f"corrupt or truncated TFRecord: record {index}'s header is cut"
                )
            length, length_crc = struct.unpack("<QI", header)
            if _masked_crc32c(header[:8]) != length_crc:
                raise DatasetFormatError(
                    path,
                    f"corrupt or truncated TFRecord: record {index}'s length fails its checksum",
                )
            if f.tell() + length + 4 > size:
                raise DatasetFormatError(
                    path,
                    f"corrupt or truncated TFRecord: record {index} ends past the end of the file",
                )
            if index < skip:
                f.seek(length + 4, os.SEEK_CUR)
            else:
                data = f.read(length)
                (data_crc,) = struct.unpack("<I", f.read(4))
                if _masked_crc32c(data) != data_crc:
                    raise DatasetFormatError(
                        path,
                        f"corrupt or truncated TFRecord: record {index}'s data fails its checksum",
                    )
                yield data
            index += 1


def _stack_steps(steps: list[dict[str, Any]], feature: Any) -> dict[str, Any]:
    """list of step dicts -> nested dict of stacked arrays (empty episodes allowed)."""

    def stack(values: list[Any]) -> Any:
        first = values[0] if values else None
        if isinstance(first, dict):
            return {k: stack([v[k] for v in values]) for k in first}
        if isinstance(first, (bytes, str)):
            return np.array([_text(v) for v in values])
        return np.stack([np.asarray(v) for v in values]) if values else np.zeros((0,))

    if not steps:
        raise ValueError("episode has no steps")
    return stack(steps)


def iter_episodes(
    path: str | os.PathLike[str], start: int = 0, stop: int | None = None
) -> Iterator[dict[str, np.ndarray]]:
    """Episodes ``start`` to ``stop`` (default: all) of an RLDS task/version directory in
    the NPZ schema (exact round trip)."""
    for _, steps, metadata in iter_examples(path, start, stop):
        yield episode_from_rlds(steps, {k: _meta_value(v) for k, v in metadata.items()})


def _meta_value(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.decode("utf-8")
    if isinstance(v, np.ndarray) and v.ndim == 0:
        return v.item()
    return v
