"""mikasa-rl-collect: the RL release's datasets (legacy_rl.md §6.1-6.2).

Small on purpose (2 shared CPU cores; the first rgb frame of a process costs 5-11 s of
renderer start-up, a 60-step RememberColor3 episode ~2.5 s): one in-process reference
collection of 2 episodes, compared byte for byte with a resumed run and (slow) a 2-worker
run through the old ``python -m`` path; a checkpoint-replay run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from mikasa_datasets.npz import RL_EPISODE_KEYS
from mikasa_datasets.validate import validate_path
from mikasa_robo_rl.agents import CKPT_NAME, CKPT_SUBDIR, AgentStateOnly, find_checkpoints
from mikasa_robo_rl.collect import (
    CollectError,
    collect,
    episode_seed,
    main,
    make_rl_collection_env,
    summary_path,
    unbatched_dir,
)

ENV_ID = "RememberColor3-v0"  # horizon 60, the shortest
T = 60
N, BATCH = 2, 2
OLD_MODULE = "mikasa_robo_suite.dataset_collectors.get_mikasa_robo_datasets"


def tree(root: Path) -> dict[str, bytes]:
    """relative path -> bytes of every file under ``root``."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def episodes(root: Path) -> dict[str, bytes]:
    """The episode directory's files (the summary holds wall times)."""
    return tree(unbatched_dir(root, ENV_ID))


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """One in-process collection: N episodes of RememberColor3-v0, one seed batch."""
    root = tmp_path_factory.mktemp("reference")
    summary = collect(ENV_ID, root, N, batch_size=BATCH, workers=1, progress=False)
    assert (summary["episodes"], summary["new_episodes"], summary["workers"]) == (N, N, 1)
    return root


def test_layout_schema_and_summary(reference):
    assert sorted(tree(reference)) == [
        f"MIKASA-Robo/summary_{ENV_ID}.json",
        *[f"MIKASA-Robo/unbatched/{ENV_ID}/train_data_{n}.npz" for n in range(N)],
    ]  # no temporary files, no batched directory
    expected = {
        "rgb": (np.uint8, (T, 128, 128, 6)),
        "joints": (np.float32, (T, 25)),
        "action": (np.float32, (T, 8)),
        "reward": (np.float32, (T,)),
        "success": (np.int64, (T,)),
        "done": (np.int64, (T,)),
    }
    for n in range(N):
        with np.load(unbatched_dir(reference, ENV_ID) / f"train_data_{n}.npz") as z:
            assert tuple(z.files) == RL_EPISODE_KEYS == tuple(expected)
            for key, (dtype, shape) in expected.items():
                assert (z[key].dtype, z[key].shape) == (np.dtype(dtype), shape), key
            assert z["done"].tolist() == [0] * (T - 1) + [1]  # every step, up to the timeout
            assert set(np.unique(z["success"])) <= {0, 1}
            assert np.abs(z["action"]).max() <= 1 and z["rgb"].any()
    summary = json.loads(summary_path(reference, ENV_ID).read_text())
    assert summary["complete"] and summary["episodes"] == N and summary["episode_length"] == T
    assert summary["settings"]["batch_size"] == BATCH
    assert summary["settings"]["policy"] == "scripted oracle"
    assert 0 <= summary["success_rate"] <= 1 and summary["frames_per_s"] > 0
    report = validate_path(reference / "MIKASA-Robo")
    assert (report.format, report.episodes, report.frames) == ("npz-rl", N, N * T)


def test_first_frame_is_the_reset_observation_of_the_derived_seed(reference):
    """Episode n = b*batch + i starts from reset(seed=episode_seed(b, i)) (reconfigured)."""
    _, venv = make_rl_collection_env(ENV_ID)
    try:
        obs, _ = venv.reset(seed=episode_seed(0, 1, BATCH), options={"reconfigure": True})
    finally:
        venv.close()
    with np.load(unbatched_dir(reference, ENV_ID) / "train_data_1.npz") as z:
        assert np.array_equal(z["rgb"][0], obs["rgb"][0].numpy())
        assert np.array_equal(z["joints"][0], obs["proprio"][0].numpy())


def test_episode_seed_is_maniskills_per_env_seed_of_a_batch_reset():
    from mani_skill.envs.sapien_env import BaseEnv

    for batch, size in ((0, 2), (3, 5), (7, 250)):
        fake = SimpleNamespace(
            num_envs=size, _main_seed=None, _batched_rng_backend=BaseEnv._batched_rng_backend,
            _enhanced_determinism=False, _episode_seed=None, _batched_episode_rng=None,
        )
        BaseEnv._set_main_rng(fake, batch)
        BaseEnv._set_episode_rng(fake, batch, torch.arange(size))
        assert [episode_seed(batch, i, size) for i in range(size)] == fake._episode_seed.tolist()
    with pytest.raises(ValueError):
        episode_seed(0, 2, 2)


def test_resume_after_a_killed_run(reference, tmp_path):
    """A run killed mid-write leaves a temporary file and misses an episode: the rerun
    deletes the temporary file and writes the missing episode (on a fresh env, after none
    of the episodes it ran before) to the same bytes; the finished one is not redone."""
    ref = episodes(reference)
    directory = unbatched_dir(tmp_path, ENV_ID)
    directory.mkdir(parents=True)
    (directory / "train_data_0.npz").write_bytes(ref["train_data_0.npz"])
    (directory / ".train_data_1.npz.4242.deadbeef.tmp").write_bytes(ref["train_data_1.npz"][:999])
    summary = collect(ENV_ID, tmp_path, N, batch_size=BATCH, workers=1, progress=False)
    assert (summary["new_episodes"], summary["episodes"]) == (1, N)
    assert episodes(tmp_path) == ref
    again = collect(ENV_ID, tmp_path, N, batch_size=BATCH, progress=False)  # nothing to do
    assert (again["new_episodes"], again["workers"]) == (0, 0) and episodes(tmp_path) == ref
    with pytest.raises(CollectError, match="batch_size=2"):  # other seeds: refuse to mix
        collect(ENV_ID, tmp_path, N, batch_size=1, progress=False)
    with pytest.raises(CollectError, match="beyond the 1 episodes"):
        collect(ENV_ID, tmp_path, 1, batch_size=1, progress=False)


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--num-train-data", "3", "--batch-size", "2"], "not a multiple of --batch-size 2"),
        (["--num_train_data", "1000"], "not a multiple of --batch-size 3"),  # old spelling
        (["--env-id", "RememberColour3-v0"], "Unknown environment: 'RememberColour3-v0'"),
        (["--env_id", "RememberColor3-VLA-v0"], "VLA ids (<Name>-VLA-v0) belong to mikasa_envs"),
        (["--ckpt-dir", "nowhere"], f"no checkpoint nowhere/{CKPT_SUBDIR}/"),
        (["--workers", "0"], "must be >= 1"),
    ],
)
def test_bad_input_exits_2(tmp_path, capsys, argv, fragment):
    argv = ["--num-train-data", "3", "--batch-size", "3", "--path-to-save-data", str(tmp_path / "d"), *argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("mikasa-rl-collect: error: ") and fragment in err
    assert "Traceback" not in err and not (tmp_path / "d").exists()


@pytest.mark.parametrize("argv", [["--batch-size", "x"], ["--bogus"]])
def test_malformed_flags_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and "usage: mikasa-rl-collect" in capsys.readouterr().err


def test_old_module_path_reports_bad_input(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", OLD_MODULE, "--env_id", "RememberColor3-v0",
         "--num_train_data", "5", "--path_to_save_data", str(tmp_path)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 2, proc.stderr
    assert "--num-train-data 5 is not a multiple of --batch-size 250" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("missing", ["mikasa_oracles", "mikasa_datasets"])
def test_old_path_imports_without_the_collect_extra(missing):
    """A base install (no mikasa-oracles, or no mikasa-datasets) still imports the old module
    (it re-exports env_info); collecting then names the extra to install."""
    code = (
        "import sys\n"
        f"sys.modules['{missing}'] = None\n"
        f"from {OLD_MODULE} import env_info, main\n"
        "assert env_info('ShellGameTouch-v0')[1] == 90\n"
        "sys.exit(main(['--env-id', 'RememberColor3-v0']))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert 'pip install "mikasa-robo-rl[collect]"' in proc.stderr and "Traceback" not in proc.stderr


# ~30 s: two fresh worker processes, each paying the ~11 s renderer start-up
def test_two_workers_through_the_old_path_write_the_same_bytes(reference, tmp_path):
    """``python -m <old path>`` with 2 worker processes, one episode each (each on a fresh
    env in its own process): the same bytes as the in-process run of both on one env."""
    proc = subprocess.run(
        [sys.executable, "-m", OLD_MODULE, "--env_id", ENV_ID, "--num_train_data", str(N),
         "--batch_size", str(BATCH), "--path_to_save_data", str(tmp_path), "--workers", "2",
         "--no-progress"],
        capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"{ENV_ID}: {N} episodes" in proc.stdout
    assert json.loads(summary_path(tmp_path, ENV_ID).read_text())["workers"] == 2
    assert episodes(tmp_path) == episodes(reference)


def save_random_checkpoints(root: Path, runs: list[str], obs_dim: int = 35) -> None:
    for k, run in enumerate(runs):
        torch.manual_seed(k)
        ckpt = root / CKPT_SUBDIR / ENV_ID / run / CKPT_NAME
        ckpt.parent.mkdir(parents=True)
        torch.save(AgentStateOnly(obs_dim, 8).state_dict(), ckpt)


def test_checkpoint_replay(tmp_path):
    """Every checkpoint is replayed (checkpoint k owns n = k*N ..), deterministically,
    through a state env in lockstep with the rgb env."""
    save_random_checkpoints(tmp_path / "ckpt", ["b", "a/seed1"])  # sorted: a/seed1, b
    summary = collect(ENV_ID, tmp_path / "one", 1, ckpt_dir=tmp_path / "ckpt", batch_size=1,
                      workers=1, progress=False)
    assert summary["settings"]["policy"] == "checkpoints" and summary["episodes"] == 2
    assert [Path(c).parent.name for c in summary["settings"]["checkpoints"]] == ["seed1", "b"]
    files = [unbatched_dir(tmp_path / "one", ENV_ID) / f"train_data_{n}.npz" for n in (0, 1)]
    first = {}
    for n, f in enumerate(files):
        with np.load(f) as z:
            first[n] = (z["rgb"][0].copy(), z["action"].copy())
            assert z["done"].tolist() == [0] * (T - 1) + [1]
    assert np.array_equal(first[0][0], first[1][0])  # same seed ...
    assert not np.array_equal(first[0][1], first[1][1])  # ... another agent
    agent = AgentStateOnly.from_state_dict(torch.load(summary["settings"]["checkpoints"][0]))
    _, venv = make_rl_collection_env(ENV_ID, "state")
    try:
        obs, _ = venv.reset(seed=episode_seed(0, 0, 1), options={"reconfigure": True})
    finally:
        venv.close()
    with torch.no_grad():
        expected = agent.get_action(obs["state"].float(), deterministic=True)[0].numpy()
    assert np.allclose(first[0][1][0], np.clip(expected, -1, 1), atol=1e-6)
    assert validate_path(unbatched_dir(tmp_path / "one", ENV_ID)).episodes == 2


def test_checkpoint_of_the_wrong_size_is_a_usage_error(tmp_path):
    save_random_checkpoints(tmp_path, ["run"], obs_dim=33)
    with pytest.raises(CollectError, match="maps 33 -> 8, RememberColor3-v0 needs 35 -> 8"):
        collect(ENV_ID, tmp_path / "out", 1, ckpt_dir=tmp_path, batch_size=1, progress=False)


@pytest.mark.slow
def test_shell_game_episode_does_not_depend_on_the_episodes_before(tmp_path):
    """ShellGameTouch's cups keep PhysX contact state across a plain reset; with the
    reconfiguring reset episode 1 is the same after episode 0 as on a fresh env."""
    env_id = "ShellGameTouch-v0"
    collect(env_id, tmp_path / "a", 2, batch_size=2, workers=1, progress=False)
    first = unbatched_dir(tmp_path / "a", env_id) / "train_data_1.npz"
    reference = first.read_bytes()
    first.unlink()
    collect(env_id, tmp_path / "a", 2, batch_size=2, workers=1, progress=False)
    assert first.read_bytes() == reference


def test_shipped_and_trained_checkpoint_layouts_are_found(tmp_path):
    shipped = Path(__file__).resolve().parents[1] / "legacy/rl/baselines/checkpoints"
    assert find_checkpoints(shipped, "RememberColor3-v0") == [shipped / "RememberColor3-v0/final_ckpt.pt"]
    run = tmp_path / "checkpoints/ppo_memtasks/state/normalized_dense" / ENV_ID / "run/20261125_000000"
    run.mkdir(parents=True)
    (run / "final_ckpt.pt").touch()
    (run / "ckpt_0_1.pt").touch()
    assert find_checkpoints(tmp_path, ENV_ID) == [run / "final_ckpt.pt"]
