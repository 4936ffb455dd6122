"""Check a dataset in any of the three formats against the schema; name the first problem.

:func:`validate_path` detects the format (NPZ task directory or file, a ``data_npz``
root of task directories, an RLDS task/version directory, a LeRobot v3 dataset root) and
checks keys, shapes, dtypes, counts and episode boundaries:

* NPZ (spec §2-§3): files numbered ``0..n-1``; every episode's schema and §3.1
  invariants; ``metadata.json`` keys, ``num_episodes``, per-episode lengths, seeds,
  ``success_once`` and reward sums agree with the files.
* RL NPZ (the RL release's ``MIKASA-Robo/unbatched/<env_id>/``, told apart by its keys:
  :data:`~mikasa_datasets.npz.RL_SCHEMA`): files numbered ``0..n-1``, every episode's
  keys/dtypes/shapes and invariants (``done`` only at the last step), one episode length
  (the task's horizon) across the directory; no ``metadata.json`` is expected.
* RLDS (spec §6): ``dataset_info.json`` (builder name, version, ``train`` split, shards
  present), ``features.json`` (every required feature with its dtype/shape), and per
  episode: step count, image/proprio/action shapes and dtypes, ``is_first`` only at step
  0, ``is_last`` only at the last step, ``is_terminal`` only there, one non-empty
  instruction, the metadata's episode length/index, shard example counts.
* LeRobot (spec §7): ``meta/info.json`` (``codebase_version`` v3.0, fps, required
  features), totals against the tables, contiguous episode ranges, per-frame
  ``frame_index``/``timestamp``/``episode_index``/``task_index``, 7-D finite
  state/action, and every video's frame count, size and time range per episode.

The first problem found is raised as :class:`~mikasa_datasets.conversion.DatasetFormatError`
(or the NPZ module's ``EpisodeFormatError``) whose message starts with the most specific
file at fault. ``quick=True`` skips decoding frame data (image/video payloads).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_datasets.conversion import DatasetFormatError, require
from mikasa_datasets.loaders import detect_format
from mikasa_datasets.npz import (
    METADATA_KEYS,
    EpisodeFormatError,
    is_rl_episode_file,
    list_episode_files,
    read_episode,
    read_episode_summary,
    read_metadata,
    read_rl_episode,
    read_rl_episode_headers,
    summarize_episode,
)

__all__ = ["ValidationReport", "validate_lerobot", "validate_npz", "validate_path", "validate_rlds"]


@dataclass
class ValidationReport:
    """A dataset that passed validation: its format, size and what was checked."""

    path: Path
    format: str
    episodes: int
    frames: int
    tasks: int = 1
    quick: bool = False

    def summary(self) -> str:
        """One line for the CLI."""
        depth = " (quick: frame data not decoded)" if self.quick else ""
        many = f", {self.tasks} tasks" if self.tasks != 1 else ""
        return f"OK {self.format} {self.path}: {self.episodes} episodes, {self.frames} frames{many}{depth}"


def validate_path(
    path: str | os.PathLike[str], fmt: str | None = None, *, quick: bool = False
) -> ValidationReport:
    """Validate the dataset at ``path`` (format auto-detected unless ``fmt`` is given).

    Returns a :class:`ValidationReport`; raises on the first problem (see module doc).
    """
    p = Path(path)
    if fmt is None and p.is_dir() and not (p / "meta").exists():
        # A root holding several tasks (data_npz/, data_rlds/, data_lerobot/): check each.
        subdirs = [
            c for c in sorted(p.iterdir()) if c.is_dir() and not c.name.startswith(("_", "."))
        ]
        if (
            subdirs
            and not list_episode_files(p)
            and not (p / "dataset_info.json").exists()
            and not any(_is_version(c.name) for c in subdirs)
        ):
            reports = [validate_path(c, quick=quick) for c in subdirs]
            return ValidationReport(
                p,
                "/".join(sorted({r.format for r in reports})),
                sum(r.episodes for r in reports),
                sum(r.frames for r in reports),
                tasks=len(reports),
                quick=quick,
            )
    fmt = fmt or detect_format(p)
    checker = {"npz": validate_npz, "rlds": validate_rlds, "lerobot": validate_lerobot}.get(fmt)
    if checker is None:
        raise ValueError(f"unknown format {fmt!r}")
    return checker(p, quick=quick)


def _is_version(name: str) -> bool:
    parts = name.split(".")
    return len(parts) == 3 and all(x.isdigit() for x in parts)


# --------------------------------------------------------------------------- NPZ
def validate_npz(path: str | os.PathLike[str], *, quick: bool = False) -> ValidationReport:
    """Validate one ``.npz`` episode file or an NPZ task directory with ``metadata.json``."""
    p = Path(path)
    if is_rl_episode_file(p) or (p.is_dir() and _is_rl_dir(p)):
        return _validate_rl_npz(p, quick=quick)
    if p.is_file():
        if quick:
            s = read_episode_summary(p)
            return ValidationReport(p, "npz", 1, s.episode_length, quick=True)
        ep = read_episode(p, validate=True)
        return ValidationReport(p, "npz", 1, int(ep["episode_length"]))
    files = list_episode_files(p)
    if not files:
        raise DatasetFormatError(p, "no train_data_<i>.npz episode files")
    for expected, f in enumerate(files):
        if f.name != f"train_data_{expected}.npz":
            raise DatasetFormatError(
                p / f"train_data_{expected}.npz",
                f"missing: episode files must be numbered 0..{len(files) - 1} without gaps",
            )
    summaries = []
    for f in files:
        if quick:
            summaries.append(read_episode_summary(f))
        else:
            summaries.append(summarize_episode(read_episode(f, validate=True), f))
    meta_path = p / "metadata.json"
    if not meta_path.is_file():
        raise DatasetFormatError(
            meta_path, "missing (spec §3.4: one metadata.json per task directory)"
        )
    meta = read_metadata(p)
    order = list(meta)[: len(METADATA_KEYS)]
    if order != list(METADATA_KEYS):
        raise DatasetFormatError(
            meta_path, f"keys are {list(meta)}; expected {list(METADATA_KEYS)} in this order"
        )
    if meta["num_episodes"] != len(files):
        raise DatasetFormatError(
            meta_path,
            f"num_episodes is {meta['num_episodes']} but there are {len(files)} episode files",
        )
    for key in ("episode_lengths", "success_once", "reward_sums", "episode_seeds"):
        if not isinstance(meta[key], list) or len(meta[key]) != len(files):
            raise DatasetFormatError(meta_path, f"{key} must be a list of {len(files)} entries")
    for i, s in enumerate(summaries):
        where = f"(train_data_{i}.npz)"
        if meta["episode_lengths"][i] != s.episode_length:
            raise DatasetFormatError(
                meta_path,
                f"episode_lengths[{i}] is {meta['episode_lengths'][i]} but the file has {s.episode_length} steps {where}",
            )
        if meta["episode_seeds"][i] not in (s.episode_seed, -1):
            raise DatasetFormatError(
                meta_path,
                f"episode_seeds[{i}] is {meta['episode_seeds'][i]} but the file's episode_seed is {s.episode_seed} {where}",
            )
        if meta["success_once"][i] is not True:
            raise DatasetFormatError(
                meta_path,
                f"success_once[{i}] is {meta['success_once'][i]!r}; only successful episodes are stored",
            )
        if not math.isclose(
            float(meta["reward_sums"][i]), s.reward_sum, rel_tol=1e-5, abs_tol=1e-4
        ):
            raise DatasetFormatError(
                meta_path,
                f"reward_sums[{i}] is {meta['reward_sums'][i]} but the file's rewards sum to {s.reward_sum:.6g} {where}",
            )
    return ValidationReport(
        p, "npz", len(files), sum(s.episode_length for s in summaries), quick=quick
    )


def _is_rl_dir(directory: Path) -> bool:
    files = list_episode_files(directory)
    return bool(files) and is_rl_episode_file(files[0])


def _rl_episode_length(f: Path, quick: bool) -> int:
    if quick:
        return read_rl_episode_headers(f)
    return int(read_rl_episode(f, validate=True)["reward"].shape[0])


def _validate_rl_npz(p: Path, *, quick: bool) -> ValidationReport:
    """An RL episode file, or an ``unbatched/<env_id>`` directory of them."""
    if p.is_file():
        return ValidationReport(p, "npz-rl", 1, _rl_episode_length(p, quick), quick=quick)
    files = list_episode_files(p)
    frames, horizon = 0, None
    for expected, f in enumerate(files):
        if f.name != f"train_data_{expected}.npz":
            raise DatasetFormatError(
                p / f"train_data_{expected}.npz",
                f"missing: episode files must be numbered 0..{len(files) - 1} without gaps",
            )
        if not is_rl_episode_file(f):
            read_rl_episode_headers(f)  # names the missing/extra keys (or the corruption)
        t = _rl_episode_length(f, quick)
        if horizon is not None and t != horizon:
            raise DatasetFormatError(
                f, f"has {t} steps but train_data_0.npz has {horizon}; every RL episode runs to the task's timeout"
            )
        horizon = t
        frames += t
    return ValidationReport(p, "npz-rl", len(files), frames, quick=quick)


# --------------------------------------------------------------------------- RLDS
# feature path -> (kind, dtype, shape); kind as in features.json ("Image", "Tensor", "Text").
_RLDS_REQUIRED: dict[str, tuple[str, str | None, tuple[int, ...] | None]] = {
    "steps/observation/image": ("Image", "uint8", (128, 128, 3)),
    "steps/observation/proprio": ("Tensor", "float32", (7,)),
    "steps/action": ("Tensor", "float32", (7,)),
    "steps/reward": ("Tensor", "float32", ()),
    "steps/discount": ("Tensor", "float32", ()),
    "steps/is_first": ("Tensor", "bool", ()),
    "steps/is_last": ("Tensor", "bool", ()),
    "steps/is_terminal": ("Tensor", "bool", ()),
    "steps/language_instruction": ("Text", None, None),
    "episode_metadata/file_path": ("Text", None, None),
}
_RLDS_OPTIONAL = {"steps/observation/wrist_image": ("Image", "uint8", (128, 128, 3))}


def _flat_features(features: Any, prefix: str = "") -> dict[str, Any]:
    """``{"steps/observation/image": <feature>, ...}`` of a TFDS FeaturesDict."""
    out: dict[str, Any] = {}
    for key, feat in features.items():
        name = f"{prefix}{key}"
        inner = getattr(feat, "feature", None)  # Dataset/Sequence wrap a FeaturesDict
        target = inner if inner is not None and hasattr(inner, "items") else feat
        if hasattr(target, "items") and not hasattr(target, "encoding_format"):
            out.update(_flat_features(target, name + "/"))
        else:
            out[name] = target
    return out


def _check_feature(
    path: Path, name: str, feat: Any, spec: tuple[str, str | None, tuple[int, ...] | None]
) -> None:
    kind, dtype, shape = spec
    cls = type(feat).__name__
    if kind == "Image" and cls != "Image":
        raise DatasetFormatError(path, f"feature {name} is a {cls}; expected an Image")
    if kind == "Text" and cls != "Text":
        raise DatasetFormatError(path, f"feature {name} is a {cls}; expected Text")
    if kind == "Tensor" and cls not in ("Tensor", "Scalar"):
        raise DatasetFormatError(path, f"feature {name} is a {cls}; expected a Tensor")
    if dtype is not None and np.dtype(feat.np_dtype) != np.dtype(dtype):
        raise DatasetFormatError(
            path, f"feature {name} has dtype {np.dtype(feat.np_dtype)}; expected {dtype}"
        )
    if shape is not None and tuple(feat.shape) != shape:
        raise DatasetFormatError(
            path, f"feature {name} has shape {tuple(feat.shape)}; expected {shape}"
        )


def validate_rlds(path: str | os.PathLike[str], *, quick: bool = False) -> ValidationReport:
    """Validate an RLDS task directory (latest version) or version directory."""
    from mikasa_datasets import rlds

    vdir = rlds.find_version_dir(path)
    info_path = vdir / "dataset_info.json"
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetFormatError(info_path, f"unreadable: {exc}") from exc
    if info.get("name") != rlds.BUILDER_NAME:
        raise DatasetFormatError(
            info_path, f"name is {info.get('name')!r}; expected {rlds.BUILDER_NAME!r}"
        )
    if info.get("version") != vdir.name:
        raise DatasetFormatError(
            info_path, f"version is {info.get('version')!r} but the directory is {vdir.name!r}"
        )
    shards = rlds.shard_files(vdir)  # names a missing shard
    lengths = next(s["shardLengths"] for s in info["splits"] if s.get("name") == rlds.SPLIT)
    shard_lengths = {f: int(n) for f, n in zip(shards, lengths, strict=True)}
    total = sum(shard_lengths.values())
    if total == 0:
        raise DatasetFormatError(info_path, "the train split has no episodes")

    tfds = rlds.import_tfds()
    features_path = vdir / "features.json"
    if not features_path.is_file():
        raise DatasetFormatError(features_path, "missing")
    try:
        features = tfds.features.FeaturesDict.from_config(str(vdir))
    except Exception as exc:
        raise DatasetFormatError(features_path, f"cannot be loaded: {exc}") from exc
    flat = _flat_features(features)
    for name, spec in _RLDS_REQUIRED.items():
        if name not in flat:
            raise DatasetFormatError(features_path, f"required feature {name} is missing")
        _check_feature(features_path, name, flat[name], spec)
    for name, spec in _RLDS_OPTIONAL.items():
        if name in flat:
            _check_feature(features_path, name, flat[name], spec)

    meta: dict[str, Any] = {}
    meta_path = vdir / "metadata.json"
    if meta_path.is_file():
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise DatasetFormatError(meta_path, f"not valid JSON: {exc}") from exc
        if int(meta.get("num_episodes", total)) < total:
            raise DatasetFormatError(
                meta_path,
                f"num_episodes is {meta.get('num_episodes')} but the shards hold {total} episodes",
            )

    if quick:
        frames = sum(int(x) for x in meta.get("episode_lengths", [])[:total]) if meta else 0
        return ValidationReport(vdir, "rlds", total, frames, quick=True)

    frames = 0
    seen: dict[Path, int] = dict.fromkeys(shards, 0)
    for number, (shard, steps, metadata) in enumerate(rlds.iter_examples(vdir)):
        seen[shard] += 1
        t = _check_rlds_episode(
            shard, number, steps, metadata, "steps/observation/wrist_image" in flat
        )
        lengths_meta = meta.get("episode_lengths")
        index = int(metadata.get("episode_index", number))
        if lengths_meta is not None and index < len(lengths_meta) and int(lengths_meta[index]) != t:
            raise DatasetFormatError(
                shard,
                f"episode {number} has {t} steps but metadata.json episode_lengths[{index}] is {lengths_meta[index]}",
            )
        frames += t
    for shard, n in seen.items():
        if n != shard_lengths[shard]:
            raise DatasetFormatError(
                shard, f"holds {n} episodes; dataset_info.json says {shard_lengths[shard]}"
            )
    return ValidationReport(vdir, "rlds", total, frames)


def _check_rlds_episode(
    shard: Path, number: int, steps: dict[str, Any], metadata: dict[str, Any], wrist: bool
) -> int:
    """Check one decoded RLDS episode; return its step count."""
    where = f"episode {number}"

    def fail(problem: str) -> None:
        raise DatasetFormatError(shard, f"{where}: {problem}")

    obs = steps["observation"]
    t = len(steps["is_first"])
    if t == 0:
        fail("has no steps")
    arrays = {
        "observation/image": (obs["image"], np.uint8, (t, 128, 128, 3)),
        "observation/proprio": (obs["proprio"], np.float32, (t, 7)),
        "action": (steps["action"], np.float32, (t, 7)),
        "reward": (steps["reward"], np.float32, (t,)),
        "discount": (steps["discount"], np.float32, (t,)),
    }
    if wrist:
        arrays["observation/wrist_image"] = (obs["wrist_image"], np.uint8, (t, 128, 128, 3))
    for name, (arr, dtype, shape) in arrays.items():
        arr = np.asarray(arr)
        if arr.dtype != dtype:
            fail(f"steps/{name} has dtype {arr.dtype}; expected {np.dtype(dtype)}")
        if arr.shape != shape:
            fail(f"steps/{name} has shape {arr.shape}; expected {shape}")
    for name in ("observation/proprio", "action", "reward", "discount"):
        if not np.isfinite(arrays[name][0]).all():
            fail(f"steps/{name} contains NaN or infinite values")
    first, last, terminal = (
        np.asarray(steps[k], dtype=bool) for k in ("is_first", "is_last", "is_terminal")
    )
    expected_first = np.arange(t) == 0
    if not np.array_equal(first, expected_first):
        fail(
            f"is_first must be true exactly at step 0; it is true at steps {np.flatnonzero(first).tolist()}"
        )
    expected_last = np.arange(t) == t - 1
    if not np.array_equal(last, expected_last):
        fail(
            f"is_last must be true exactly at the last step {t - 1}; it is true at steps {np.flatnonzero(last).tolist()}"
        )
    if (terminal & ~expected_last).any():
        fail(
            f"is_terminal is true before the last step (at {np.flatnonzero(terminal & ~expected_last).tolist()})"
        )
    texts = set(np.asarray(steps["language_instruction"]).tolist())
    if len(texts) != 1:
        fail(f"language_instruction changes within the episode ({len(texts)} distinct values)")
    if not str(next(iter(texts))).strip():
        fail("language_instruction is empty")
    if "episode_length" in metadata and int(metadata["episode_length"]) != t:
        fail(
            f"episode_metadata/episode_length is {int(metadata['episode_length'])} but the episode has {t} steps"
        )
    if "episode_index" in metadata and int(metadata["episode_index"]) != number:
        fail(
            f"episode_metadata/episode_index is {int(metadata['episode_index'])}; expected {number} (stored order)"
        )
    return t


# --------------------------------------------------------------------------- LeRobot
_LEROBOT_REQUIRED: dict[str, tuple[tuple[str, ...], tuple[int, ...]]] = {
    "observation.images.top": (("video", "image"), (128, 128, 3)),
    "observation.state": (("float32",), (7,)),
    "action": (("float32",), (7,)),
}
_LEROBOT_OPTIONAL = {
    "observation.images.wrist": (("video", "image"), (128, 128, 3)),
    "next.reward": (("float32",), (1,)),
    "next.success": (("bool",), (1,)),
    "next.done": (("bool",), (1,)),
}


def validate_lerobot(path: str | os.PathLike[str], *, quick: bool = False) -> ValidationReport:
    """Validate a LeRobot v3 dataset root (the directory holding ``meta/info.json``)."""
    from mikasa_datasets import lerobot

    root = Path(path)
    info_path = root / "meta" / "info.json"
    info = lerobot.read_info(root)
    if info.get("codebase_version") != "v3.0":
        raise DatasetFormatError(
            info_path, f"codebase_version is {info.get('codebase_version')!r}; expected 'v3.0'"
        )
    fps = info.get("fps")
    if not isinstance(fps, int) or fps <= 0:
        raise DatasetFormatError(info_path, f"fps is {fps!r}; expected a positive integer")
    features = info.get("features", {})
    for name, (dtypes, shape) in {**_LEROBOT_REQUIRED, **_LEROBOT_OPTIONAL}.items():
        if name not in features:
            if name in _LEROBOT_REQUIRED:
                raise DatasetFormatError(info_path, f"required feature {name!r} is missing")
            continue
        ft = features[name]
        if ft.get("dtype") not in dtypes:
            raise DatasetFormatError(
                info_path,
                f"feature {name!r} has dtype {ft.get('dtype')!r}; expected one of {list(dtypes)}",
            )
        if tuple(ft.get("shape", ())) != shape:
            raise DatasetFormatError(
                info_path,
                f"feature {name!r} has shape {list(ft.get('shape', ()))}; expected {list(shape)}",
            )
    if not (root / "meta" / "stats.json").is_file():
        raise DatasetFormatError(root / "meta" / "stats.json", "missing")

    _, episodes, frames, tasks = lerobot.read_tables(root)
    ep_path = root / "meta" / "episodes"
    data_path = root / "data"
    n_eps, n_frames = len(episodes), len(frames)
    if info.get("total_episodes") != n_eps:
        raise DatasetFormatError(
            info_path,
            f"total_episodes is {info.get('total_episodes')} but meta/episodes lists {n_eps}",
        )
    if info.get("total_frames") != n_frames:
        raise DatasetFormatError(
            info_path,
            f"total_frames is {info.get('total_frames')} but the data files hold {n_frames} frames",
        )
    if info.get("total_tasks") != len(tasks):
        raise DatasetFormatError(
            info_path,
            f"total_tasks is {info.get('total_tasks')} but meta/tasks.parquet lists {len(tasks)}",
        )
    if not np.array_equal(episodes["episode_index"].to_numpy(), np.arange(n_eps)):
        raise DatasetFormatError(ep_path, "episode_index values are not 0..N-1")
    if not np.array_equal(frames["index"].to_numpy(), np.arange(n_frames)):
        raise DatasetFormatError(data_path, "frame index column is not 0..total_frames-1")

    video_keys = [k for k, ft in features.items() if ft.get("dtype") == "video"]
    state = np.stack(frames["observation.state"].to_numpy()) if n_frames else np.zeros((0, 7))
    action = np.stack(frames["action"].to_numpy()) if n_frames else np.zeros((0, 7))
    if state.shape[1:] != (7,) or action.shape[1:] != (7,):
        raise DatasetFormatError(
            data_path,
            f"observation.state/action rows have shapes {state.shape[1:]}/{action.shape[1:]}; expected (7,)",
        )
    if not (np.isfinite(state).all() and np.isfinite(action).all()):
        raise DatasetFormatError(
            data_path, "observation.state or action contains NaN or infinite values"
        )

    ep_of_row = frames["episode_index"].to_numpy()
    frame_index = frames["frame_index"].to_numpy()
    timestamps = frames["timestamp"].to_numpy()
    task_index = frames["task_index"].to_numpy()
    start = 0
    for i, ep in episodes.iterrows():
        length = int(ep["length"])
        lo, hi = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
        where = f"episode {i}"
        if length <= 0:
            raise DatasetFormatError(ep_path, f"{where} has length {length}")
        if lo != start or hi - lo != length:
            raise DatasetFormatError(
                ep_path,
                f"{where} spans frames [{lo}, {hi}) with length {length}; expected [{start}, {start + length})",
            )
        rows = slice(lo, hi)
        if not (ep_of_row[rows] == i).all():
            raise DatasetFormatError(
                data_path,
                f"{where}: frames {lo}..{hi - 1} carry episode_index {sorted(set(ep_of_row[rows].tolist()))}",
            )
        if not np.array_equal(frame_index[rows], np.arange(length)):
            raise DatasetFormatError(data_path, f"{where}: frame_index is not 0..{length - 1}")
        if not np.allclose(timestamps[rows], np.arange(length) / fps, atol=1e-4):
            raise DatasetFormatError(
                data_path, f"{where}: timestamps are not frame_index / fps ({fps})"
            )
        bad_tasks = set(task_index[rows].tolist()) - set(tasks)
        if bad_tasks:
            raise DatasetFormatError(
                data_path, f"{where}: task_index {sorted(bad_tasks)} not in meta/tasks.parquet"
            )
        for key in video_keys:
            f0, f1 = (
                float(ep[f"videos/{key}/from_timestamp"]),
                float(ep[f"videos/{key}/to_timestamp"]),
            )
            if abs((f1 - f0) - length / fps) > 1.5 / fps:
                raise DatasetFormatError(
                    ep_path,
                    f"{where}: {key} covers {f1 - f0:.3f}s of video for {length} frames at {fps} fps",
                )
        start = hi
    if not quick:
        _check_videos(root, info, episodes, video_keys)
    return ValidationReport(root, "lerobot", n_eps, n_frames, quick=quick)


def _check_videos(root: Path, info: dict[str, Any], episodes: Any, video_keys: list[str]) -> None:
    """Every video file decodes, is 128x128 and holds exactly its episodes' frames."""
    av = require("av", "lerobot")
    for key in video_keys:
        expected: dict[Path, int] = {}
        for _, ep in episodes.iterrows():
            path = root / info["video_path"].format(
                video_key=key,
                chunk_index=int(ep[f"videos/{key}/chunk_index"]),
                file_index=int(ep[f"videos/{key}/file_index"]),
            )
            expected[path] = expected.get(path, 0) + int(ep["length"])
        for path, n in expected.items():
            if not path.is_file():
                raise DatasetFormatError(path, "video file listed in meta/episodes is missing")
            count = 0
            try:
                with av.open(str(path)) as container:
                    stream = container.streams.video[0]
                    if (stream.codec_context.height, stream.codec_context.width) != (128, 128):
                        raise DatasetFormatError(
                            path,
                            f"video is {stream.codec_context.width}x{stream.codec_context.height}; expected 128x128",
                        )
                    for _ in container.decode(stream):
                        count += 1
            except DatasetFormatError:
                raise
            except Exception as exc:
                raise DatasetFormatError(
                    path,
                    f"video cannot be decoded (corrupt or truncated?) after {count} frames: {exc}",
                ) from exc
            if count != n:
                raise DatasetFormatError(path, f"video holds {count} frames; its episodes have {n}")


# Re-exported so callers can catch both error types from one place.
ValidationError = (DatasetFormatError, EpisodeFormatError)
