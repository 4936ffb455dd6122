"""Scripted oracles in ``pd_joint_delta_pos``: the EE -> joint-delta conversion
(``mikasa_oracles.joint_delta``) moves the arm as ``pd_ee_delta_pose`` would."""

from __future__ import annotations

import numpy as np
import pytest
from mikasa_oracles import make_oracle, rollout
from mikasa_oracles.joint_delta import EEDeltaToJointDelta, JointDeltaOracle, bounded_tracking_step

SEED = 4242424242
JOINT_DELTA = "pd_joint_delta_pos"


@pytest.fixture
def make_jd_env(make_env):
    def _make(env_id: str, **kwargs):
        return make_env(env_id, control_mode=JOINT_DELTA, reward_mode="normalized_dense", **kwargs)

    return _make


def _tcp(env) -> np.ndarray:
    return env.unwrapped.agent.tcp.pose.p[0].cpu().numpy()


def test_converted_action_is_8d_float32_in_bounds(make_jd_env):
    env = make_jd_env("RememberColor3-VLA-v0")
    env.reset(seed=SEED)
    converter = EEDeltaToJointDelta(env.unwrapped)
    rng = np.random.default_rng(0)
    for ee_action in [*rng.uniform(-3, 3, (5, 7)), np.array([0, 0, 0, 0, 0, 0, -1.0])]:
        action = converter.convert(ee_action)
        assert action.shape == (8,) and action.dtype == np.float32
        assert np.abs(action).max() <= 1
        assert action[7] == np.float32(np.clip(ee_action[6], -1, 1))  # the gripper passes through
        env.step(action)
    # A zero EE delta is a zero joint delta (IK from the current joints converges at once).
    assert np.abs(converter.convert(np.zeros(7))[:7]).max() < 1e-6


def test_conversion_tracks_the_ee_controller(make_env, make_jd_env):
    """Same seed, same EE actions: the TCP of the joint-delta env follows the EE-mode env."""
    ee_env = make_env("RememberColor3-VLA-v0", reward_mode="normalized_dense")
    jd_env = make_jd_env("RememberColor3-VLA-v0")
    ee_env.reset(seed=SEED)
    jd_env.reset(seed=SEED)
    converter = EEDeltaToJointDelta(jd_env.unwrapped)
    rng = np.random.default_rng(1)
    start = _tcp(ee_env)
    for _ in range(6):
        # Moves of ~2-3 cm (forward, down) and up to 0.02 rad per step: within the
        # joint-delta bounds, where both controllers set the same joint drive targets.
        move = np.array([0.2, 0.0, -0.2]) + rng.uniform(-0.1, 0.1, 3)
        ee_action = np.concatenate([move, rng.uniform(-0.2, 0.2, 3), [1.0]]).astype(np.float32)
        ee_env.step(ee_action)
        jd_env.step(converter.convert(ee_action))
        assert np.linalg.norm(_tcp(ee_env) - _tcp(jd_env)) < 0.003
    assert np.linalg.norm(_tcp(ee_env) - start) > 0.05  # the arm did move


def test_bounded_tracking_step():
    rng = np.random.default_rng(2)
    jac = rng.normal(size=(6, 7))
    low, high = np.full(7, -0.1), np.full(7, 0.1)
    inside = rng.uniform(-0.09, 0.09, 7)
    assert np.allclose(bounded_tracking_step(jac, inside, low, high), inside)
    for _ in range(20):
        delta = rng.uniform(-0.5, 0.5, 7)
        step = bounded_tracking_step(jac, delta, low, high, rot_weight=1.0)
        assert np.all(step >= low) and np.all(step <= high)
        # Closer to the wanted TCP motion than the uniformly shrunk step.
        scaled = delta / np.abs(delta).max() * 0.1
        wanted = jac @ delta
        assert np.linalg.norm(jac @ step - wanted) <= np.linalg.norm(jac @ scaled - wanted) + 1e-9



def test_z_weight_trades_sideways_progress_for_height():
    rng = np.random.default_rng(3)
    low, high = np.full(7, -0.1), np.full(7, 0.1)
    for _ in range(20):
        jac, delta = rng.normal(size=(6, 7)), rng.uniform(-0.5, 0.5, 7)
        error = [jac @ bounded_tracking_step(jac, delta, low, high, z_weight=w) - jac @ delta for w in (1.0, 10.0)]
        assert abs(error[1][2]) <= abs(error[0][2]) + 1e-9

def test_converter_needs_a_joint_delta_mode(make_env):
    env = make_env("RememberColor3-VLA-v0")  # pd_ee_delta_pose
    env.reset(seed=SEED)
    with pytest.raises(ValueError, match="not a joint-delta mode"):
        EEDeltaToJointDelta(env.unwrapped).convert(np.zeros(7))


def test_converter_rebuilds_after_a_reconfigure(make_jd_env):
    env = make_jd_env("RememberColor3-VLA-v0")
    env.reset(seed=SEED)
    converter = EEDeltaToJointDelta(env.unwrapped)
    converter.convert(np.zeros(7))
    first = converter.kinematics
    env.reset(seed=SEED, options={"reconfigure": True})
    action = converter.convert(np.array([0.5, 0, 0, 0, 0, 0, 1.0]))
    assert converter.kinematics is not first
    assert converter.kinematics.articulation is env.unwrapped.agent.robot
    assert np.abs(action[:7]).max() > 0.1


def test_converted_oracle_solves_remember_color(make_jd_env):
    # The VLA horizon (25) is tight for joint deltas (±0.1 rad a step): give it the RL's 60.
    env = make_jd_env("RememberColor3-VLA-v0", max_episode_steps=60)
    oracle = JointDeltaOracle(make_oracle(env))
    assert oracle.chunk_size == 1 and oracle.env is env and oracle.base is env.unwrapped
    obs, _ = env.reset(seed=SEED)
    oracle.reset()
    action = oracle.forward(obs)
    assert action.shape == (8,) and action.dtype == np.float32
    assert rollout(env, oracle, SEED, stop_on_success=True).success_once


SWEEP_IDS = [
    f"{name}-VLA-v0"
    for name in (
        "RememberColor3", "ShellGameTouch", "ShellGamePush", "InterceptSlow", "InterceptGrabSlow",
        "RotateLenientPos", "RotateStrictPos", "TakeItBack", "BunchOfColors3", "SeqOfColors3",
        "ChainOfColors3", "RememberShapeAndColor3x2",
    )
]


@pytest.mark.slow
@pytest.mark.parametrize("env_id", SWEEP_IDS)
def test_converted_oracles_solve_with_a_longer_horizon(make_jd_env, env_id):
    import mikasa_envs

    horizon = max(60, 2 * mikasa_envs.get_task(env_id).max_episode_steps)
    env = make_jd_env(env_id, max_episode_steps=horizon)
    oracle = JointDeltaOracle(make_oracle(env))
    seeds = range(SEED, SEED + 5)
    assert sum(rollout(env, oracle, s, stop_on_success=True).success_once for s in seeds) >= 4
