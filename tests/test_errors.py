"""Bad input gets a clear error that names the problem and the accepted values."""

from __future__ import annotations

import gymnasium as gym
import mikasa_envs
import numpy as np
import pytest
import torch


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(obs_mode="rgbx"), r"unknown obs_mode 'rgbx'; accepted values: state, state_dict, rgb"),
        (dict(reward_mode="densee"), r"unknown reward_mode 'densee'; accepted values: normalized_dense"),
        (dict(control_mode="pd_ee_delta"), r"pd_ee_delta not in supported modes: .*pd_ee_delta_pose"),
        (dict(robot_uids="xarm6"), r"robot_uids='xarm6' is not supported .* panda, panda_wristcam"),
    ],
)
def test_bad_constructor_arguments(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        gym.make("RememberColor3-VLA-v0", **kwargs)


def test_unknown_env_id_suggests_close_matches():
    with pytest.raises(ValueError, match=r"Did you mean: RememberColor3-VLA-v0"):
        mikasa_envs.make("RememberColr3-VLA-v0")


@pytest.mark.parametrize(
    "action, needle",
    [
        (np.zeros(6, dtype=np.float32), r"shape \(6,\); control mode 'pd_ee_delta_pose' expects \(1, 7\) or \(7,\)"),
        (np.zeros((2, 7), dtype=np.float32), r"shape \(2, 7\)"),
        (np.full(7, np.nan, dtype=np.float32), "NaN"),
        (torch.tensor([0.0, 0, 0, 0, 0, 0, float("nan")]), "NaN"),
        ([0.0] * 7, "numpy array or torch tensor"),
    ],
)
def test_bad_actions(make_env, action, needle):
    env = make_env("RememberColor3-VLA-v0")
    env.reset(seed=0)
    with pytest.raises((ValueError, TypeError), match=needle):
        env.step(action)
    # The env is still usable afterwards.
    env.step(np.zeros(7, dtype=np.float32))
