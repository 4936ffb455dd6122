"""mikasa-bench end to end on the simulator, kept small (state mode, one short task,
2 episodes): worker-count independence, resume of an interrupted run, a policy that
returns the wrong shape mid-run, episode videos (which must not change results, also in
rgb mode) and the Ray executor on a bounded local Ray instance.

State mode is the explicitly non-canonical fast override; the env, seeds, action path
and policies are the same as in rgb mode.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from mikasa_bench import cli
from mikasa_bench.policies import resolve_policy
from mikasa_bench.protocol import BenchmarkConfig
from mikasa_bench.protocol.tasks import resolve_tasks
from mikasa_bench.results.store import RunStore

TASK = "RememberColor3-VLA-v0"
COMMON = [
    "--task",
    TASK,
    "--num-episodes",
    "2",
    "--obs-mode",
    "state",
    "--no-progress",
    "--no-report",
]
PER_EPISODE = ("successes", "returns", "episode_lengths", "episode_seeds")


def _task_json(run_dir: Path, env_id: str = TASK) -> dict:
    return json.loads((run_dir / f"{env_id}.json").read_text())


@pytest.fixture(scope="module")
def baseline(tmp_path_factory) -> Path:
    """The oracle on one task with a single worker process."""
    out = tmp_path_factory.mktemp("bench") / "w1"
    assert (
        cli.main(["run", *COMMON, "--policy", "oracle", "--workers", "1", "--out", str(out)]) == 0
    )
    return out


def test_oracle_run_writes_spec_files(baseline):
    r = _task_json(baseline)
    assert r["episode_seeds"] == [4242424242, 4242424243]
    assert r["successes"] == [True, True] and r["episode_lengths"] == [25, 25]
    assert r["model"]["name"] == "oracle" and r["obs_mode"] == "state"
    s = json.loads((baseline / "summary.json").read_text())
    assert s["complete"] and s["per_task_sr"] == {TASK: 1.0}
    assert s["protocol"]["canonical"] is False
    assert "obs_mode='state' (canonical 'rgb')" in s["protocol"]["deviations"]
    assert s["versions"]["mani-skill"] and s["wall_time_s"] > 0


def test_workers_1_and_2_give_identical_episodes(baseline, tmp_path):
    out = tmp_path / "w2"
    assert (
        cli.main(["run", *COMMON, "--policy", "oracle", "--workers", "2", "--out", str(out)]) == 0
    )
    a, b = _task_json(baseline), _task_json(out)
    assert {k: a[k] for k in PER_EPISODE} == {k: b[k] for k in PER_EPISODE}


def test_two_envs_per_worker_give_identical_episodes(baseline, tmp_path):
    # One process, two env threads (on a GPU they would share render passes).
    out = tmp_path / "w1x2"
    argv = ["run", *COMMON, "--policy", "oracle", "--workers", "1", "--envs-per-worker", "2"]
    assert cli.main([*argv, "--out", str(out)]) == 0
    a, b = _task_json(baseline), _task_json(out)
    assert {k: a[k] for k in PER_EPISODE} == {k: b[k] for k in PER_EPISODE}


def test_env_threads_keep_global_rng_policies_reproducible(tmp_path):
    # The reference demo policy draws from torch's global RNG: threads of one process share
    # it, so each episode's policy calls must see the episode's own RNG states.
    policy = ["--policy", "mikasa_bench.policies:DummyChunkPolicy", "--workers", "1"]
    runs = {}
    for k in ("1", "2"):
        out = tmp_path / f"k{k}"
        assert cli.main(["run", *COMMON, *policy, "--envs-per-worker", k, "--out", str(out)]) == 0
        runs[k] = {key: _task_json(out)[key] for key in PER_EPISODE}
    assert runs["1"] == runs["2"]


def test_an_episode_does_not_depend_on_what_its_worker_played_before():
    # PhysX keeps contact caches across resets; the protocol fixes each episode's history
    # (a fresh scene every 5 episodes, in order), and a worker replays what it lacks.
    from mikasa_bench.runners.jobs import EpisodeJob
    from mikasa_bench.runners.worker import EpisodeWorker

    config = BenchmarkConfig(n_episodes=7, obs_mode="state", sim_backend="cpu")
    task = resolve_tasks(env_ids=["RememberShapeAndColor5x3-VLA-v0"]).tasks[0]
    policy = resolve_policy("oracle")
    jobs = [EpisodeJob(0, task, i, seed, config, policy) for i, seed in enumerate(config.episode_seeds())]

    def play(order):
        worker = EpisodeWorker(0)
        try:
            return {i: worker.run(jobs[i]).result for i in order}
        finally:
            worker.close()

    in_order = play(range(7))
    shuffled = play([6, 2, 5, 0, 1, 3, 4])
    assert shuffled == in_order
    assert all(r.success_once for r in in_order.values())


def test_resume_after_interruption_loses_and_duplicates_nothing(baseline, tmp_path):
    # Pre-write an interrupted run: episode 0 journaled (with a marker wall time),
    # episode 1 torn mid-write by kill -9.
    config = BenchmarkConfig(n_episodes=2, obs_mode="state", sim_backend="cpu")
    selection = resolve_tasks(env_ids=[TASK])
    store = RunStore.create(
        tmp_path / "run",
        tasks=selection.tasks,
        policy=resolve_policy("oracle"),
        config=config,
        selection=selection.to_dict(),
        commit=None,
    )
    done = _task_json(baseline)
    rec = {
        "env_id": TASK,
        "episode": 0,
        "seed": 4242424242,
        "success_once": done["successes"][0],
        "episode_return": done["returns"][0],
        "n_steps": done["episode_lengths"][0],
        "action_chunk_size": 1,
        "wall_s": 999.0,
    }
    with open(store.journal_path, "a") as f:
        f.write(json.dumps(rec) + "\n" + '{"env_id": "RememberColor3-VLA-v0", "epis')
    assert (
        cli.main(
            [
                "run",
                "--resume",
                str(store.run_dir),
                "--workers",
                "0",
                "--no-progress",
                "--no-report",
            ]
        )
        == 0
    )
    lines = [json.loads(x) for x in store.journal_path.read_text().splitlines()]
    assert [(x["episode"], x["wall_s"] == 999.0) for x in lines] == [(0, True), (1, False)]
    r = _task_json(store.run_dir)
    assert {k: r[k] for k in PER_EPISODE} == {k: done[k] for k in PER_EPISODE}
    assert r["wall_time_s"] >= 999.0  # episode 0 came from the journal, it was not rerun
    s_resumed = json.loads((store.run_dir / "summary.json").read_text())
    s_base = json.loads((baseline / "summary.json").read_text())
    for key in (
        "split",
        "sr_split",
        "sr_per_memory_type",
        "tasks",
        "per_task_sr",
        "per_task_mean_return",
    ):
        assert s_resumed[key] == s_base[key]
    # Resuming a finished run runs nothing and changes no result.
    assert (
        cli.main(
            [
                "run",
                "--resume",
                str(store.run_dir),
                "--workers",
                "0",
                "--no-progress",
                "--no-report",
            ]
        )
        == 0
    )
    assert _task_json(store.run_dir)["returns"] == r["returns"]


def test_wrong_action_shape_stops_with_clear_error_and_keeps_results(tmp_path, capsys):
    policy = tmp_path / "shape_policy.py"
    policy.write_text(
        "import numpy as np\n\n"
        "class Policy:\n"
        "    def __init__(self, env_id):\n"
        "        self.bad = env_id.startswith('FindImposter')\n\n"
        "    def forward(self, obs):\n"
        "        return np.zeros(3 if self.bad else 7, np.float32)\n"
    )
    out = tmp_path / "run"
    argv = [
        "run",
        "--task",
        TASK,
        "--task",
        "FindImposterColor3-VLA-v0",
        "--num-episodes",
        "1",
        "--obs-mode",
        "state",
        "--policy",
        str(policy),
        "--workers",
        "0",
        "--no-progress",
        "--no-report",
        "--out",
        str(out),
    ]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "FindImposterColor3-VLA-v0 episode 0 (seed 4242424242)" in err
    assert "returned an action of shape (3,); expected one action of shape (7,)" in err
    assert "--resume" in err
    # The task finished before the failure is on disk, and the summary covers it.
    assert _task_json(out)["successes"] == [False]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["tasks"] == [TASK] and summary["tasks_pending"] == ["FindImposterColor3-VLA-v0"]
    shutil.rmtree(out)


# --------------------------------------------------------------------------------------
# videos, render settings, Ray
# --------------------------------------------------------------------------------------


def _journal(run_dir: Path) -> list[dict]:
    return [json.loads(x) for x in (run_dir / "meta" / "episodes.jsonl").read_text().splitlines()]


def test_video_env_observes_and_scores_like_the_canonical_env():
    """The video chain (render_mode rgb_array + overlays, render() before every step)
    gives bit-identical rgb observations, proprio and rewards."""
    from mikasa_bench.media.video import compose_frame
    from mikasa_bench.runners.episode import make_benchmark_env

    plain = make_benchmark_env(TASK, BenchmarkConfig(n_episodes=1, sim_backend="cpu"))
    video = make_benchmark_env(
        TASK, BenchmarkConfig(n_episodes=1, sim_backend="cpu", save_videos=True)
    )
    try:
        obs_a, _ = plain.reset(seed=4242424242)
        obs_b, _ = video.reset(seed=4242424242)
        rng = np.random.default_rng(0)
        for _ in range(6):
            frame = compose_frame(video.render(), obs_b)
            assert frame.shape == (512, 768, 3)
            assert torch.equal(obs_a["rgb"], obs_b["rgb"])
            assert torch.equal(obs_a["proprio"], obs_b["proprio"])
            action = torch.from_numpy(rng.uniform(-1, 1, (1, 7)).astype(np.float32))
            obs_a, r_a, *_ = plain.step(action)
            obs_b, r_b, *_ = video.step(action)
            assert torch.equal(r_a, r_b)
        assert torch.equal(obs_a["rgb"], obs_b["rgb"])
    finally:
        plain.close()
        video.close()


def test_video_run_records_one_mp4_per_episode_with_unchanged_results(baseline, tmp_path):
    import imageio_ffmpeg

    out = tmp_path / "video"
    argv = [a for a in COMMON if a != "--no-report"]
    # In this process (--workers 0): the rgb test above already paid lavapipe's one-off
    # pipeline compilation here; the worker path is the same `EpisodeWorker`.
    argv += ["--policy", "oracle", "--workers", "0", "--video", "--out", str(out)]
    assert cli.main(["run", *argv]) == 0
    a, b = _task_json(baseline), _task_json(out)
    assert {k: a[k] for k in PER_EPISODE} == {k: b[k] for k in PER_EPISODE}
    rels = [f"videos/{TASK}/episode_{i:04d}.mp4" for i in range(2)]
    assert b["videos"] == rels
    for rel, n_steps in zip(rels, b["episode_lengths"], strict=True):
        reader = imageio_ffmpeg.read_frames(str(out / rel))
        meta = next(reader)
        # 512x512 scene view + a 256-wide column with the two camera panels.
        assert meta["size"] == (768, 512) and meta["codec"] == "h264"
        assert len(list(reader)) == n_steps + 1
    assert not list(out.rglob("*.tmp"))  # written atomically, no leftovers
    assert all(r["render"].startswith(("cpu: ", "gpu: ")) for r in _journal(out))
    assert f"[1](<{rels[1]}>)" in (out / "report.md").read_text()


def test_ray_executor_matches_local_workers(baseline, tmp_path):
    ray = pytest.importorskip("ray")
    # A bounded local instance: 2 CPUs, no dashboard, a small object store.
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        object_store_memory=100 * 1024**2,
        log_to_driver=False,
    )
    try:
        out = tmp_path / "ray"
        argv = ["--policy", "oracle", "--executor", "ray", "--workers", "2", "--out", str(out)]
        assert cli.main(["run", *COMMON, *argv]) == 0
        assert ray.is_initialized()  # an instance the caller started is left running
    finally:
        ray.shutdown()
    a, b = _task_json(baseline), _task_json(out)
    assert {k: a[k] for k in PER_EPISODE} == {k: b[k] for k in PER_EPISODE}
    meta = json.loads((out / "meta" / "run.json").read_text())
    assert meta["sessions"][0]["execution"] == {"name": "ray", "workers": 2, "address": "local"}
    assert sorted(r["episode"] for r in _journal(out)) == [0, 1]
