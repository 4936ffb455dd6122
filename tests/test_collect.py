"""mikasa-collect: oracle demonstrations as NPZ episodes (datasets spec §2-§4).

Small on purpose (2 shared CPU cores, ~0.08 s per rgb step): a few 3-episode collections
of RememberColor3 / FindImposterColor3, compared byte for byte.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from mikasa_datasets.npz import (
    METADATA_KEYS,
    list_episode_files,
    read_episode,
    read_metadata,
)
from mikasa_oracles.collect import (
    CollectError,
    CollectionFailed,
    collect,
    make_collection_env,
)
from mikasa_oracles.collect_cli import main

ENV_ID = "RememberColor3-VLA-v0"
NAME = "remember_color_3_vla_v0"
N = 3


@contextmanager
def chdir(path: Path) -> Iterator[None]:
    """Run in ``path`` so the relative ``--out`` (and thus metadata.json) is the same for
    every collection compared."""
    old = os.getcwd()
    path.mkdir(parents=True, exist_ok=True)
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def run(cwd: Path, env_id: str = ENV_ID, n: int = N, **kwargs):
    """``collect`` into ``<cwd>/data`` with the relative path ``data``."""
    with chdir(cwd):
        return collect(env_id, n, "data", progress=False, **kwargs)


def tree(root: Path) -> dict[str, bytes]:
    """relative path -> bytes of every file under ``root``."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """One in-process collection of ``N`` RememberColor3 episodes (cwd of ``data``)."""
    cwd = tmp_path_factory.mktemp("reference")
    summary = run(cwd)
    assert (summary.new_episodes, summary.existing_episodes) == (N, 0)
    return cwd


def test_layout_schema_and_metadata(reference):
    directory = reference / "data" / "data_npz" / NAME
    assert sorted(tree(reference / "data")) == [
        f"data_npz/{NAME}/metadata.json",
        *[f"data_npz/{NAME}/train_data_{i}.npz" for i in range(N)],
    ]  # no _batched leftovers, no temporary files
    episodes = [
        read_episode(p, validate=True, max_episode_steps=25) for p in list_episode_files(directory)
    ]
    for ep in episodes:
        t = int(ep["episode_length"])
        assert ep["rgb"].shape == (t, 128, 128, 6) and ep["rgb"].dtype == np.uint8
        assert ep["proprio"].shape == (t, 7) and ep["proprio"].dtype == np.float32
        assert ep["action"].dtype == np.float32 and np.abs(ep["action"]).max() <= 1
        assert 10 <= t <= 25
        assert ep["done"].tolist() == [0] * (t - 1) + [1]
        assert ep["success"][-1] == 1
        assert str(ep["language_instruction"]).startswith("Observe the cube's color")
    seeds = [int(ep["episode_seed"]) for ep in episodes]
    assert seeds == sorted(seeds) and seeds[0] >= 0

    meta = json.loads((directory / "metadata.json").read_text(encoding="utf-8"))
    assert tuple(meta) == METADATA_KEYS
    assert meta["env_id"] == ENV_ID
    assert meta["num_episodes"] == N
    assert meta["episode_lengths"] == [int(ep["episode_length"]) for ep in episodes]
    assert meta["success_once"] == [True] * N
    assert meta["episode_seeds"] == seeds
    assert meta["reward_sums"] == pytest.approx(
        [float(ep["reward"].sum(dtype=np.float64)) for ep in episodes]
    )
    assert meta["unbatched_dir"] == f"data/data_npz/{NAME}"
    assert meta["batched_source_dir"] == f"data/data_npz/_batched/{NAME}"


def test_step_alignment_matches_a_replay(reference):
    """rgb/proprio[t] is the observation before action[t]; reward/success/done[t] come from
    that step (spec §3.1): replaying the stored actions from the stored seed reproduces
    every stored value."""
    ep = read_episode(reference / "data" / "data_npz" / NAME / "train_data_1.npz")
    env = make_collection_env(ENV_ID)
    try:
        obs, _ = env.reset(seed=int(ep["episode_seed"]))
        for t in range(int(ep["episode_length"])):
            np.testing.assert_array_equal(obs["rgb"][0].numpy(), ep["rgb"][t])
            np.testing.assert_array_equal(obs["proprio"][0].numpy(), ep["proprio"][t])
            obs, reward, terminated, truncated, info = env.step(ep["action"][t])
            assert float(reward[0]) == ep["reward"][t]
            assert int(bool(info["success"][0])) == ep["success"][t]
            done = bool(info["success"][0]) or bool(terminated[0]) or bool(truncated[0])
            assert int(done) == ep["done"][t]
    finally:
        env.close()


def test_same_command_twice_is_byte_identical(reference, tmp_path, capsys):
    with chdir(tmp_path):
        status = main(
            ["--env-id", ENV_ID, "--num-episodes", str(N), "--out", "data", "--no-progress"]
        )
    assert status == 0
    out = capsys.readouterr().out
    assert f"{N} new episode(s)" in out and "success rate" in out and "episodes/min" in out
    assert tree(tmp_path / "data") == tree(reference / "data")


def test_resume_after_deleting_the_last_file(reference, tmp_path):
    shutil.copytree(reference / "data", tmp_path / "data")
    directory = tmp_path / "data" / "data_npz" / NAME
    (directory / f"train_data_{N - 1}.npz").unlink()  # metadata.json is now stale too
    summary = run(tmp_path)
    assert (summary.existing_episodes, summary.new_episodes) == (N - 1, 1)
    assert tree(tmp_path / "data") == tree(reference / "data")


def test_resume_removes_stray_temp_and_staged_files(reference, tmp_path):
    shutil.copytree(reference / "data", tmp_path / "data")
    directory = tmp_path / "data" / "data_npz" / NAME
    last = directory / f"train_data_{N - 1}.npz"
    partial = last.read_bytes()[:50_000]
    last.unlink()
    # What a kill -9 during a write leaves: a partial temporary file next to the final
    # names, and an attempt staged but not yet committed.
    (directory / f".train_data_{N - 1}.npz.999.deadbeef.tmp").write_bytes(partial)
    staging = tmp_path / "data" / "data_npz" / "_batched" / NAME
    staging.mkdir(parents=True)
    (staging / "seed_123.npz").write_bytes(partial)
    (staging / ".seed_124.npz.999.beef.tmp").write_bytes(partial)
    summary = run(tmp_path)
    assert summary.new_episodes == 1
    assert tree(tmp_path / "data") == tree(reference / "data")


def test_budget_exhausted_then_resume(reference, tmp_path):
    """A run that stops early (here: the attempt budget) keeps a consistent prefix;
    re-running completes it to exactly the uninterrupted result."""
    with pytest.raises(CollectionFailed, match="--max-attempts"):
        run(tmp_path, max_attempts=1)
    directory = tmp_path / "data" / "data_npz" / NAME
    assert [p.name for p in list_episode_files(directory)] == ["train_data_0.npz"]
    assert read_metadata(directory)["num_episodes"] == 1
    assert not (tmp_path / "data" / "data_npz" / "_batched").exists()
    run(tmp_path)
    assert tree(tmp_path / "data") == tree(reference / "data")


def test_complete_dataset_is_left_alone(reference, tmp_path):
    shutil.copytree(reference / "data", tmp_path / "data")
    before = tree(tmp_path / "data")
    summary = run(tmp_path)
    assert (summary.existing_episodes, summary.new_episodes, summary.attempts) == (N, 0, 0)
    assert tree(tmp_path / "data") == before
    with pytest.raises(CollectError, match=f"already holds {N} episodes"):
        run(tmp_path, n=N - 1)
    with pytest.raises(CollectError, match="--start-seed"):
        run(tmp_path, n=N + 1, start_seed=10**6)


def test_two_workers_write_what_one_worker_writes(tmp_path):
    env_id, name = "FindImposterColor3-VLA-v0", "find_imposter_color_3_vla_v0"
    one = run(tmp_path / "one", env_id)
    two = run(tmp_path / "two", env_id, workers=2)
    assert one.new_episodes == two.new_episodes == N and two.workers == 2
    files = tree(tmp_path / "one" / "data")
    assert sorted(files) == [
        f"data_npz/{name}/metadata.json",
        *[f"data_npz/{name}/train_data_{i}.npz" for i in range(N)],
    ]
    assert tree(tmp_path / "two" / "data") == files


def test_envs_in_threads_write_what_one_worker_writes(reference, tmp_path):
    """--envs-per-worker: one process running two envs in threads (their cameras rendered
    in shared passes) writes the in-process collection's bytes."""
    threaded = run(tmp_path, workers=1, envs_per_worker=2)
    assert threaded.new_episodes == N
    assert tree(tmp_path / "data") == tree(reference / "data")


@pytest.mark.parametrize("workers", [1, 2])
def test_several_tasks_in_one_command_write_what_each_alone_writes(
    reference, tmp_path, capsys, workers
):
    """Tasks one after another (with 2 workers: on one pool of processes that switch
    tasks) write what each task's collection alone writes."""
    other, other_name = "FindImposterColor3-VLA-v0", "find_imposter_color_3_vla_v0"
    with chdir(tmp_path / "both"):
        argv = ["--env-id", ENV_ID, "--env-id", other, "--num-episodes", str(N), "--out", "data"]
        argv += ["--workers", str(workers)]
        assert main([*argv, "--no-progress"]) == 0
    assert "2/2 task(s) complete: 6 new episode(s)" in capsys.readouterr().out
    run(tmp_path / "alone", other)
    both = tree(tmp_path / "both" / "data")
    assert {k: v for k, v in both.items() if NAME in k} == tree(reference / "data")
    assert {k: v for k, v in both.items() if other_name in k} == tree(tmp_path / "alone" / "data")


class _FakeRunner:
    """Stands in for the simulator: seeds 1, 4, 7, ... fail, the others give a synthetic
    12-step episode that records its seed."""

    def __init__(self, env_id, staging_dir, min_length, fallback_language):
        self.staging = Path(staging_dir)

    def run(self, seed):
        from mikasa_datasets.npz import make_episode, write_episode
        from mikasa_oracles.collect import AttemptResult

        if seed % 3 == 1:
            return AttemptResult(seed, False, "unsuccessful", 25, 0.0, 0.0)
        t = 12
        rng = np.random.default_rng(seed)
        flags = [0] * (t - 1) + [1]
        ep = make_episode(
            rgb=rng.integers(0, 256, (t, 128, 128, 6)),
            proprio=rng.normal(size=(t, 7)),
            action=rng.uniform(-1, 1, (t, 7)),
            reward=rng.uniform(0, 1, t),
            success=flags,
            done=flags,
            language_instruction=fallback_language_of(ENV_ID),
            episode_seed=seed,
        )
        path = write_episode(self.staging / f"seed_{seed}.npz", ep)
        return AttemptResult(seed, True, "saved", t, float(ep["reward"].sum()), 0.0, str(path))

    def close(self):
        pass


def fallback_language_of(env_id: str) -> str:
    from mikasa_envs.manifest import get_task

    return get_task(env_id).language_instruction


class _LifoPool:
    """A worker pool that finishes the most recently submitted attempt first: the worst
    case for keeping indices in seed order."""

    max_in_flight = 0

    def __init__(self, runner_args, workers, envs_per_worker=1):
        from mikasa_oracles import collect_pools

        self.runner = collect_pools.AttemptRunner(*runner_args)
        self.slots = workers * envs_per_worker
        self.submitted: list[int] = []

    def submit(self, seed, runner_args=None):
        self.submitted.append(seed)
        _LifoPool.max_in_flight = max(_LifoPool.max_in_flight, len(self.submitted))

    def get(self):
        return self.runner.run(self.submitted.pop())

    def close(self, graceful=True):
        pass


def test_out_of_order_completion_keeps_seed_order(tmp_path, monkeypatch):
    """Indices follow seed order whatever the completion order; failed seeds are skipped;
    no attempt is started that could not be needed."""
    from mikasa_oracles import collect as collect_module
    from mikasa_oracles import collect_pools

    monkeypatch.setattr(collect_pools, "AttemptRunner", _FakeRunner)
    monkeypatch.setattr(collect_module, "ProcessPool", _LifoPool)
    serial = run(tmp_path / "serial", n=5)
    parallel = run(tmp_path / "parallel", n=5, workers=4)
    directory = tmp_path / "parallel" / "data" / "data_npz" / NAME
    assert read_metadata(directory)["episode_seeds"] == [0, 2, 3, 5, 6]
    assert (parallel.attempts, parallel.successes, parallel.reasons) == (
        7,
        5,
        {"saved": 5, "unsuccessful": 2},
    )
    assert serial.attempts == 7
    assert _LifoPool.max_in_flight == 4
    assert tree(tmp_path / "parallel" / "data") == tree(tmp_path / "serial" / "data")


def test_ray_executor_writes_what_local_workers_write(reference, tmp_path, capsys):
    """``--executor ray``: the actors stage on their node and send the bytes back; the
    files are the in-process collection's, and a Ray the caller started is left running."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=100 * 1024**2, log_to_driver=False)
    try:
        with chdir(tmp_path):
            status = main(["--env-id", ENV_ID, "--num-episodes", str(N), "--out", "data",
                           "--workers", "2", "--executor", "ray", "--no-progress"])
        assert status == 0 and ray.is_initialized()
    finally:
        ray.shutdown()
    assert tree(tmp_path / "data") == tree(reference / "data")
    assert "2 worker" in capsys.readouterr().out


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--env-id", "RememberColour3-VLA-v0"], "Did you mean: RememberColor3-VLA-v0"),
        (["--env-id", ENV_ID, "--num-episodes", "0"], "must be >= 1"),
        (["--env-id", ENV_ID, "--num-episodes", "-3"], "must be >= 1"),
        (["--env-id", ENV_ID, "--workers", "0"], "must be >= 1"),
        (["--env-id", ENV_ID, "--envs-per-worker", "0"], "must be >= 1"),
        (["--env-id", ENV_ID, "--envs-per-worker", "2", "--executor", "ray"], "needs the local executor"),
        (["--env-id", ENV_ID, "--max-attempts", "0"], "must be >= 1"),
        (["--env-id", ENV_ID, "--start-seed", "-1"], "must be >= 0"),
        (["--env-id", ENV_ID, "--obs-mode", "state"], "unrecognized arguments: --obs-mode"),
        (["--env-id", ENV_ID, "--env-id", ENV_ID], "--env-id given more than once: " + ENV_ID),
        (["--env-id", ENV_ID, "--env-id", "RememberColour3-VLA-v0"], "Did you mean: RememberColor3-VLA-v0"),
        (["--env-id", ENV_ID, "--split", "short"], "not allowed with argument"),
        (["--split", "tiny"], "invalid choice: 'tiny'"),
        (["--env-id", ENV_ID, "--executor", "slurm"], "invalid choice: 'slurm'"),
        ([], "one of the arguments --env-id --split is required"),
    ],
)
def test_bad_input_exits_2(tmp_path, capsys, argv, fragment):
    with chdir(tmp_path):
        try:
            status = main([*argv, "--out", "data", "--no-progress"])
        except SystemExit as exc:  # argparse
            status = exc.code
    assert status == 2
    assert fragment in capsys.readouterr().err
    assert not (tmp_path / "data").exists()


def test_family_without_oracle_exits_2(tmp_path, capsys, monkeypatch):
    import mikasa_oracles

    monkeypatch.delitem(mikasa_oracles.ORACLES, "shell_game_touch")
    with chdir(tmp_path):
        status = main(["--env-id", "ShellGameTouch-VLA-v0", "--out", "data", "--no-progress"])
    assert status == 2
    assert "no oracle for 'ShellGameTouch-VLA-v0'" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()


def test_console_script_reports_bad_input():
    script = Path(sys.executable).with_name("mikasa-collect")
    assert script.exists(), "reinstall mikasa-oracles (pip install -e packages/mikasa-oracles)"
    proc = subprocess.run(
        [str(script), "--env-id", ENV_ID, "--num-episodes", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "--num-episodes" in proc.stderr and "must be >= 1, got 0" in proc.stderr


def test_split_selects_the_manifests_tasks_in_order():
    from mikasa_envs.manifest import list_tasks
    from mikasa_oracles.collect_cli import selected_env_ids

    assert selected_env_ids(None, "all") == [t.env_id for t in list_tasks()]
    short = selected_env_ids(None, "short")
    assert short == [t.env_id for t in list_tasks(split="short")] and 0 < len(short) < 90
    assert selected_env_ids([ENV_ID, "ShellGameTouch-VLA-v0"], None) == [ENV_ID, "ShellGameTouch-VLA-v0"]


def _collect_throughput_module():
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "collect_throughput.py"
    spec = importlib.util.spec_from_file_location("collect_throughput", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_plan_projection_fits_the_per_episode_cost(capsys):
    """benchmarks/collect_throughput.py: from long runs costing a worker 0.5 s per episode
    plus 10 ms per frame, the projection recovers both and adds the start-up per task;
    without two long runs it falls back to the families' rates and says so."""
    ct = _collect_throughput_module()
    workers, a, b = 16, 0.5, 0.010

    def row(family, frames_per_episode, episodes, startup=10.0, success=1.0):
        per_min = 60.0 * workers / (a + b * frames_per_episode)
        return {
            "path": "collect", "family": family, "env_id": f"{family}-v0", "workers": workers,
            "episodes": episodes, "frames": frames_per_episode * episodes, "startup_s": startup,
            "steady_episodes_per_min": per_min, "success_rate": success, "horizon": 100,
            "bytes": 1000 * frames_per_episode * episodes,
        }

    tasks = [("short", 100, "short-v0", True, True), ("long", 100, "long-v0", True, True),
             ("long", 200, "long2-v0", True, True), ("short", 50, "hidden-v0", True, False)]
    rows = [row("short", 20, 256), row("long", 100, 256, success=0.5)]
    plan = ct.project_plan(rows, tasks, 160)
    assert plan["model"]["episode_s"] == pytest.approx(a, abs=1e-3)
    assert plan["model"]["frame_s"] == pytest.approx(b, abs=1e-5)
    # short: 160 x (0.5 + 0.2) / 16; long: twice the attempts, 160 x 2 x (0.5 + 1.0) / 16;
    # long2 (horizon 200): 200 frames, 160 x 2 x (0.5 + 2.0) / 16; 10 s start-up each.
    expected = 3 * 10 + 160 * 0.7 / 16 + 320 * 1.5 / 16 + 320 * 2.5 / 16
    assert plan["hours"] == pytest.approx(expected / 3600, abs=0.006)
    assert plan["frames"] == 160 * (20 + 100 + 200) and plan["tasks"] == 3
    assert plan["disk_gb"] == pytest.approx(160 * 320 * 1000 / 1e9, abs=0.05)
    fallback = ct.project_plan([row("short", 20, 32), row("long", 100, 32)], tasks, 160)
    assert fallback["model"] is None
    assert "pessimistic" in capsys.readouterr().out
