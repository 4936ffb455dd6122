"""Checked, fast reading of NPZ episode files (the reading half of :mod:`mikasa_datasets.npz`).

A file is read into memory once; members stored uncompressed (what :func:`numpy.savez`
writes) are CRC-checked and viewed in place, without zipfile's chunked stream reads. Every
key's dtype and shape is checked from its array header against the schema
(:mod:`mikasa_datasets.npz_schema`) before any frame data is trusted. :data:`fast_zlib`
(ISA-L where installed, else zlib) lives here too; the RLDS PNG codec shares it.

Separate from :mod:`mikasa_datasets.npz` because the zip/``.npy`` access is low-level code of
its own. Import these names from :mod:`mikasa_datasets.npz`, which re-exports them.
"""

from __future__ import annotations

import io
import os
import struct
import zipfile
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np

from mikasa_datasets.npz_schema import (
    EPISODE_KEYS,
    RL_EPISODE_KEYS,
    RL_SCHEMA,
    SCHEMA,
    Episode,
    EpisodeFormatError,
    KeySpec,
    check_array,
    check_keys,
    check_lengths,
    validate_episode,
    validate_rl_episode,
)


# --------------------------------------------------------------------------- read
def _read_header(fp: IO[bytes]) -> tuple[tuple[int, ...], bool, np.dtype]:
    version = np.lib.format.read_magic(fp)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(fp)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(fp)
    # Version 3.0 (utf-8 headers) has no public reader; numpy's own loader uses this.
    return np.lib.format._read_array_header(fp, version)  # type: ignore[attr-defined]


def _read_into_bytearray(path: Path) -> bytearray:
    """The whole file, read straight into a bytearray (one copy fewer than bytes)."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = bytearray(size)
        got = f.readinto(data)
    del data[got:]  # a file that shrank meanwhile
    return data


def _zlib_module() -> Any:
    """Intel ISA-L's zlib-compatible module (``isal``, the ``rlds`` extra) where installed,
    else zlib: the same streams and checksums, 3-5x faster here (CRC-32, deflate,
    inflate). NPZ CRC checks and the RLDS PNG codec use it."""
    try:
        from isal import isal_zlib
    except ImportError:
        return zlib
    return isal_zlib


fast_zlib = _zlib_module()
_crc32 = fast_zlib.crc32


def _array_from_npy_bytes(
    payload: memoryview, shape: tuple[int, ...], fortran_order: bool, dtype: np.dtype, start: int
) -> np.ndarray:
    """The array of a whole ``.npy`` file in memory (its header already parsed: ``start``
    is where the data begins), viewing the data without a copy."""
    if dtype.hasobject:
        raise ValueError(f"holds Python objects (dtype {dtype})")
    count = int(np.prod(shape, dtype=np.int64))
    size = count * dtype.itemsize
    if len(payload) - start != size:
        raise ValueError(f"array data is {len(payload) - start} bytes, its header says {size}")
    arr = np.frombuffer(payload, dtype=dtype, count=count, offset=start)
    if not arr.flags.aligned:  # the member sits anywhere in the zip; small arrays: copy
        arr = arr.copy()
    return arr.reshape(shape, order="F" if fortran_order else "C")


class NpzArchive:
    """An NPZ file opened for schema-checked access; every error names the file.

    The file is read into memory once. Members stored uncompressed (``numpy.savez``, what
    this package writes) are checked (CRC-32) and viewed in place, without zipfile's
    chunked stream reads; compressed members go through zipfile.
    """

    def __init__(self, path: Path, schema: Mapping[str, KeySpec] = SCHEMA) -> None:
        self.path = path
        self.schema = schema
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such episode file")
        try:
            self.data = _read_into_bytearray(path)  # writable: arrays viewing it are too
            self.zf = zipfile.ZipFile(path)  # reads the central directory only
            names = self.zf.namelist()
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError) as exc:
            raise EpisodeFormatError(
                path, f"not a readable NPZ archive (truncated or corrupt?): {exc}"
            ) from exc
        bad = [n for n in names if not n.endswith(".npy")]
        if bad:
            self.close()
            raise EpisodeFormatError(path, f"archive member(s) {bad} are not .npy arrays")
        self.members = {n[: -len(".npy")]: n for n in names}
        self._stored: dict[str, memoryview] = {}
        self._headers: dict[str, tuple[tuple[int, ...], bool, np.dtype, int]] = {}
        try:
            check_keys(list(self.members), path, schema)
        except BaseException:
            self.close()
            raise

    def _stored_bytes(self, key: str) -> memoryview | None:
        """The CRC-checked bytes of an uncompressed member (None for a compressed one)."""
        if key in self._stored:
            return self._stored[key]
        info = self.zf.getinfo(self.members[key])
        if info.compress_type != zipfile.ZIP_STORED:
            return None
        offset = info.header_offset
        local = bytes(self.data[offset : offset + 30])
        if len(local) < 30 or local[:4] != b"PK\x03\x04":
            raise ValueError("bad local file header")
        name_length, extra_length = struct.unpack("<HH", local[26:30])
        start = offset + 30 + name_length + extra_length
        payload = memoryview(self.data)[start : start + info.compress_size]
        if len(payload) != info.compress_size:
            raise EOFError(f"member data ends after {len(payload)} of {info.compress_size} bytes")
        if _crc32(payload) != info.CRC:
            raise zipfile.BadZipFile(f"bad CRC-32 for file {info.filename!r}")
        self._stored[key] = payload
        return payload

    def _stored_header(self, key: str, payload: memoryview) -> tuple[tuple[int, ...], bool, np.dtype, int]:
        """(shape, fortran order, dtype, data offset) of an uncompressed member, parsed once."""
        if key not in self._headers:
            stream = io.BytesIO(payload[:4096])  # headers are at most a few hundred bytes
            shape, fortran_order, dtype = _read_header(stream)
            self._headers[key] = (tuple(shape), fortran_order, dtype, stream.tell())
        return self._headers[key]

    def header(self, key: str) -> tuple[tuple[int, ...], np.dtype]:
        """(shape, dtype) of member ``key`` from its ``.npy`` header (data not read)."""
        try:
            payload = self._stored_bytes(key)
            if payload is not None:
                shape, _, dtype, _ = self._stored_header(key, payload)
            else:
                with self.zf.open(self.members[key]) as fp:
                    shape, _, dtype = _read_header(fp)
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
            raise EpisodeFormatError(
                self.path, f"key {key!r} cannot be read (corrupt or truncated?): {exc}"
            ) from exc
        return tuple(shape), dtype

    def array(self, key: str) -> np.ndarray:
        """Member ``key`` as an array (CRC-checked; viewing the file's bytes when stored)."""
        try:
            payload = self._stored_bytes(key)
            if payload is not None:
                arr = _array_from_npy_bytes(payload, *self._stored_header(key, payload))
            else:
                with self.zf.open(self.members[key]) as fp:
                    # Reading to the member's end makes zipfile verify its CRC-32.
                    arr = np.lib.format.read_array(fp, allow_pickle=False)
                    if fp.read(1):
                        raise ValueError("trailing bytes after the array data")
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
            raise EpisodeFormatError(
                self.path, f"key {key!r} cannot be read (corrupt or truncated?): {exc}"
            ) from exc
        return arr

    def checked_headers(self) -> int:
        """Check every key's dtype/shape from the array headers; return the step count."""
        lengths: dict[str, int] = {}
        for key, spec in self.schema.items():
            shape, dtype = self.header(key)
            if dtype.hasobject:
                raise EpisodeFormatError(
                    self.path,
                    f"key {key!r} holds Python objects (dtype {dtype}); expected {spec.dtype_text()}",
                )
            t = check_array(key, dtype, shape, self.path, self.schema)
            if t is not None:
                lengths[key] = t
        length = int(self.array("episode_length")) if "episode_length" in self.schema else None
        return check_lengths(lengths, length, self.path)

    def close(self) -> None:
        """Close the zip file (arrays already read stay valid)."""
        self.zf.close()


def read_episode(
    path: str | os.PathLike[str],
    *,
    validate: bool = False,
    max_episode_steps: int | None = None,
) -> Episode:
    """Load one episode file, checking it against the schema.

    Raises :class:`EpisodeFormatError` naming ``path`` for a truncated or corrupt file
    (including a CRC mismatch in any array), a missing or unexpected key, or a wrong
    dtype or shape; ``FileNotFoundError`` if it does not exist. With ``validate`` the §3.1
    invariants are checked too (:func:`validate_episode`).
    """
    path = Path(path)
    archive = NpzArchive(path)
    try:
        archive.checked_headers()
        episode = {key: archive.array(key) for key in EPISODE_KEYS}
    finally:
        archive.close()
    if validate:
        validate_episode(episode, source=path, max_episode_steps=max_episode_steps)
    return episode


def is_rl_episode_file(path: str | os.PathLike[str]) -> bool:
    """Whether the NPZ file at ``path`` holds exactly the :data:`RL_SCHEMA` keys (the RL
    release's layout) rather than :data:`SCHEMA`'s; ``False`` for an unreadable file."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError):
        return False
    return sorted(names) == sorted(f"{k}.npy" for k in RL_EPISODE_KEYS)


def read_rl_episode(
    path: str | os.PathLike[str],
    *,
    validate: bool = False,
    max_episode_steps: int | None = None,
) -> Episode:
    """Load one RL episode file (:data:`RL_SCHEMA`), checking keys, dtypes and shapes
    (CRC-checked); with ``validate`` also :func:`validate_rl_episode`'s invariants."""
    path = Path(path)
    archive = NpzArchive(path, RL_SCHEMA)
    try:
        archive.checked_headers()
        episode = {key: archive.array(key) for key in RL_EPISODE_KEYS}
    finally:
        archive.close()
    if validate:
        validate_rl_episode(episode, source=path, max_episode_steps=max_episode_steps)
    return episode


def read_rl_episode_headers(path: str | os.PathLike[str]) -> int:
    """Check an RL episode file's keys, dtypes and shapes from the array headers only
    (frames not read); return its length ``T``."""
    archive = NpzArchive(Path(path), RL_SCHEMA)
    try:
        return archive.checked_headers()
    finally:
        archive.close()
