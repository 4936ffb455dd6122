"""`mikasa-datasets validate` and the shared machinery behind the dataset-format tests.

The RLDS and LeRobot tests need tensorflow / lerobot, which live in the separate
conversion environment `.venv-datasets` (scripts/setup_datasets_envs.sh; see the
mikasa-datasets README for why). Each of test_rlds.py, test_lerobot.py and this file
therefore has two faces:

* inside `.venv-datasets` (tensorflow_datasets importable) it defines the real tests;
* in the main environment it defines one test that makes sure `.venv-datasets` exists
  (running the idempotent setup script under a file lock, so parallel xdist workers do not
  race) and runs the same file there with pytest, failing with the inner output if any
  inner test fails.

So the default `pytest -n auto` of the main suite runs every dataset test; nothing is
skipped. Tests that need only numpy (NPZ validation, CLI plumbing) run directly in both.
"""

from __future__ import annotations

import fcntl
import hashlib
import importlib.util
import json
import os
import re
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
import tomllib
from mikasa_datasets import cli
from mikasa_datasets.loaders import DatasetFormatError, detect_format, write_synthetic_task
from mikasa_datasets.npz import EpisodeFormatError, read_episode, write_episode
from mikasa_datasets.validate import validate_path

REPO = Path(__file__).resolve().parents[1]
DATASETS_VENV = Path(os.environ.get("MIKASA_DATASETS_VENV", REPO / ".venv-datasets"))
IN_DATASETS_ENV = importlib.util.find_spec("tensorflow_datasets") is not None
ENV_ID = "RememberColor3-VLA-v0"
NAME = "remember_color_3_vla_v0"


# --------------------------------------------------------------------------- the launcher
def datasets_python() -> Path:
    """`.venv-datasets/bin/python`, creating/refreshing the environment first."""
    # In the temp dir, not the checkout: the lock file must not show up in `git status`.
    key = hashlib.sha1(str(DATASETS_VENV).encode()).hexdigest()[:12]
    lock_path = Path(tempfile.gettempdir()) / f"mikasa-datasets-setup-{key}.lock"
    with open(lock_path, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one setup at a time across xdist workers
        proc = subprocess.run(
            ["bash", str(REPO / "scripts" / "setup_datasets_envs.sh")],
            cwd=REPO,
            env={**os.environ, "MIKASA_DATASETS_VENV": str(DATASETS_VENV)},
            capture_output=True,
            text=True,
            timeout=1800,
        )
    assert proc.returncode == 0, (
        f"setup_datasets_envs.sh failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    return DATASETS_VENV / "bin" / "python"


def run_plain_in_datasets_env(
    executable: str, *args: str, cwd: Path, timeout: int = 600
) -> subprocess.CompletedProcess[str]:
    """``.venv-datasets/bin/<executable> ARGS`` as a user runs it: no project wrapper, a
    clean environment (no PYTHONPATH or other PYTHON* variables, HOME = ``cwd``), outside
    the checkout. Creates/refreshes the environment first."""
    bin_dir = datasets_python().parent
    env = {
        "PATH": f"{bin_dir}:/usr/local/bin:/usr/bin:/bin",
        "HOME": str(cwd),
        "LANG": "C.UTF-8",
        "TMPDIR": os.environ.get("TMPDIR", "/tmp"),
        "OMP_NUM_THREADS": "1",
    }
    return subprocess.run(
        [str(bin_dir / executable), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def run_suite_in_datasets_env(test_file: str, timeout: int = 1500) -> None:
    """Run ``test_file`` with pytest inside `.venv-datasets`; fail with its output if red.

    `--noconftest`: tests/conftest.py imports mikasa_envs/ManiSkill and lists every env id,
    which the conversion tests do not need (the environment has them since it also runs
    LeRobot policies on the tasks, tests/test_lerobot_policy.py).
    """
    python = datasets_python()
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    env["HF_HOME"] = str(
        Path(os.environ.get("TMPDIR", "/tmp")) / "mikasa-datasets-tests-hf"
    )  # no writes to ~
    proc = subprocess.run(
        [
            str(python),
            "-m",
            "pytest",
            "-q",
            "--noconftest",
            "-p",
            "no:cacheprovider",
            "-rA",
            test_file,
        ],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    out = proc.stdout + proc.stderr
    summary = [line for line in out.splitlines() if re.search(r"\b(passed|failed|error)\b", line)]
    assert proc.returncode == 0, f"{test_file} failed inside {DATASETS_VENV}:\n{out[-8000:]}"
    assert " passed" in (summary[-1] if summary else ""), f"no inner test ran:\n{out[-3000:]}"
    assert "skipped" not in summary[-1], f"inner tests were skipped:\n{summary[-1]}"


if not IN_DATASETS_ENV:

    def test_validate_suite_in_datasets_env() -> None:
        """RLDS/LeRobot validation tests of this file, run inside `.venv-datasets`."""
        run_suite_in_datasets_env(__file__)


# --------------------------------------------------------------------------- fixtures
@pytest.fixture
def npz_task(tmp_path: Path) -> Path:
    """A valid synthetic NPZ task directory with 3 episodes."""
    return write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 14, 11])


def _fails_with(path: Path, *fragments: str, **kwargs) -> str:
    with pytest.raises((DatasetFormatError, EpisodeFormatError)) as info:
        validate_path(path, **kwargs)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


# --------------------------------------------------------------------------- NPZ (numpy only)
def test_valid_npz_task_passes(npz_task: Path) -> None:
    report = validate_path(npz_task)
    assert (report.format, report.episodes, report.frames) == ("npz", 3, 35)
    assert validate_path(npz_task, quick=True).frames == 35
    assert validate_path(npz_task / "train_data_2.npz").frames == 11
    root = validate_path(npz_task.parent)  # a data_npz root of tasks
    assert (root.tasks, root.episodes) == (1, 3)
    assert detect_format(npz_task) == "npz"


def test_truncated_npz_names_file(npz_task: Path) -> None:
    f = npz_task / "train_data_1.npz"
    f.write_bytes(f.read_bytes()[:5000])
    _fails_with(npz_task, str(f), "truncated or corrupt")


def test_gap_in_episode_numbering_named(npz_task: Path) -> None:
    (npz_task / "train_data_1.npz").unlink()
    _fails_with(npz_task, "train_data_1.npz", "missing", "without gaps")


def test_metadata_mismatches_named(npz_task: Path) -> None:
    meta_path = npz_task / "metadata.json"
    meta = json.loads(meta_path.read_text())
    meta["episode_lengths"][2] = 99
    meta_path.write_text(json.dumps(meta))
    _fails_with(npz_task, "metadata.json", "episode_lengths[2] is 99", "11 steps")
    meta["episode_lengths"][2] = 11
    meta["num_episodes"] = 4
    meta_path.write_text(json.dumps(meta))
    _fails_with(npz_task, "metadata.json", "num_episodes is 4", "3 episode files")
    meta_path.unlink()
    _fails_with(npz_task, "metadata.json", "missing")


def test_episode_boundary_problem_named(npz_task: Path) -> None:
    f = npz_task / "train_data_0.npz"
    ep = read_episode(f)
    ep["done"] = ep["done"].copy()
    ep["done"][4] = 1
    write_episode(f, ep, validate=False)
    _fails_with(npz_task, str(f), "done is 1 at step 4")


def test_wrong_dtype_named(npz_task: Path) -> None:
    f = npz_task / "train_data_1.npz"
    ep = read_episode(f)
    ep["proprio"] = ep["proprio"].astype(np.float64)
    np.savez(f, **ep)  # bypass the writer's schema check
    _fails_with(npz_task, str(f), "'proprio'", "float64")


def test_unrecognised_directory_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "x.txt").write_text("x")
    assert cli.main(["validate", str(tmp_path)]) == 1
    assert "not a recognised dataset directory" in capsys.readouterr().out


def test_cli_validate_reports_ok_and_first_problem(
    npz_task: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["validate", str(npz_task)]) == 0
    assert capsys.readouterr().out.startswith(f"OK npz {npz_task}: 3 episodes, 35 frames")
    (npz_task / "train_data_2.npz").write_bytes(b"not a zip")
    assert cli.main(["validate", str(npz_task)]) == 1
    out = capsys.readouterr().out
    assert out.startswith("INVALID ") and "train_data_2.npz" in out
    assert cli.main(["validate", str(npz_task.parent / "nope")]) == 1
    assert "no such file or directory" in capsys.readouterr().out


def test_extras_are_pinned_by_the_setup_script() -> None:
    """Every optional dependency of mikasa-datasets is installed by setup_datasets_envs.sh."""
    project = tomllib.loads((REPO / "packages/mikasa-datasets/pyproject.toml").read_text())[
        "project"
    ]
    script = (REPO / "scripts/setup_datasets_envs.sh").read_text().lower()
    assert project["scripts"]["mikasa-datasets"] == "mikasa_datasets.cli:main"
    for extra in ("rlds", "lerobot"):
        for req in project["optional-dependencies"][extra]:
            name = re.split(r"[<>=!;\[ ]", req, maxsplit=1)[0].lower()
            if name == "tensorflow":  # the non-Linux spelling of tensorflow-cpu
                continue
            assert f'"{name}' in script, f"{name} ({extra}) is not installed by the setup script"


if not IN_DATASETS_ENV:

    def test_missing_format_library_gives_install_hint(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        """In the main environment (no tensorflow) RLDS work fails clearly, with exit 3."""
        write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10])
        assert cli.main(["to-rlds", "--root", str(tmp_path), "--task", ENV_ID]) == 3
        err = capsys.readouterr().err
        assert "setup_datasets_envs.sh" in err and "mikasa-datasets[rlds]" in err
        assert not (tmp_path / "data_rlds").exists()


# --------------------------------------------------------------------------- RLDS / LeRobot
if IN_DATASETS_ENV:
    from mikasa_datasets import lerobot as lr
    from mikasa_datasets import rlds

    @pytest.fixture(scope="module")
    def converted(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
        root = tmp_path_factory.mktemp("formats")
        task = write_synthetic_task(root / "data_npz", ENV_ID, [10, 13])
        r = rlds.convert_npz_to_rlds(task, root / "data_rlds")
        lerobot_path = lr.convert_npz_to_lerobot(task, root / "data_lerobot").path
        return {"root": root, "npz": task, "rlds": r.path, "lerobot": lerobot_path}

    def _copy(src: Path, tmp_path: Path) -> Path:
        import shutil

        dst = tmp_path / src.name
        shutil.copytree(src, dst)
        return dst

    def test_valid_rlds_and_lerobot_pass(converted: dict[str, Path]) -> None:
        assert validate_path(converted["rlds"]).summary().startswith("OK rlds")
        assert validate_path(converted["rlds"].parent).frames == 23  # task dir -> latest version
        assert validate_path(converted["lerobot"]).summary().startswith("OK lerobot")
        assert validate_path(converted["lerobot"], quick=True).episodes == 2
        whole = validate_path(converted["root"] / "data_rlds")
        assert (whole.format, whole.episodes) == ("rlds", 2)
        assert cli.main(["validate", str(converted["rlds"]), str(converted["lerobot"])]) == 0

    def test_rlds_missing_or_corrupt_shard_named(
        converted: dict[str, Path], tmp_path: Path
    ) -> None:
        vdir = _copy(converted["rlds"], tmp_path)
        shard = rlds.shard_files(vdir)[0]
        data = bytearray(shard.read_bytes())
        data[len(data) // 2 : len(data) // 2 + 64] = b"\x00" * 64
        shard.write_bytes(bytes(data))
        _fails_with(vdir, str(shard), "corrupt or truncated TFRecord")
        shard.write_bytes(bytes(data[: len(data) // 3]))
        _fails_with(vdir, str(shard))
        shard.unlink()
        _fails_with(vdir, str(shard), "missing")

    def test_rlds_feature_spec_problems_named(converted: dict[str, Path], tmp_path: Path) -> None:
        vdir = _copy(converted["rlds"], tmp_path)
        features = vdir / "features.json"
        spec = json.loads(features.read_text())
        steps = spec["featuresDict"]["features"]["steps"]["sequence"]["feature"]["featuresDict"][
            "features"
        ]
        steps["observation"]["featuresDict"]["features"]["proprio"]["tensor"]["shape"][
            "dimensions"
        ] = ["8"]
        features.write_text(json.dumps(spec))
        _fails_with(vdir, "features.json", "steps/observation/proprio", "shape (8,)")
        info_path = vdir / "dataset_info.json"
        info = json.loads(info_path.read_text())
        info["name"] = "other"
        info_path.write_text(json.dumps(info))
        _fails_with(vdir, "dataset_info.json", "'other'")

    def test_rlds_episode_boundaries_checked(tmp_path: Path) -> None:
        """An RLDS episode whose is_last is set early is rejected, naming shard + episode."""
        from mikasa_datasets.loaders import synthetic_episode

        ep = synthetic_episode(np.random.default_rng(1), 12, "touch it", 7)
        example = rlds.episode_to_rlds(
            ep, file_path="train_data_0.npz", env_id=ENV_ID, episode_index=0
        )
        example["steps"]["is_last"] = example["steps"]["is_last"].copy()
        example["steps"]["is_last"][5] = True
        builder = rlds._builder_class()(
            example_source=lambda: iter([(0, example)]), data_dir=str(tmp_path)
        )
        builder.download_and_prepare()
        vdir = tmp_path / rlds.BUILDER_NAME / rlds.RLDS_VERSION
        _fails_with(
            vdir, "mikasa_dataset-train.tfrecord-00000-of-00001", "episode 0", "is_last", "[5, 11]"
        )

    def test_lerobot_problems_named(converted: dict[str, Path], tmp_path: Path) -> None:
        root = _copy(converted["lerobot"], tmp_path)
        info_path = root / "meta" / "info.json"
        info = json.loads(info_path.read_text())
        info["total_frames"] = 999
        info_path.write_text(json.dumps(info))
        _fails_with(root, "info.json", "total_frames is 999", "23 frames")
        info["total_frames"] = 23
        info["features"]["observation.state"]["shape"] = [8]
        info_path.write_text(json.dumps(info))
        _fails_with(root, "info.json", "observation.state", "shape [8]")
        info["features"]["observation.state"]["shape"] = [7]
        info_path.write_text(json.dumps(info))
        video = next((root / "videos" / lr.WRIST_KEY).rglob("*.mp4"))
        video.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
        _fails_with(root, str(video))
        video.unlink()
        _fails_with(root, str(video), "missing")
        (root / "meta" / "stats.json").unlink()
        _fails_with(root, "stats.json", "missing")

    def test_lerobot_corrupt_parquet_named(converted: dict[str, Path], tmp_path: Path) -> None:
        root = _copy(converted["lerobot"], tmp_path)
        data = next((root / "data").rglob("*.parquet"))
        data.write_bytes(data.read_bytes()[:100])
        _fails_with(root, str(data), "corrupt or truncated")
