"""One RLDS episode as this package writes it: names, feature spec, PNG codec, NPZ <-> example.

The pieces that both the NPZ -> RLDS export (:mod:`mikasa_datasets.rlds`) and the reader
(:mod:`mikasa_datasets.rlds_read`) need: the dataset's names and version, the quiet lazy
import of TensorFlow Datasets (:func:`import_tfds`; importing this module imports no
TensorFlow),
:func:`rlds_features` (the feature spec of the :mod:`mikasa_datasets.rlds` docstring), the
PNG codec (:func:`encode_png`, :func:`decode_pngs`) and the mapping between an NPZ episode
and a TFDS example (:func:`episode_to_rlds`, :func:`episode_from_rlds`). Import these names
from :mod:`mikasa_datasets.rlds`, which re-exports them.
"""

from __future__ import annotations

import functools
import io
import os
import struct
import zlib
from typing import Any

import numpy as np

from mikasa_datasets.conversion import require
from mikasa_datasets.npz import fast_zlib

RLDS_DIRNAME = "data_rlds"
BUILDER_NAME = "mikasa_dataset"
RLDS_VERSION = "1.0.0"
SPLIT = "train"
IMAGE_SHAPE = (128, 128, 3)
STATE_DIM = 7

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- libraries
@functools.cache
def import_tfds() -> Any:
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
    """The ``tfds.features.FeaturesDict`` of one RLDS episode (``rlds`` module docstring)."""
    tfds = import_tfds()
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
# Measured on 128x128 MIKASA renders (a 2-core CPU machine): ISA-L level 1 0.15 ms and 25.9 KB per
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


def png_rows(data: bytes) -> tuple[np.ndarray, int, int] | None:
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
        parsed = png_rows(bytes(data))
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
    text = as_text(instructions[0]) if len(instructions) else ""
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


def as_text(value: Any) -> str:
    """A TFDS text value as ``str``: bytes decoded as UTF-8, anything else through ``str``."""
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)
