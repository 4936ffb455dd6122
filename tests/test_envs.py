"""Every registered env: construction, observation contract, info keys, rewards."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from conftest import CANONICAL_IDS, REGISTERED_IDS
from mikasa_envs import get_task
from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.manifest import SELECTION_FAMILIES
from mikasa_wrappers import apply_mikasa_vla_wrappers

# Keys every task's info carries, and the ones the six selection families add (common.md §6).
INFO_KEYS = {"elapsed_steps", "success", "task_cue", "language_instruction", "oracle_info", "reward_dict"}
SELECTION_INFO_KEYS = INFO_KEYS | {"obj_to_goal_pos", "is_obj_placed", "is_robot_static"}


def _matches_instruction(instruction: str, env_id: str) -> bool:
    """The instruction equals the manifest's, whose ``{field}`` placeholders match any value.

    Rotate gives a list, one string per env (rotate_lenient.md); each must match.
    """
    if isinstance(instruction, list):
        return bool(instruction) and all(_matches_instruction(i, env_id) for i in instruction)
    template = get_task(env_id).language_instruction
    pattern = "".join(".+" if part.startswith("{") else re.escape(part) for part in re.split(r"(\{\w+\})", template))
    return isinstance(instruction, str) and re.fullmatch(pattern, instruction) is not None


def _selection_state_dim(env) -> int:
    base = env.unwrapped
    oracle = 1 if base.oracle_info.ndim == 1 else base.oracle_info.shape[1]
    return 9 + 9 + 7 + oracle + 3 * base.num_objects


@pytest.mark.parametrize("env_id", REGISTERED_IDS)
def test_state_mode_contract(make_env, env_id):
    selection = get_task(env_id).family in SELECTION_FAMILIES
    keys = SELECTION_INFO_KEYS if selection else INFO_KEYS
    env = make_env(env_id, reward_mode="normalized_dense")
    base: MikasaVLABaseEnv = env.unwrapped
    obs, info = env.reset(seed=7)
    assert obs.dtype == torch.float32 and obs.ndim == 2 and obs.shape[0] == 1
    state_dim = obs.shape[1]
    if selection:
        assert state_dim == _selection_state_dim(env)
        assert info["task_cue"] is None and info["oracle_info"].dtype == torch.uint8
        lo, hi = base.CUE_PHASE_STEPS
        assert lo <= int(base.cue_steps_per_env[0]) <= hi
        lo, hi = base.EMPTY_PHASE_STEPS
        assert lo <= int(base.empty_steps_per_env[0]) <= hi
    assert keys - {"reward_dict"} <= set(info)
    assert _matches_instruction(info["language_instruction"], env_id)
    assert info["reward_dict"] is None
    assert isinstance(info["oracle_info"], torch.Tensor) and info["oracle_info"].shape[0] == 1
    rewards = []
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(np.zeros(7, dtype=np.float32))
        rewards.append(float(reward[0]))
        assert set(info) >= keys
        assert not bool(terminated[0]) and not bool(truncated[0])
        assert obs.shape == (1, state_dim) and obs.dtype == torch.float32
        assert _matches_instruction(info["language_instruction"], env_id)
    assert all(0.0 <= r <= 1.0 for r in rewards)
    # reward_dict is one step stale (computed after the info is built), as upstream.
    assert isinstance(info["reward_dict"], dict) and info["reward_dict"]
    if selection:
        assert "reaching_reward" in info["reward_dict"]


@pytest.mark.parametrize("env_id", CANONICAL_IDS)
def test_rgb_mode_through_canonical_wrappers(make_env, env_id):
    env = apply_mikasa_vla_wrappers(make_env(env_id, obs_mode="rgb", reward_mode="normalized_dense"))
    obs, info = env.reset(seed=3)
    # task_cue stays in the VLA observation for the families that set it (wrappers.md §2).
    has_cue = env.unwrapped.task_cue is not None
    assert list(obs) == ["proprio", "rgb", "task_cue"] if has_cue else ["proprio", "rgb"]
    assert obs["rgb"].shape == (1, 128, 128, 6) and obs["rgb"].dtype == torch.uint8
    assert obs["proprio"].shape == (1, 7) and obs["proprio"].dtype == torch.float32
    obs, reward, terminated, truncated, info = env.step(np.zeros(7, dtype=np.float32))
    assert obs["rgb"].shape == (1, 128, 128, 6)
    assert 0.0 <= float(reward[0]) <= 1.0
    assert _matches_instruction(info["language_instruction"], env_id)
    assert env.max_episode_steps == get_task(env_id).max_episode_steps
    # Both cameras see something (not a blank frame).
    assert obs["rgb"][..., :3].float().std() > 5 and obs["rgb"][..., 3:].float().std() > 5


def test_truncates_at_manifest_horizon(make_env):
    env = make_env("RememberColor3-VLA-v0")
    env.reset(seed=0)
    for step in range(1, 26):
        *_, truncated, info = env.step(None)
        assert bool(truncated[0]) == (step >= 25)


def test_max_episode_steps_override(make_env):
    env = make_env("RememberShape3-VLA-v0", max_episode_steps=5)
    env.reset(seed=0)
    for _ in range(5):
        *_, truncated, _ = env.step(None)
    assert bool(truncated[0])


@pytest.mark.parametrize("reward_mode", ["sparse", "dense", "none"])
def test_reward_modes(make_env, reward_mode):
    env = make_env("FindImposterColor3-VLA-v0", reward_mode=reward_mode)
    env.reset(seed=1)
    _, reward, *_ = env.step(np.zeros(7, dtype=np.float32))
    if reward_mode == "dense":
        # A still robot far from the (hidden) target earns ≈ 0.5 (stillness term).
        assert 0.4 < float(reward[0]) < 0.6
    else:
        assert float(reward[0]) == 0.0


@pytest.mark.parametrize(
    "control_mode, action_dim",
    [("pd_joint_delta_pos", 8), ("pd_joint_pos", 8), ("pd_ee_delta_pos", 4), ("pd_ee_delta_pose", 7)],
)
def test_other_panda_control_modes(make_env, control_mode, action_dim):
    env = make_env("RememberColor5-VLA-v0", control_mode=control_mode)
    env.reset(seed=0)
    assert env.action_space.shape == (action_dim,)
    env.step(env.action_space.sample())


def test_panda_without_wrist_camera(make_env):
    env = make_env("RememberColor3-VLA-v0", obs_mode="rgb", robot_uids="panda")
    obs, _ = env.reset(seed=0)
    assert list(obs["sensor_data"]) == ["base_camera"]


@pytest.mark.parametrize(
    "env_id",
    [
        "RememberColor3-VLA-v0",
        "RememberShape5-VLA-v0",
        "RememberShapeAndColor3x2-VLA-v0",
        "FindImposterColor3-VLA-v0",
        "FindImposterShape3-VLA-v0",
        "FindImposterShapeAndColor3x2-VLA-v0",
    ],
)
def test_overlays_render_for_each_family(make_env, env_id):
    frames = []
    for include_overlays in (False, True):
        env = make_env(env_id, obs_mode="rgb", render_mode="rgb_array")
        env = apply_mikasa_vla_wrappers(env, include_overlays=include_overlays)
        env.reset(seed=0)
        env.step(np.zeros(7, dtype=np.float32))
        frame = env.render()
        frames.append(np.asarray(frame.cpu() if isinstance(frame, torch.Tensor) else frame))
    plain, overlaid = frames
    assert overlaid.shape == plain.shape and overlaid.shape[-1] == 3
    # Text and the target swatch are drawn in the top-left corner; the scene is unchanged elsewhere.
    assert (overlaid[..., :100, :300, :] != plain[..., :100, :300, :]).mean() > 0.01
    np.testing.assert_array_equal(overlaid[..., 300:, 300:, :], plain[..., 300:, 300:, :])


def test_gymnasium_module_entry_point_registers_without_import():
    """``gym.make("mikasa_envs:<id>")`` imports the package and finds the env."""
    import subprocess
    import sys

    code = (
        "import gymnasium as gym; "
        "env = gym.make('mikasa_envs:RememberColor3-VLA-v0', obs_mode='state'); "
        "print(type(env.unwrapped).__name__)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().endswith("RememberColor3VLAEnv")
