"""``pip install mikasa-envs`` into an empty venv gives working environments."""

from __future__ import annotations

import subprocess
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

SMOKE = """
import gymnasium as gym
import numpy as np
import mikasa_envs

env = gym.make("RememberColor3-VLA-v0", obs_mode="rgb", control_mode="pd_ee_delta_pose")
obs, info = env.reset(seed=0)
obs, reward, terminated, truncated, info = env.step(np.zeros(7, dtype=np.float32))
assert obs["sensor_data"]["base_camera"]["rgb"].shape == (1, 128, 128, 3)
print("OK", info["language_instruction"])
"""


def test_mikasa_envs_alone_in_fresh_venv(tmp_path):
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    # torch==2.13.0: the CPU wheel this machine keeps locally (see README, dependency pins).
    subprocess.run(
        [python, "-m", "pip", "install", "-q", "torch==2.13.0", str(REPO / "packages" / "mikasa-envs")],
        check=True,
    )
    listed = subprocess.run([python, "-m", "pip", "list"], check=True, capture_output=True, text=True).stdout
    assert "mikasa-wrappers" not in listed and "mikasa-envs" in listed
    out = subprocess.run(
        [python, "-c", SMOKE], check=True, capture_output=True, text=True, cwd=tmp_path, timeout=600
    ).stdout
    assert "OK Observe the cube's color" in out


RL_SMOKE = """
import gymnasium as gym
import numpy as np
import mikasa_robo_suite.memory_envs  # the old import path registers the 32 ids
from mikasa_robo_suite.utils.wrappers import env_info

env = gym.make("ShellGameTouch-v0", obs_mode="rgb", control_mode="pd_joint_delta_pos")
wrappers, timeout = env_info("ShellGameTouch-v0")
for wrapper, kwargs in wrappers:
    env = wrapper(env, **kwargs)
obs, info = env.reset(seed=0)
obs, reward, terminated, truncated, info = env.step(np.zeros(8, dtype=np.float32))
assert obs["sensor_data"]["base_camera"]["rgb"].shape == (1, 128, 128, 3) and timeout == 90
print("OK", sorted(obs))
"""


def test_mikasa_robo_rl_in_fresh_venv(tmp_path):
    """``pip install ./legacy/rl`` gives working RL envs and wrappers; of this project it
    pulls only mikasa-envs and mikasa-wrappers (whose classes the release's wrappers are)."""
    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    # Our packages are not on PyPI: pip resolves mikasa-envs / mikasa-wrappers from these paths.
    local = [str(REPO / "packages" / "mikasa-envs"), str(REPO / "packages" / "mikasa-wrappers")]
    subprocess.run(
        [python, "-m", "pip", "install", "-q", "torch==2.13.0", *local, str(REPO / "legacy" / "rl")],
        check=True,
    )
    listed = subprocess.run([python, "-m", "pip", "list"], check=True, capture_output=True, text=True).stdout
    ours = sorted(line.split()[0] for line in listed.splitlines() if line.startswith("mikasa"))
    assert ours == ["mikasa-envs", "mikasa-robo-rl", "mikasa-wrappers"]
    out = subprocess.run(
        [python, "-c", RL_SMOKE], check=True, capture_output=True, text=True, cwd=tmp_path, timeout=600
    ).stdout
    assert "OK ['agent', 'extra', 'oracle_info', 'sensor_data', 'sensor_param', 'task_cue']" in out
