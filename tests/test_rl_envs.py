"""The 32 RL ids of mikasa-robo-rl: registration, contract, timing, wrappers, old paths."""

from __future__ import annotations

import subprocess
import sys

import gymnasium as gym
import mikasa_robo_rl
import numpy as np
import pytest
import torch
from mani_skill.utils.registration import REGISTERED_ENVS
from mikasa_robo_rl import get_rl_task, list_rl_tasks, rl_env_ids
from mikasa_robo_rl.wrappers import apply_rl_wrappers, env_info
from mikasa_wrappers import (
    DebugRewardWrapper,
    InitialZeroActionWrapper,
    RememberColorInfoWrapper,
    RenderRewardInfoWrapper,
    RenderStepInfoWrapper,
    RotateRenderAngleInfoWrapper,
    ShellGameRenderCupInfoWrapper,
    StateOnlyTensorToDictWrapper,
)

RL_IDS = list(rl_env_ids())
ROTATE_IDS = [t.env_id for t in list_rl_tasks() if t.task_cue is not None]


@pytest.fixture
def make_rl_env(make_env):
    """``make_rl_env(env_id, **kwargs)``: ``make_env`` with the RL release's defaults."""

    def _make(env_id: str, **kwargs) -> gym.Env:
        kwargs.setdefault("control_mode", "pd_joint_delta_pos")
        kwargs.setdefault("reward_mode", "normalized_dense")
        return make_env(env_id, **kwargs)

    return _make


def _random_actions(n: int, seed: int, dim: int = 8) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (n, dim)).astype(np.float32)


# ------------------------------------------------------------------------- manifest
def test_manifest_has_the_32_tasks_of_the_release():
    assert len(RL_IDS) == 32 and RL_IDS[0] == "ShellGameTouch-v0" and RL_IDS[-1] == "ChainOfColors7-v0"
    assert len(mikasa_robo_rl.groups()) == 12
    counts = {m: len(list_rl_tasks(memory_type=m)) for m in mikasa_robo_rl.MEMORY_TYPES}
    assert counts == {"Object": 14, "Spatial": 9, "Sequential": 3, "Capacity": 6}
    assert ROTATE_IDS == [i for i in RL_IDS if i.startswith("Rotate")]
    with pytest.raises(ValueError, match="unknown group 'Shell'; accepted values: ShellGame"):
        list_rl_tasks(group="Shell")


@pytest.mark.parametrize("env_id", RL_IDS)
def test_state_mode_contract(make_rl_env, env_id):
    task = get_rl_task(env_id)
    env = make_rl_env(env_id)
    base = env.unwrapped
    assert env_id in gym.registry and type(base).__name__ == env_id.replace("-v0", "Env")
    # The release's normalised dense divides by its listed constant; a success step earns what
    # the VLA family's does (RotateLenient 60, Bunch/Seq/Chain 400: not the divisor).
    assert base.normalized_dense_divisor == task.reward_divisor
    assert base.DENSE_REWARD_MAX == REGISTERED_ENVS[task.vla_env_id].cls.DENSE_REWARD_MAX
    assert base.single_action_space.shape == (8,)
    obs, info = env.reset(seed=5)
    assert obs.dtype == torch.float32 and obs.shape[0] == 1
    assert (info["task_cue"] is not None) == (task.task_cue is not None)
    assert isinstance(info["oracle_info"], torch.Tensor)
    rewards = []
    for action in _random_actions(4, seed=1):
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(float(reward[0]))
        assert not bool(truncated[0])
    assert obs.dtype == torch.float32
    assert all(0.0 <= r <= 1.0 for r in rewards)


@pytest.mark.parametrize(
    "env_id, cue, empty",
    [
        ("ShellGameTouch-v0", 5, 0),
        ("RememberColor9-v0", 5, 5),
        ("RememberShapeAndColor5x3-v0", 5, 5),
        ("BunchOfColors7-v0", 5, 5),
        ("SeqOfColors5-v0", 25, 5),
        ("ChainOfColors3-v0", 15, 5),
        ("InterceptFast-v0", 0, 0),
        ("TakeItBack-v0", 0, 0),
    ],
)
def test_fixed_phase_timing(make_rl_env, env_id, cue, empty):
    env = make_rl_env(env_id)
    for seed in (0, 1, 2):
        env.reset(seed=seed)
        base = env.unwrapped
        assert (int(base.cue_steps_per_env[0]), int(base.empty_steps_per_env[0])) == (cue, empty)


@pytest.mark.parametrize("env_id", ["RememberColor3-v0", "ShellGameTouch-v0", "BunchOfColors3-v0", "TakeItBack-v0"])
def test_truncates_at_the_rl_horizon(make_rl_env, env_id):
    horizon = get_rl_task(env_id).max_episode_steps
    env = make_rl_env(env_id)
    env.reset(seed=0)
    truncations = [bool(env.step(None)[3][0]) for _ in range(horizon)]
    assert truncations == [False] * (horizon - 1) + [True]


def test_shell_game_cue_shows_the_ball_for_five_steps(make_rl_env):
    env = make_rl_env("ShellGameTouch-v0")
    env.reset(seed=3)
    base = env.unwrapped
    heights = []
    for _ in range(7):
        heights.append(float(base.mugs[0].pose.p[0, 2]))
        env.step(None)
    # Mugs are parked out of sight while elapsed_steps < 5, then stand on the table.
    assert all(z > 10 for z in heights[:5]) and all(z < 1 for z in heights[5:])


def test_rotate_lenient_success_counts_only_after_step_five(make_rl_env):
    env = make_rl_env("RotateLenientPos-v0")
    env.reset(seed=0)
    base = env.unwrapped
    base.task_cue[:] = 0.0  # target = the start heading: the angle is right from the start
    success = [bool(env.step(np.zeros(8, dtype=np.float32))[4]["success"][0]) for _ in range(12)]
    assert success[:5] == [False] * 5 and all(success[6:])


@pytest.mark.parametrize("env_id", RL_IDS)
def test_seeded_determinism(make_rl_env, env_id):
    env = make_rl_env(env_id)
    actions = _random_actions(5, seed=2)
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=11)
        trajectory = [obs.clone()]
        for action in actions:
            obs, reward, *_ = env.step(action)
            trajectory += [obs.clone(), reward.clone()]
        runs.append(torch.cat([t.reshape(-1) for t in trajectory]))
    assert torch.equal(runs[0], runs[1])


# ------------------------------------------------------------------------ rgb chain
@pytest.mark.parametrize("env_id", RL_IDS)
def test_rgb_joints_through_the_rl_chain(make_rl_env, env_id):
    env = apply_rl_wrappers(make_rl_env(env_id, obs_mode="rgb"), "rgb_joints")
    obs, _ = env.reset(seed=3)
    expected = ["proprio", "rgb", "task_cue"] if env_id in ROTATE_IDS else ["proprio", "rgb"]
    assert list(obs) == expected
    assert obs["rgb"].shape == (1, 128, 128, 6) and obs["rgb"].dtype == torch.uint8
    assert obs["proprio"].shape == (1, 25) and obs["proprio"].dtype == torch.float32
    # proprio = [tcp_pose 7, qpos 9, qvel 9]
    base = env.unwrapped
    assert torch.allclose(obs["proprio"][0, :7], base.agent.tcp.pose.raw_pose[0])
    assert torch.allclose(obs["proprio"][0, 7:16], base.agent.robot.get_qpos()[0])
    obs, reward, *_ = env.step(np.zeros(8, dtype=np.float32))
    assert obs["rgb"].shape == (1, 128, 128, 6) and 0.0 <= float(reward[0]) <= 1.0
    assert obs["rgb"][..., :3].float().std() > 5 and obs["rgb"][..., 3:].float().std() > 5


def test_observation_modes_of_the_baselines(make_rl_env):
    state = apply_rl_wrappers(make_rl_env("RotateStrictPos-v0"), "state")
    obs, _ = state.reset(seed=0)
    assert list(obs) == ["state", "task_cue"]
    oracle = apply_rl_wrappers(make_rl_env("RememberColor3-v0", obs_mode="rgb"), "rgb_oracle")
    obs, _ = oracle.reset(seed=0)
    assert list(obs) == ["rgb", "oracle_info"] and obs["oracle_info"].shape == (1, 1)
    with pytest.raises(ValueError, match="needs an env made with obs_mode='rgb'"):
        apply_rl_wrappers(make_rl_env("RememberColor3-v0"), "rgb_joints")
    with pytest.raises(ValueError, match="unknown RL observation mode 'rgbd'; accepted values: state, rgb"):
        apply_rl_wrappers(make_rl_env("RememberColor3-v0"), "rgbd")


def test_ee_delta_pose_control_mode_also_works(make_rl_env):
    env = make_rl_env("TakeItBack-v0", control_mode="pd_ee_delta_pose")
    env.reset(seed=0)
    _, reward, *_ = env.step(np.zeros(7, dtype=np.float32))
    assert env.unwrapped.single_action_space.shape == (7,) and 0.0 <= float(reward[0]) <= 1.0


@pytest.mark.parametrize("reward_mode", ["sparse", "dense"])
def test_reward_modes(make_rl_env, reward_mode):
    env = make_rl_env("RememberColor3-v0", reward_mode=reward_mode)
    env.reset(seed=0)
    _, reward, *_ = env.step(np.zeros(8, dtype=np.float32))
    assert reward.shape == (1,) and torch.isfinite(reward).all()


# -------------------------------------------------------------------------- errors
def test_unknown_id_names_close_matches():
    with pytest.raises(ValueError, match=r"Unknown environment: 'RememberColour3-v0'\. Did you mean: RememberColor3-v0"):
        mikasa_robo_rl.make("RememberColour3-v0")
    with pytest.raises(ValueError, match="Unknown environment: 'RememberColor3-VLA-v0'"):
        env_info("RememberColor3-VLA-v0")


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(obs_mode="pixels"), "unknown obs_mode 'pixels'; accepted values: state"),
        (dict(reward_mode="shaped"), "unknown reward_mode 'shaped'; accepted values: normalized_dense"),
        (dict(control_mode="pd_teleport"), "unknown control_mode"),
    ],
)
def test_bad_modes_are_named(make_rl_env, kwargs, message):
    with pytest.raises(ValueError, match=message):
        make_rl_env("ShellGamePush-v0", **kwargs)


def test_bad_actions_are_named(make_rl_env):
    env = make_rl_env("InterceptSlow-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action has shape \(7,\); control mode 'pd_joint_delta_pos' expects \(1, 8\) or \(8,\)"):
        env.step(np.zeros(7, dtype=np.float32))
    nan = np.zeros(8, dtype=np.float32)
    nan[3] = np.nan
    with pytest.raises(ValueError, match="action contains NaN"):
        env.step(nan)


# ------------------------------------------------------------------------ env_info
def test_env_info_lists_the_release_wrappers():
    wrappers, timeout = env_info("ShellGamePick-v0")
    assert timeout == 90
    assert [w for w, _ in wrappers] == [
        StateOnlyTensorToDictWrapper,
        InitialZeroActionWrapper,
        RenderStepInfoWrapper,
        ShellGameRenderCupInfoWrapper,
        RenderRewardInfoWrapper,
        DebugRewardWrapper,
    ]
    assert wrappers[1][1] == {"n_initial_steps": 0}
    wrappers, timeout = env_info("RememberColor5-v0", noop_steps=3)
    assert timeout == 60 and wrappers[1][1] == {"n_initial_steps": 2}
    assert wrappers[2][0] is RememberColorInfoWrapper
    wrappers, timeout = env_info("RotateStrictPosNeg-v0")
    assert timeout == 90 and RotateRenderAngleInfoWrapper in [w for w, _ in wrappers]
    assert env_info("TakeItBack-v0")[1] == 180 and env_info("ChainOfColors7-v0")[1] == 120
    # Known to upstream's env_info though never registered.
    wrappers, timeout = env_info("CameraShutdownPick-v0")
    assert timeout == 90 and wrappers[2][1] == {"n_initial_steps": 19}


def test_every_id_has_env_info_with_its_horizon():
    for env_id in RL_IDS:
        wrappers, timeout = env_info(env_id)
        assert timeout == get_rl_task(env_id).max_episode_steps
        assert wrappers[0][0] is StateOnlyTensorToDictWrapper


def test_overlays_render_on_frames_only(make_rl_env):
    plain = make_rl_env("RememberShape3-v0", obs_mode="rgb", render_mode="rgb_array")
    env = apply_rl_wrappers(make_rl_env("RememberShape3-v0", obs_mode="rgb", render_mode="rgb_array"), "rgb_joints")
    plain.reset(seed=1)
    obs, _ = env.reset(seed=1)
    obs, *_ = env.step(np.zeros(8, dtype=np.float32))
    raw, *_ = plain.step(np.zeros(8, dtype=np.float32))
    top = raw["sensor_data"]["base_camera"]["rgb"]
    assert torch.equal(obs["rgb"][..., :3], top)  # overlays never touch observations
    frame, bare = env.render(), plain.render()
    assert frame.shape == bare.shape and not torch.equal(torch.as_tensor(frame), torch.as_tensor(bare))


# ---------------------------------------------------------------------- old paths
OLD_PATHS = """
import gymnasium as gym
import mikasa_robo_suite.memory_envs as old_envs
import mikasa_robo_suite.rl.memory_envs as new_envs
from mikasa_robo_suite.utils.wrappers import StateOnlyTensorToDictWrapper, FlattenRGBDObservationWrapper
from mikasa_robo_suite.rl.utils.wrappers import env_info as env_info_rl
from mikasa_robo_suite.dataset_collectors.get_mikasa_robo_datasets import env_info
assert old_envs.RememberShape6Env is old_envs.RememberShape5Env is new_envs.RememberShape5Env
assert env_info is env_info_rl and env_info("ShellGameTouch-v0")[1] == 90
env = gym.make("ShellGameTouch-v0", obs_mode="state", control_mode="pd_joint_delta_pos")
env = FlattenRGBDObservationWrapper(StateOnlyTensorToDictWrapper(env), rgb=False, depth=False, state=True)
print(sorted(env.reset(seed=0)[0]))
"""


def test_old_import_paths_keep_working():
    out = subprocess.run([sys.executable, "-c", OLD_PATHS], check=True, capture_output=True, text=True, timeout=300)
    assert out.stdout.strip() == "['state']"


def test_gymnasium_module_entry_point_registers_without_import():
    code = (
        "import gymnasium as gym\n"
        "env = gym.make('mikasa_robo_rl:RememberColor5-v0', obs_mode='state', control_mode='pd_joint_delta_pos')\n"
        "print(env.unwrapped.spec.id, env.reset(seed=0)[0].shape[1])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, timeout=300)
    assert out.stdout.split()[0] == "RememberColor5-v0"
