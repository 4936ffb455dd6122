"""ManiSkill's trajectory replay of the RL ids: ``python -m mikasa_envs.replay_trajectory``
registers them through mikasa-envs' plugin hook (the entry point group
``mikasa_envs.plugins``, which mikasa-robo-rl joins), not by importing mikasa_robo_rl."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib.metadata import entry_points

import gymnasium as gym
import mikasa_robo_rl  # noqa: F401  (registers the RL ids here, to record)
import torch
from mani_skill.utils.wrappers import RecordEpisode
from mikasa_envs.replay_trajectory import PLUGIN_GROUP

ENV_ID = "RememberColor3-v0"  # horizon 60


def test_mikasa_robo_rl_is_a_mikasa_envs_plugin():
    plugins = {(e.name, e.value) for e in entry_points(group=PLUGIN_GROUP)}
    assert ("rl", "mikasa_robo_rl") in plugins


def test_replay_tool_replays_an_rl_episode(tmp_path):
    env = gym.make(ENV_ID, num_envs=1, obs_mode="state", control_mode="pd_joint_delta_pos",
                   reward_mode="normalized_dense", sim_backend="cpu")
    env = RecordEpisode(env, str(tmp_path), save_trajectory=True, save_video=False,
                        trajectory_name=ENV_ID)
    env.reset(seed=3)
    for _ in range(60):
        env.step(torch.zeros(1, 8))
    env.close()
    result = subprocess.run(
        [sys.executable, "-m", "mikasa_envs.replay_trajectory",
         "--traj-path", str(tmp_path / f"{ENV_ID}.h5"), "--use-env-states", "--save-traj",
         "--allow-failure"],
        capture_output=True, text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "1/1=100.00% demos saved" in result.stdout, result.stdout[-2000:]
    assert (tmp_path / f"{ENV_ID}.state.pd_joint_delta_pos.physx_cpu.h5").is_file()
