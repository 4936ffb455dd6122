"""The RL oracles (VLA family oracles in joint deltas) solve every RL id; zero actions none."""

from __future__ import annotations

import math

import numpy as np
import pytest
from mikasa_oracles import ZeroActions, rollout
from mikasa_robo_rl import get_rl_task, rl_env_ids
from mikasa_robo_rl.oracles import make_rl_oracle
from mikasa_robo_rl.wrappers import apply_rl_wrappers

RL_IDS = list(rl_env_ids())
SEED = 4242424242
# The colour-sequence ids are time-bound (50 seeds, benchmarks/rl_oracle_validity.py,
# legacy/rl/VALIDITY.md: the rate within the published horizon): touching 3-7 cubes in cue
# order around a 1.6 rad arc takes about as long as (3 cubes) or longer than (5, 7) the
# 120 steps allow an arm whose base joint turns at most 0.73 rad/s in pd_joint_delta_pos.
# Their oracle is also checked within EXTENDED x the horizon, and the quick test runs there.
TIME_BOUND = {
    "SeqOfColors3-v0": 0.96,
    "SeqOfColors5-v0": 0.20,
    "SeqOfColors7-v0": 0.0,
    "ChainOfColors3-v0": 0.96,
    "ChainOfColors5-v0": 0.20,
    "ChainOfColors7-v0": 0.0,
}
EXTENDED = 3
TARGET = 0.95


@pytest.fixture
def make_rl_env(make_env):
    def _make(env_id: str, **kwargs):
        return make_env(env_id, control_mode="pd_joint_delta_pos", reward_mode="normalized_dense", **kwargs)

    return _make


def _successes(env, policy, seeds, stop_on_success: bool = True) -> int:
    return sum(rollout(env, policy, s, stop_on_success).success_once for s in seeds)


def _extended_env(make_rl_env, env_id: str):
    """``env_id`` with EXTENDED x its horizon as the step limit."""
    return make_rl_env(env_id, max_episode_steps=EXTENDED * get_rl_task(env_id).max_episode_steps)


@pytest.mark.parametrize("env_id", RL_IDS)
def test_oracle_solves_first_seeds_and_zero_actions_do_not(make_rl_env, env_id):
    env = make_rl_env(env_id)
    assert not rollout(env, ZeroActions(8), SEED, stop_on_success=False).success_once
    if env_id in TIME_BOUND:
        env = _extended_env(make_rl_env, env_id)
    # A few seeds: most, not all (ids at 96 % fail one seed in 25; the rate is the slow test's).
    assert _successes(env, make_rl_oracle(env), range(SEED, SEED + 3)) >= 2


def test_oracle_acts_in_joint_deltas_through_the_rl_rgb_chain(make_rl_env):
    env = apply_rl_wrappers(make_rl_env("RememberShape3-v0", obs_mode="rgb"), "rgb_joints")
    oracle = make_rl_oracle(env)
    obs, _ = env.reset(seed=SEED)
    oracle.reset()
    action = oracle.forward(obs)
    assert action.shape == (8,) and action.dtype == np.float32 and np.abs(action).max() <= 1
    assert _successes(env, oracle, [SEED]) == 1


def test_memoryless_rl_oracle_guesses_from_the_episode_seed(make_rl_env):
    """The memoryless variant acts in joint deltas too, and its guesses are the episode
    seed's: the same seed gives the same episode, whatever ran before."""
    from mikasa_oracles.scripted import Memoryless

    env = make_rl_env("RememberColor5-v0")
    oracle = make_rl_oracle(env, memoryless=True)
    assert isinstance(oracle.oracle, Memoryless)
    first = [rollout(env, oracle, s).steps for s in (SEED, SEED + 1)]
    again = [rollout(env, oracle, s).steps for s in (SEED + 1, SEED)]
    assert first == again[::-1]
    oracle.reset(seed=SEED + 7)
    assert oracle.oracle.episode_seed == SEED + 7


def test_oracle_needs_the_rl_control_mode(make_rl_env, make_env):
    env = make_env("RememberColor3-v0", control_mode="pd_ee_delta_pose")
    with pytest.raises(ValueError, match="act in control_mode='pd_joint_delta_pos'"):
        make_rl_oracle(env)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", RL_IDS)
def test_oracle_success_rate_50_seeds(make_rl_env, env_id):
    env = make_rl_env(env_id)
    seeds = range(SEED, SEED + 50)
    measured = TIME_BOUND.get(env_id, 1.0)
    target = math.ceil(TARGET * 50) if measured >= TARGET else int(measured * 50) - 2  # or no regression
    assert _successes(env, make_rl_oracle(env), seeds) >= target
    assert _successes(env, ZeroActions(8), seeds, stop_on_success=False) == 0
    if env_id in TIME_BOUND:
        env = _extended_env(make_rl_env, env_id)
        assert _successes(env, make_rl_oracle(env), seeds) >= math.ceil(TARGET * 50)
