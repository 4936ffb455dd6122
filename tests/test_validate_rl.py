"""The RL release's NPZ schema (``mikasa_datasets.npz.RL_SCHEMA``) in the writer/reader and
in ``mikasa-datasets validate`` (numpy only: runs in the main environment)."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
from mikasa_datasets import cli
from mikasa_datasets.loaders import DatasetFormatError
from mikasa_datasets.npz import (
    RL_EPISODE_KEYS,
    EpisodeFormatError,
    EpisodeInvariantError,
    is_rl_episode_file,
    read_rl_episode,
    write_rl_episode,
)
from mikasa_datasets.validate import validate_path

ENV_ID = "RememberColor3-v0"
T = 60


def rl_episode(seed: int = 0, t: int = T) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    success = (np.arange(t) >= t // 2).astype(np.int64)
    return {
        "rgb": rng.integers(0, 256, (t, 128, 128, 6), dtype=np.uint8),
        "joints": rng.normal(size=(t, 25)).astype(np.float32),
        "action": rng.uniform(-1, 1, (t, 8)).astype(np.float32),
        "reward": rng.uniform(0, 1, t).astype(np.float32),
        "success": success,
        "done": (np.arange(t) == t - 1).astype(np.int64),
    }


def write_dir(root: Path, n: int = 3, **overrides) -> Path:
    directory = root / "MIKASA-Robo" / "unbatched" / ENV_ID
    for i in range(n):
        write_rl_episode(directory / f"train_data_{i}.npz", {**rl_episode(i), **overrides})
    return directory


def raw_savez(path: Path, **arrays) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return path


def test_writer_round_trip_and_byte_identical_files(tmp_path):
    ep = rl_episode()
    a = write_rl_episode(tmp_path / "a.npz", ep)
    b = write_rl_episode(tmp_path / "b.npz", ep)
    assert a.read_bytes() == b.read_bytes()
    with zipfile.ZipFile(a) as zf:  # numpy's savez: fixed zip timestamps, schema key order
        assert [i.date_time for i in zf.infolist()] == [(1980, 1, 1, 0, 0, 0)] * 6
        assert zf.namelist() == [f"{k}.npy" for k in RL_EPISODE_KEYS]
    back = read_rl_episode(a, validate=True)
    assert all(np.array_equal(back[k], ep[k]) and back[k].dtype == ep[k].dtype for k in ep)
    assert is_rl_episode_file(a) and not is_rl_episode_file(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "b.npz"]  # no temp files


def test_writer_refuses_wrong_dtypes_and_broken_invariants(tmp_path):
    with pytest.raises(EpisodeFormatError, match="key 'success' has dtype int32; expected int64"):
        write_rl_episode(tmp_path / "x.npz", {**rl_episode(), "success": np.zeros(T, np.int32)})
    with pytest.raises(EpisodeInvariantError, match="done is 1 at step 3 before the last step"):
        write_rl_episode(tmp_path / "x.npz", {**rl_episode(), "done": (np.arange(T) >= 3).astype(np.int64)})
    with pytest.raises(EpisodeFormatError, match="missing key"):
        write_rl_episode(tmp_path / "x.npz", {k: v for k, v in rl_episode().items() if k != "joints"})
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("quick", [False, True])
def test_validate_rl_directory_file_and_root(tmp_path, quick):
    directory = write_dir(tmp_path)
    for path, episodes in ((directory, 3), (directory / "train_data_1.npz", 1),
                           (tmp_path / "MIKASA-Robo", 3), (tmp_path / "MIKASA-Robo" / "unbatched", 3)):
        report = validate_path(path, quick=quick)
        assert (report.format, report.episodes, report.frames) == ("npz-rl", episodes, episodes * T)
    (tmp_path / "MIKASA-Robo" / f"summary_{ENV_ID}.json").write_text("{}")  # beside, ignored
    assert validate_path(tmp_path / "MIKASA-Robo", quick=quick).episodes == 3


def test_validate_names_the_first_problem(tmp_path):
    directory = write_dir(tmp_path)
    (directory / "train_data_1.npz").unlink()
    with pytest.raises(DatasetFormatError, match="train_data_1.npz: missing"):
        validate_path(directory)

    directory = write_dir(tmp_path / "lengths")
    write_rl_episode(directory / "train_data_2.npz", rl_episode(2, t=T - 1))
    with pytest.raises(DatasetFormatError, match="train_data_2.npz: has 59 steps but train_data_0.npz has 60"):
        validate_path(directory)

    directory = write_dir(tmp_path / "dtype")
    bad = {**rl_episode(1), "done": rl_episode(1)["done"].astype(np.int32)}
    raw_savez(directory / "train_data_1.npz", **bad)
    with pytest.raises(EpisodeFormatError, match="key 'done' has dtype int32; expected int64"):
        validate_path(directory, quick=True)

    directory = write_dir(tmp_path / "flags")
    raw_savez(directory / "train_data_0.npz", **{**rl_episode(0), "success": np.full(T, 2, np.int64)})
    with pytest.raises(EpisodeInvariantError, match="success holds values other than 0/1"):
        validate_path(directory)

    directory = write_dir(tmp_path / "mixed")
    raw_savez(directory / "train_data_2.npz", **{**rl_episode(2), "language_instruction": np.array("x")})
    with pytest.raises(EpisodeFormatError, match="unexpected key.*language_instruction"):
        validate_path(directory)


def test_cli_validate(tmp_path, capsys):
    directory = write_dir(tmp_path, n=2)
    assert cli.main(["validate", str(directory)]) == 0
    assert capsys.readouterr().out.startswith(f"OK npz-rl {directory}: 2 episodes, 120 frames")
    raw_savez(directory / "train_data_1.npz", **{**rl_episode(1), "reward": np.full(T, np.nan, np.float32)})
    assert cli.main(["validate", str(directory)]) == 1
    assert "INVALID" in capsys.readouterr().out
