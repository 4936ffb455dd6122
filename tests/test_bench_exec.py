"""Fast tests of mikasa-bench's execution extras that need no simulator: render-device
settings and worker environments, executor selection, episode videos (frame layout, mp4
encoding, files written by the runner and linked by the report) on a fake env."""

from __future__ import annotations

import json
import os
from pathlib import Path

import gymnasium as gym
import imageio_ffmpeg
import numpy as np
import pytest
import torch
from mikasa_bench import cli
from mikasa_bench.errors import BenchError
from mikasa_bench.media.render import LAVAPIPE_ICD_ENV, gym_render_kwargs, worker_environment
from mikasa_bench.media.video import EpisodeVideo, compose_frame
from mikasa_bench.policies import PolicySpec
from mikasa_bench.protocol import BenchmarkConfig, protocol_settings
from mikasa_bench.protocol.tasks import BenchmarkTask
from mikasa_bench.results.report import write_report
from mikasa_bench.results.run_data import load_run
from mikasa_bench.results.store import RunStore
from mikasa_bench.runners.executor import InlineExecutor, LocalExecutor, make_executor
from mikasa_bench.runners.jobs import EpisodeJob, render_config
from mikasa_bench.runners.runner import execute_runs
from mikasa_bench.runners.worker import worker_env_vars

TASK = BenchmarkTask("RememberColor3-VLA-v0", "short", "Object", 25, "", "PPO")


class RenderingFakeEnv(gym.Env):
    """num_envs=1 torch env with a 64x64 ``render()`` and a 16x16 6-channel ``rgb`` obs;
    the render's red channel and the obs encode the step count."""

    def __init__(self, horizon: int = 3) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (7,), np.float32)
        self.observation_space = gym.spaces.Box(0, 255, (1, 16, 16, 6), np.uint8)
        self.max_episode_steps = horizon
        self.device = torch.device("cpu")
        self.t = 0

    def _obs(self) -> dict:
        return {"rgb": torch.full((1, 16, 16, 6), 10 * self.t, dtype=torch.uint8)}

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return self._obs(), {}

    def step(self, action):
        self.t += 1
        done = torch.tensor([self.t >= self.max_episode_steps])
        info = {"success": torch.tensor([self.t == 2])}
        return self._obs(), torch.tensor([1.0]), torch.tensor([False]), done, info

    def render(self):
        frame = torch.zeros(1, 64, 64, 3, dtype=torch.uint8)
        frame[..., 0] = 20 * self.t
        return frame


# --------------------------------------------------------------------------------------
# render device settings
# --------------------------------------------------------------------------------------


def test_render_device_settings_are_validated_and_recorded():
    with pytest.raises(ValueError, match="unsupported render_device 'tpu'"):
        BenchmarkConfig(render_device="tpu")
    with pytest.raises(ValueError, match="needs render_device='cpu'"):
        BenchmarkConfig(render_device="auto", gpu_render_workers=2)
    mixed = BenchmarkConfig(render_device="cpu", gpu_render_workers=2)
    assert [mixed.render_device_for(i) for i in range(4)] == ["gpu", "gpu", "cpu", "cpu"]
    settings = protocol_settings(mixed)
    assert settings["render_device"] == "mixed: 2 worker(s) gpu, the rest cpu"
    assert settings["canonical"] is True  # where pixels are rendered is not a deviation
    assert protocol_settings(BenchmarkConfig())["render_device"] == "auto"
    # run.json files written before these fields existed still load.
    old = BenchmarkConfig().to_dict()
    for key in ("render_device", "gpu_render_workers"):
        old.pop(key)
    assert BenchmarkConfig(**old).render_device == "auto"
    assert gym_render_kwargs("auto") == {}
    assert gym_render_kwargs("cpu") == {"render_backend": "sapien_cpu"}
    assert gym_render_kwargs("gpu") == {"render_backend": "sapien_cuda"}


def test_cpu_rendering_workers_see_only_lavapipe(tmp_path, monkeypatch):
    icd = tmp_path / "lvp_icd.x86_64.json"
    icd.write_text("{}")
    monkeypatch.setenv(LAVAPIPE_ICD_ENV, str(icd))
    env = worker_environment("cpu", lp_threads=0)
    assert env == {"LP_NUM_THREADS": "0", "VK_ICD_FILENAMES": str(icd), "VK_DRIVER_FILES": str(icd)}
    assert "VK_ICD_FILENAMES" not in worker_environment("gpu")
    assert "VK_ICD_FILENAMES" not in worker_environment("auto")
    # A mixed pool: worker 0 renders on the GPU, worker 1 on lavapipe.
    config = BenchmarkConfig(render_device="cpu", gpu_render_workers=1)
    assert "VK_ICD_FILENAMES" not in worker_env_vars(config, 0, 2)
    assert worker_env_vars(config, 1, 2)["VK_ICD_FILENAMES"] == str(icd)


@pytest.mark.parametrize(
    ("visible", "device_nodes", "index", "seen"),
    [
        (None, 2, 0, "0"),
        (None, 2, 3, "1"),  # round robin over the machine's GPUs
        (None, 0, 1, None),  # no GPU: nothing set
        ("2,3", 0, 1, "3"),
        (" 1 , 0", 0, 0, "1"),
        ("0,-1,1", 0, 1, "0"),  # CUDA reads up to the first invalid entry
        ("", 2, 0, ""),
        ("-1", 2, 0, "-1"),
    ],
)
def test_pool_workers_see_one_gpu_each(monkeypatch, visible, device_nodes, index, seen):
    # ManiSkill's reset forks torch's RNG on every visible GPU: a worker must see one (or none).
    from mikasa_envs import workers

    monkeypatch.setattr(workers.glob, "glob", lambda _: [f"/dev/nvidia{i}" for i in range(device_nodes)])
    if visible is None:
        monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    else:
        monkeypatch.setenv("CUDA_VISIBLE_DEVICES", visible)
    workers.use_one_gpu(index)
    assert os.environ.get("CUDA_VISIBLE_DEVICES") == seen


def test_one_pool_needs_one_render_setting():
    spec = PolicySpec("zero", label="zero")
    jobs = [
        EpisodeJob(0, TASK, 0, 1, BenchmarkConfig(render_device="cpu"), spec),
        EpisodeJob(1, TASK, 0, 1, BenchmarkConfig(render_device="gpu"), spec),
    ]
    with pytest.raises(BenchError, match="different render devices"):
        render_config(jobs)


def test_executor_selection_errors():
    assert isinstance(make_executor("local", 0), InlineExecutor)
    assert isinstance(make_executor("local", 3), LocalExecutor)
    with pytest.raises(BenchError, match="unknown executor 'dask'"):
        make_executor("dask")
    with pytest.raises(BenchError, match="only used by --executor ray"):
        make_executor("local", 2, address="ray://head:10001")
    with pytest.raises(BenchError, match="cannot be used with Ray"):
        make_executor("ray", 0)


# --------------------------------------------------------------------------------------
# videos
# --------------------------------------------------------------------------------------


def test_video_frame_layout():
    render = np.zeros((512, 512, 3), np.uint8)
    render[..., 2] = 200
    rgb = np.zeros((1, 128, 128, 6), np.uint8)
    rgb[..., 0] = 100  # top camera: red
    rgb[..., 4] = 150  # wrist camera: green
    frame = compose_frame(torch.from_numpy(render)[None], {"rgb": torch.from_numpy(rgb)})
    assert frame.shape == (512, 768, 3) and frame.dtype == np.uint8
    assert (frame[:, :512] == render).all()
    assert tuple(frame[200, 700]) == (100, 0, 0)  # top panel, away from its label
    assert tuple(frame[450, 700]) == (0, 150, 0)  # wrist panel
    assert frame[10:30, 520:560].max() == 255  # the "top" label is drawn in white
    # No rgb observation (state mode): both panels show the scene.
    frame = compose_frame(render, {"state": np.zeros(3)})
    assert tuple(frame[450, 700]) == (0, 0, 200)


def test_episode_video_encodes_h264(tmp_path):
    with EpisodeVideo(tmp_dir=tmp_path) as video:
        for i in range(5):
            video.add(np.full((64, 96, 3), 40 * i, np.uint8))
        data = video.finish()
    assert list(tmp_path.iterdir()) == []  # the temp file is gone
    path = tmp_path / "v.mp4"
    path.write_bytes(data)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert meta["size"] == (96, 64) and meta["codec"] == "h264" and meta["fps"] == 30
    assert len(list(reader)) == 5


def test_runner_writes_videos_before_journal_and_report_links_them(tmp_path, monkeypatch):
    import mikasa_bench.runners.worker as ex

    made = []

    def fake_make(env_id, config):
        made.append(config)
        return RenderingFakeEnv(horizon=3)

    monkeypatch.setattr(ex, "make_benchmark_env", fake_make)
    config = BenchmarkConfig(n_episodes=2, start_seed=7, obs_mode="state", save_videos=True)
    store = RunStore.create(
        tmp_path / "run",
        tasks=[TASK],
        policy=PolicySpec("zero", label="zero"),
        config=config,
        selection={"env_ids": [TASK.env_id]},
        commit=None,
    )
    execute_runs([store], InlineExecutor(), progress=False)
    assert made[0].save_videos
    recs = [json.loads(x) for x in store.journal_path.read_text().splitlines()]
    rels = [f"videos/{TASK.env_id}/episode_{i:04d}.mp4" for i in range(2)]
    assert [r["video"] for r in recs] == rels
    for rel in rels:
        reader = imageio_ffmpeg.read_frames(str(store.run_dir / rel))
        assert next(reader)["size"] == (96, 64)  # 64x64 scene + 32-wide camera column
        assert len(list(reader)) == 4  # before each of the 3 steps + after the last
    result = json.loads((store.run_dir / f"{TASK.env_id}.json").read_text())
    assert result["videos"] == rels and result["successes"] == [True, True]
    meta = json.loads((store.run_dir / "meta" / "run.json").read_text())
    assert meta["config"]["save_videos"] and meta["sessions"][0]["execution"]["name"] == "inline"
    md, html = write_report([load_run(store.run_dir)], tmp_path / "report")
    assert f"[0](<../run/{rels[0]}>)" in md.read_text()
    assert f"href='../run/{rels[1]}'" in html.read_text()


def test_cli_video_and_render_options_are_run_defining(tmp_path, capsys):
    assert cli.main(["run", "--resume", str(tmp_path), "--video", "--render-device", "cpu"]) == 2
    assert "do not pass --video, --render-device" in capsys.readouterr().err
    args = ["run", "--task", TASK.env_id, "--policy", "zero", "--out", str(tmp_path / "x")]
    assert cli.main([*args, "--gpu-render-workers", "2"]) == 2
    assert "needs render_device='cpu'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_video_paths_follow_the_spec():
    from mikasa_bench.media.video import video_relpath

    assert (
        video_relpath("RememberColor3-VLA-v0", 7) == "videos/RememberColor3-VLA-v0/episode_0007.mp4"
    )
    assert Path(video_relpath("A", 0)).name == "episode_0000.mp4"


def test_envs_per_process_default_follows_the_render_device(monkeypatch):
    from mikasa_bench.runners import executor

    gpu = BenchmarkConfig(render_device="gpu")
    cpu = BenchmarkConfig(render_device="cpu")
    mixed = BenchmarkConfig(render_device="cpu", gpu_render_workers=1)
    assert executor.envs_per_process(gpu, 0, None) == executor.GPU_ENVS_PER_WORKER
    assert executor.envs_per_process(cpu, 0, None) == 1
    assert [executor.envs_per_process(mixed, i, None) for i in (0, 1)] == [executor.GPU_ENVS_PER_WORKER, 1]
    assert executor.envs_per_process(cpu, 0, 3) == 3  # as asked
    monkeypatch.setattr(executor, "gpu_visible", lambda: False)
    assert executor.envs_per_process(BenchmarkConfig(render_device="auto"), 0, None) == 1
    with pytest.raises(BenchError, match="--envs-per-worker must be >= 1"):
        LocalExecutor(2, 0)
