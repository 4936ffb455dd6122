"""mikasa_datasets: the dataset-name helper (spec §1) and the NPZ episode format (§2-§3)."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
from mikasa_datasets import env_id_to_dataset_name, is_dataset_name, npz
from mikasa_datasets.npz import (
    EPISODE_KEYS,
    METADATA_KEYS,
    EpisodeFormatError,
    EpisodeInvariantError,
    list_episode_files,
    make_episode,
    read_episode,
    read_episode_summary,
    read_metadata,
    remove_stale_temp_files,
    summarize_directory,
    summarize_episode,
    validate_episode,
    write_episode,
    write_metadata,
)

# --------------------------------------------------------------------------- naming (§1)
SPEC_NAME_TABLE = [
    ("RememberColor3-VLA-v0", "remember_color_3_vla_v0"),
    ("BatteriesCheckerHard-3-VLA-v0", "batteries_checker_hard_3_vla_v0"),
    ("BatteriesCheckerEasy-12-VLA-v0", "batteries_checker_easy_12_vla_v0"),
    ("RememberShapeAndColor3x2-Long-VLA-v0", "remember_shape_and_color_3x2_long_vla_v0"),
    ("FindImposterShapeAndColor5x3-VLA-v0", "find_imposter_shape_and_color_5x3_vla_v0"),
    ("ShellGameTouch-VLA-v0", "shell_game_touch_vla_v0"),
    (
        "ShellGameShuffleColorLampTouch-Long-VLA-v0",
        "shell_game_shuffle_color_lamp_touch_long_vla_v0",
    ),
    ("GatherAndRecall1-VLA-v0", "gather_and_recall_1_vla_v0"),
    ("TraceShapeSeqHard-VLA-v0", "trace_shape_seq_hard_vla_v0"),
    ("ShellGameTouch-v0", "shell_game_touch_v0"),
    ("remember_color_3_vla_v0", "remember_color_3_vla_v0"),
    ("Remember9Colors-VLA-v1", "remember_9colors_vla_v1"),
    ("Abc3Def4-v0", "abc_3def_4_v0"),
    ("Task--A-v0", "task_a_v0"),
    ("Foo_Bar-v0", "foo_bar_v0"),
    ("", ""),
    # Rule illustrations from §1.2 (b) and (c).
    ("HTTPServer", "http_server"),
    ("ABCTest", "abc_test"),
    ("Ab3", "ab_3"),
    ("X3", "x3"),
    ("V2A", "v2a"),
    ("3x2", "3x2"),
]


@pytest.mark.parametrize("env_id, name", SPEC_NAME_TABLE)
def test_env_id_to_dataset_name_spec_table(env_id, name):
    assert env_id_to_dataset_name(env_id) == name
    # Idempotent: a dataset name maps to itself.
    assert env_id_to_dataset_name(name) == name


@pytest.mark.parametrize(
    "value, expected",
    [
        ("remember_color_3_vla_v0", True),
        ("abc", True),
        ("_0_", True),
        ("", False),
        ("RememberColor3-VLA-v0", False),
        ("remember-color", False),
        ("Remember_color", False),
        ("remember color", False),
    ],
)
def test_is_dataset_name(value, expected):
    assert is_dataset_name(value) is expected


def test_every_registered_task_has_a_valid_distinct_dataset_name():
    from mikasa_envs.manifest import list_tasks

    ids = [t.env_id for t in list_tasks(include_extra=True)]
    names = [env_id_to_dataset_name(i) for i in ids]
    assert all(is_dataset_name(n) for n in names)
    assert len(set(names)) == len(names)


# --------------------------------------------------------------------------- helpers
def synthetic(t: int = 12, seed: int = 7, language: str = "Touch the red cube.") -> dict:
    """A valid episode of ``t`` steps with random content."""
    rng = np.random.default_rng(seed)
    done = np.zeros(t, dtype=np.int32)
    done[-1] = 1
    return make_episode(
        rgb=rng.integers(0, 256, (t, 128, 128, 6), dtype=np.uint8),
        proprio=rng.normal(size=(t, 7)),
        action=rng.uniform(-1.5, 1.5, size=(t, 7)),  # make_episode clips
        reward=rng.uniform(0, 1, size=t),
        success=done.copy(),
        done=done,
        language_instruction=language,
        episode_seed=seed,
    )


def save_raw(path: Path, arrays: dict) -> Path:
    """Write arrays with plain numpy (bypassing the checks of write_episode)."""
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    return path


# --------------------------------------------------------------------------- round trip
def test_schema_table_matches_spec():
    expected = {
        "rgb": ("uint8", "(T, 128, 128, 6)"),
        "proprio": ("float32", "(T, 7)"),
        "action": ("float32", "(T, 7)"),
        "reward": ("float32", "(T,)"),
        "success": ("int32", "(T,)"),
        "done": ("int32", "(T,)"),
        "language_instruction": ("unicode string (<U…)", "()"),
        "success_once": ("bool", "()"),
        "episode_length": ("int32", "()"),
        "episode_seed": ("int64", "()"),
    }
    assert {k: (s.dtype_text(), s.shape_text()) for k, s in npz.SCHEMA.items()} == expected
    assert npz.DATA_NPZ_DIRNAME == "data_npz" and npz.BATCHED_TMP_SUBDIR == "_batched"


def test_round_trip(tmp_path):
    ep = synthetic(t=12)
    path = write_episode(tmp_path / "train_data_0.npz", ep)
    back = read_episode(path, validate=True)
    assert list(back) == list(EPISODE_KEYS)
    for key in EPISODE_KEYS:
        assert back[key].dtype == ep[key].dtype, key
        assert back[key].shape == ep[key].shape, key
        np.testing.assert_array_equal(back[key], ep[key])
    assert (
        back["language_instruction"].shape == () and back["language_instruction"].dtype.kind == "U"
    )
    assert str(back["language_instruction"]) == "Touch the red cube."
    assert int(back["episode_length"]) == 12 and int(back["episode_seed"]) == 7
    assert bool(back["success_once"]) is True
    assert np.abs(back["action"]).max() <= 1.0
    # A plain numpy reader needs no allow_pickle; members are in schema order.
    with np.load(path) as plain:
        assert list(plain.files) == list(EPISODE_KEYS)
    # Writing the same episode again gives the same bytes.
    again = write_episode(tmp_path / "again.npz", ep)
    assert again.read_bytes() == path.read_bytes()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_summary_matches_full_read(tmp_path):
    ep = synthetic(t=9, seed=3)
    path = write_episode(tmp_path / "train_data_0.npz", ep)
    s = read_episode_summary(path)
    assert s == summarize_episode(ep, path)
    assert (s.episode_length, s.episode_seed, s.success_once) == (9, 3, True)
    assert s.reward_sum == pytest.approx(float(ep["reward"].astype(np.float64).sum()))


# --------------------------------------------------------------------------- corruption
def _corrupt_cases(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, fragment the error message must contain)."""
    good = write_episode(tmp_path / "good.npz", synthetic())
    data = good.read_bytes()
    cases: dict[str, tuple[Path, str]] = {}

    def raw(name: str, mutate) -> Path:
        arrays = dict(synthetic())
        mutate(arrays)
        return save_raw(tmp_path / f"{name}.npz", arrays)

    p = tmp_path / "truncated.npz"
    p.write_bytes(data[: len(data) // 2])
    cases["truncated"] = (p, "truncated or corrupt")
    p = tmp_path / "truncated_tail.npz"
    p.write_bytes(data[:-10])
    cases["truncated_tail"] = (p, "truncated or corrupt")
    p = tmp_path / "empty.npz"
    p.write_bytes(b"")
    cases["empty"] = (p, "truncated or corrupt")
    p = tmp_path / "garbage.npz"
    p.write_bytes(b"this is not a zip archive" * 10)
    cases["garbage"] = (p, "truncated or corrupt")
    # One flipped byte inside the frame data: caught by the zip CRC.
    flipped = bytearray(data)
    with zipfile.ZipFile(good) as zf:
        info = zf.getinfo("rgb.npy")
    flipped[info.header_offset + 30 + len("rgb.npy") + 20 + 5000] ^= 0xFF
    p = tmp_path / "bitflip.npz"
    p.write_bytes(bytes(flipped))
    cases["bitflip"] = (p, "'rgb' cannot be read")

    cases["missing_key"] = (raw("missing_key", lambda a: a.pop("done")), "missing key(s) 'done'")
    cases["extra_key"] = (
        raw("extra_key", lambda a: a.update(state=np.zeros(3))),
        "unexpected key(s) 'state'",
    )
    cases["reward_dtype"] = (
        raw("reward_dtype", lambda a: a.update(reward=a["reward"].astype(np.float64))),
        "key 'reward' has dtype float64; expected float32",
    )
    cases["rgb_dtype"] = (
        raw("rgb_dtype", lambda a: a.update(rgb=a["rgb"].astype(np.float32) / 255)),
        "key 'rgb' has dtype float32; expected uint8",
    )
    cases["seed_dtype"] = (
        raw("seed_dtype", lambda a: a.update(episode_seed=np.array(3, dtype=np.int32))),
        "key 'episode_seed' has dtype int32; expected int64",
    )
    cases["language_bytes"] = (
        raw("language_bytes", lambda a: a.update(language_instruction=np.array(b"touch"))),
        "key 'language_instruction' has dtype",
    )
    cases["rgb_shape"] = (
        raw("rgb_shape", lambda a: a.update(rgb=a["rgb"][:, :64])),
        "key 'rgb' has shape (12, 64, 128, 6); expected (T, 128, 128, 6)",
    )
    cases["proprio_shape"] = (
        raw("proprio_shape", lambda a: a.update(proprio=a["proprio"][:, :6])),
        "key 'proprio' has shape (12, 6); expected (T, 7)",
    )
    cases["scalar_shape"] = (
        raw("scalar_shape", lambda a: a.update(episode_length=np.array([12], dtype=np.int32))),
        "key 'episode_length' has shape (1,); expected ()",
    )
    cases["ragged"] = (
        raw("ragged", lambda a: a.update(reward=a["reward"][:-1])),
        "per-step arrays disagree",
    )
    cases["length_value"] = (
        raw("length_value", lambda a: a.update(episode_length=np.array(11, dtype=np.int32))),
        "episode_length is 11",
    )
    cases["object_array"] = (
        raw("object_array", lambda a: a.update(success_once=np.array({"x": 1}, dtype=object))),
        "holds Python objects",
    )
    p = tmp_path / "single_npy.npz"
    buffer = io.BytesIO()
    np.save(buffer, np.zeros(3))
    p.write_bytes(buffer.getvalue())
    cases["single_npy"] = (p, "truncated or corrupt")
    return cases


def test_every_corruption_is_an_error_naming_the_file(tmp_path):
    for name, (path, fragment) in _corrupt_cases(tmp_path).items():
        with pytest.raises(EpisodeFormatError) as info:
            read_episode(path)
        message = str(info.value)
        assert message.startswith(str(path)), (name, message)
        assert fragment in message, (name, message)
        assert info.value.path == path
        # The cheap check used on resume rejects the same files, except damage inside
        # the frame data, which only the full read verifies.
        if name != "bitflip":
            with pytest.raises(EpisodeFormatError, match=str(path)):
                read_episode_summary(path)


def test_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="train_data_5.npz"):
        read_episode(tmp_path / "train_data_5.npz")


# --------------------------------------------------------------------------- invariants
def _broken(kind: str) -> dict:
    ep = synthetic(t=12)
    if kind == "early_done":
        ep["done"][4] = 1
    elif kind == "last_not_done":
        ep["done"][-1] = 0
        ep["success"][-1] = 0
    elif kind == "no_final_success":
        ep["success"][-1] = 0
    elif kind == "success_once_false":
        ep["success_once"] = np.array(False)
    elif kind == "done_values":
        ep["done"][-1] = 2
    elif kind == "action_range":
        ep["action"][0, 0] = 1.5
    elif kind == "nan_proprio":
        ep["proprio"][3, 2] = np.nan
    elif kind == "empty_language":
        ep["language_instruction"] = np.array("")
    return ep


@pytest.mark.parametrize(
    "kind, fragment",
    [
        ("early_done", "done is 1 at step 4"),
        ("last_not_done", "done[T-1] is 0"),
        ("no_final_success", "success[T-1] is 0"),
        ("success_once_false", "success_once is False"),
        ("done_values", "values other than 0/1"),
        ("action_range", "action leaves [-1, 1]"),
        ("nan_proprio", "proprio contains NaN"),
        ("empty_language", "language_instruction is empty"),
    ],
)
def test_validate_episode_invariants(tmp_path, kind, fragment):
    ep = _broken(kind)
    with pytest.raises(
        EpisodeInvariantError, match=fragment.replace("[", r"\[").replace("]", r"\]")
    ):
        validate_episode(ep)
    # write_episode validates: nothing (not even a temporary file) is left behind.
    target = tmp_path / "train_data_0.npz"
    with pytest.raises(EpisodeInvariantError, match=str(target)):
        write_episode(target, ep)
    assert list(tmp_path.iterdir()) == []
    # A file written without validation is readable, and read_episode(validate=True)
    # reports the broken invariant with the file name.
    write_episode(target, ep, validate=False)
    read_episode(target)
    with pytest.raises(EpisodeInvariantError, match=str(target)):
        read_episode(target, validate=True)


def test_length_bounds():
    ep = synthetic(t=12)
    assert validate_episode(ep, max_episode_steps=12, min_length=12) == 12
    with pytest.raises(EpisodeInvariantError, match="at most 11"):
        validate_episode(ep, max_episode_steps=11)
    with pytest.raises(EpisodeInvariantError, match="at least 13"):
        validate_episode(ep, min_length=13)


def test_check_schema_rejects_wrong_in_memory_types():
    ep = synthetic()
    ep["reward"] = ep["reward"].tolist()
    with pytest.raises(EpisodeFormatError, match="'reward' is a list"):
        validate_episode(ep)


# --------------------------------------------------------------------------- atomicity
def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    target = tmp_path / "train_data_0.npz"

    def exploding_savez(f, **arrays):
        f.write(b"PK\x03\x04 partial")  # some bytes reach the temporary file
        raise KeyboardInterrupt

    monkeypatch.setattr(npz.np, "savez", exploding_savez)
    with pytest.raises(KeyboardInterrupt):
        write_episode(target, synthetic())
    assert list(tmp_path.iterdir()) == []


def test_list_episode_files_sorts_numerically_and_skips_other_names(tmp_path):
    for i in (10, 2, 0, 1, 33):
        (tmp_path / f"train_data_{i}.npz").write_bytes(b"")
    for other in (
        ".train_data_3.npz.123.abcd.tmp",
        "train_data_x.npz",
        "train_data_4.npz.tmp",
        "train_data_05b.npz",
        "metadata.json",
        "train_data_batch_0.npz",
    ):
        (tmp_path / other).write_bytes(b"")
    assert [p.name for p in list_episode_files(tmp_path)] == [
        f"train_data_{i}.npz" for i in (0, 1, 2, 10, 33)
    ]
    assert list_episode_files(tmp_path / "missing") == []
    removed = remove_stale_temp_files(tmp_path)
    assert [p.name for p in removed] == [".train_data_3.npz.123.abcd.tmp"]


def test_summarize_directory_reports_a_hole(tmp_path):
    for i in (0, 2):
        write_episode(tmp_path / f"train_data_{i}.npz", synthetic(seed=i))
    with pytest.raises(EpisodeFormatError, match="train_data_1.npz is missing"):
        summarize_directory(tmp_path)


# --------------------------------------------------------------------------- metadata
def test_metadata(tmp_path):
    directory = tmp_path / "données" / "data_npz" / "remember_color_3_vla_v0"
    paths = []
    for i, t in enumerate((10, 14)):
        paths.append(write_episode(directory / f"train_data_{i}.npz", synthetic(t=t, seed=100 + i)))
    summaries = summarize_directory(directory)
    path = write_metadata(directory, "RememberColor3-VLA-v0", summaries)
    text = path.read_text(encoding="utf-8")
    assert "données" in text  # ensure_ascii=False
    meta = json.loads(text)
    assert tuple(meta) == METADATA_KEYS
    assert meta["env_id"] == "RememberColor3-VLA-v0"
    assert meta["num_episodes"] == 2
    assert meta["episode_lengths"] == [10, 14]
    assert meta["success_once"] == [True, True]
    assert meta["episode_seeds"] == [100, 101]
    for got, p in zip(meta["reward_sums"], paths, strict=True):
        assert got == pytest.approx(float(read_episode(p)["reward"].astype(np.float64).sum()))
    assert meta["unbatched_dir"] == str(directory)
    assert meta["batched_source_dir"] == str(directory.parent / "_batched" / directory.name)
    assert text == json.dumps(meta, ensure_ascii=False, indent=2) + "\n"
    assert read_metadata(directory) == meta
    assert not [p for p in directory.iterdir() if p.name.endswith(".tmp")]
    (directory / "metadata.json").write_text('{"env_id": "x"}')
    with pytest.raises(ValueError, match="metadata.json: missing key"):
        read_metadata(directory)
