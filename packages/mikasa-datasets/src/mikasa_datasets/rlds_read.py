"""Reading an RLDS dataset written by :mod:`mikasa_datasets.rlds` (spec §6).

Finds the version directory and its TFRecord shards from ``dataset_info.json``, reads the
records in Python with their CRC-32C checks (:func:`read_tfrecords`: no TensorFlow op runs,
so it works in forked worker processes), decodes them with the stored ``features.json`` and
the package's PNG decoder, and rebuilds NPZ-schema episodes (:func:`iter_episodes`). A
missing, corrupt or truncated file raises DatasetFormatError naming it.

Separate from the export (the builder and :func:`~mikasa_datasets.rlds.convert_npz_to_rlds`
in :mod:`mikasa_datasets.rlds`), which needs only :func:`find_version_dir` and the example
count from here. Import these names from :mod:`mikasa_datasets.rlds`, which re-exports them.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.conversion import DatasetFormatError, require
from mikasa_datasets.rlds_format import (
    BUILDER_NAME,
    SPLIT,
    as_text,
    decode_pngs,
    episode_from_rlds,
    import_tfds,
)


# --------------------------------------------------------------------------- reading
def _shard_lengths(version_dir: Path) -> list[int]:
    """Episodes per shard of the train split, from dataset_info.json."""
    info = json.loads((version_dir / "dataset_info.json").read_text(encoding="utf-8"))
    for split in info.get("splits", []):
        if split.get("name") == SPLIT:
            return [int(n) for n in split.get("shardLengths", [])]
    raise DatasetFormatError(version_dir / "dataset_info.json", f"has no {SPLIT!r} split")


def num_examples(info: dict[str, Any]) -> int:
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
    tfds = import_tfds()
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
    tfds = import_tfds()
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
            return np.array([as_text(v) for v in values])
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
