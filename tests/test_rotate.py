"""RotateLenient / RotateStrict: target draw, instruction, angle measurement, success, reward.

Success states are constructed by teleporting the peg (``evaluate()`` reads the current
pose), so no episode has to be solved here; the oracle runs in tests/test_oracles.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from mani_skill.utils.structs import Pose
from mikasa_envs.tasks._rotate import (
    MODE_POS,
    MODE_POS_NEG,
    sample_target_angles,
    target_degrees,
    wrap_angle,
    xyz_euler_gamma,
)
from mikasa_oracles import make_oracle
from mikasa_wrappers import apply_mikasa_vla_wrappers

LENIENT_IDS = ["RotateLenientPos-VLA-v0", "RotateLenientPosNeg-VLA-v0"]
STRICT_IDS = ["RotateStrictPos-VLA-v0", "RotateStrictPosNeg-VLA-v0"]
ROTATE_IDS = LENIENT_IDS + STRICT_IDS
LENIENT_TEMPLATE = "Rotate the peg by {angle_deg} degrees to match the target angle."
STRICT_TEMPLATE = (
    "Rotate the peg by {angle_deg} degrees to match the target angle while keeping the center of the peg in place."
)
LENIENT_INFO_KEYS = {
    "elapsed_steps",
    "success",
    "task_cue",
    "language_instruction",
    "oracle_info",
    "relative_angle",
    "y_angle_error",
    "reward_dict",
}
STRICT_INFO_KEYS = LENIENT_INFO_KEYS | {"x_pos_error", "y_pos_error"}
SMOOTHNESS_KEYS = {"action_l2", "delta_action_l2", "qvel_l2", "smooth_penalty"}
LENIENT_REWARD_KEYS = {
    "to_grip_dist",
    "reaching_reward",
    "reached_status",
    "y_angle_reward",
    "correct_angle",
    "angle_diff_deg",
    "agent_is_static",
    "success",
} | SMOOTHNESS_KEYS
STRICT_REWARD_KEYS = (LENIENT_REWARD_KEYS - {"angle_diff_deg"}) | {
    "y_angle_diff_deg",
    "x_pos_error",
    "y_pos_error",
    "x_pos_reward",
    "y_pos_reward",
    "position_ok",
}
POS_DEGREES = set(range(6, 91))
POS_NEG_DEGREES = set(range(-25, -5)) | set(range(25, 46))
ZERO_ACTION = np.zeros(7, dtype=np.float32)


def _template(env_id: str) -> str:
    return STRICT_TEMPLATE if "Strict" in env_id else LENIENT_TEMPLATE


def _place_peg(base, turn: float, shift=(0.0, 0.0), z: float | None = None) -> dict:
    """Put the peg at its start heading + ``turn``, shifted in xy; return ``evaluate()``."""
    heading = float(base.initial_rotations[0]) + turn
    position = base.initial_peg_position.clone()
    position[0, 0] += shift[0]
    position[0, 1] += shift[1]
    if z is not None:
        position[0, 2] = z
    quat = torch.tensor([[math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)]])
    base.peg.set_pose(Pose.create_from_pq(position, quat))
    return base.evaluate()


# --------------------------------------------------------------------- pure functions
def test_target_ranges_and_instruction_degrees():
    u = torch.linspace(0, 1, 20001)[:-1]
    pos = sample_target_angles(u, MODE_POS, 0.1)
    assert pos.min() >= 0.1 and pos.max() < math.pi / 2
    pos_neg = sample_target_angles(u, MODE_POS_NEG, 0.1)
    # The sign comes from the same draw as the magnitude: + only for u > 0.5.
    assert torch.equal(pos_neg > 0, u > 0.5)
    assert pos_neg[u > 0.5].min() > 0.4427 and pos_neg.max() <= math.pi / 4 + 1e-6
    assert pos_neg[u <= 0.5].min() >= -0.4427 and pos_neg[u <= 0.5].max() <= -0.1 + 1e-6
    assert set(target_degrees(pos.half()).tolist()) == POS_DEGREES
    assert set(target_degrees(pos_neg.half()).tolist()) == POS_NEG_DEGREES
    with pytest.raises(ValueError, match="unknown rotate MODE"):
        sample_target_angles(u, "both", 0.1)


def test_degrees_use_the_float16_target():
    cue = torch.tensor([0.1, -0.1222, 1.5703, 0.7854]).half()
    expected = [round(float(np.float32(c) * np.float32(180 / math.pi))) for c in cue.float().numpy()]
    assert target_degrees(cue).tolist() == expected == [6, -7, 90, 45]


def test_angle_helpers():
    assert torch.allclose(wrap_angle(torch.tensor([math.pi, -math.pi, 3 * math.pi / 2, 0.3])),
                          torch.tensor([-math.pi, -math.pi, -math.pi / 2, 0.3]))
    headings = torch.tensor([0.0, 0.5, 2.0, -2.5, 3.0])
    quats = torch.stack([torch.cos(headings / 2), 0 * headings, 0 * headings, torch.sin(headings / 2)], dim=-1)
    assert torch.allclose(xyz_euler_gamma(quats), headings, atol=1e-6)


# --------------------------------------------------------------------- the envs
@pytest.mark.parametrize("env_id", ROTATE_IDS)
def test_reset_state_info_and_observation(make_env, env_id):
    env = make_env(env_id, reward_mode="normalized_dense")
    base = env.unwrapped
    obs, info = env.reset(seed=11)
    strict = "Strict" in env_id
    assert set(info) - {"reconfigure"} == (STRICT_INFO_KEYS if strict else LENIENT_INFO_KEYS)
    assert info["reward_dict"] is None
    # task_cue: the float16 target, [B]; the instruction shows it in whole degrees, as a list.
    cue = info["task_cue"]
    assert cue.dtype == torch.float16 and cue.shape == (1,) and base.task_cue is cue
    degrees = int(target_degrees(cue)[0])
    assert info["language_instruction"] == [_template(env_id).format(angle_deg=degrees)]
    assert base.language_instruction == info["language_instruction"]
    assert base.LANGUAGE_INSTRUCTION == _template(env_id)
    # No turn yet: the error still to go is the whole target.
    assert float(info["relative_angle"][0]) == pytest.approx(0.0, abs=1e-5)
    assert info["oracle_info"].dtype == torch.float32 and info["oracle_info"].shape == (1,)
    assert float(info["oracle_info"][0]) == pytest.approx(float(cue[0]), abs=1e-5)
    # The peg lies flat at its start pose.
    peg = base.peg.pose.raw_pose[0]
    assert abs(float(peg[0])) <= 0.1 and abs(float(peg[1])) <= 0.1 and float(peg[2]) == pytest.approx(0.025, abs=1e-4)
    theta0 = base.initial_rotations
    assert theta0.dtype == torch.float32 and 0 <= float(theta0[0]) < 2 * math.pi
    assert float(wrap_angle(xyz_euler_gamma(peg[None, 3:]) - theta0)[0]) == pytest.approx(0.0, abs=1e-5)
    # No cue / delay phases.
    assert int(base.cue_steps_per_env[0]) == 0 and int(base.empty_steps_per_env[0]) == 0
    # State: qpos 9, qvel 9, tcp_pose 7, oracle_info 1, peg_pose 7.
    assert obs.shape == (1, 33) and obs.dtype == torch.float32
    assert float(obs[0, 25]) == pytest.approx(float(info["oracle_info"][0]))
    torch.testing.assert_close(obs[0, 26:33], peg)
    if strict:
        torch.testing.assert_close(base.initial_peg_position[0], peg[:3])
        assert float(info["x_pos_error"][0]) == 0.0 and float(info["y_pos_error"][0]) == 0.0
    obs, reward, terminated, truncated, info = env.step(ZERO_ACTION)
    obs, reward, terminated, truncated, info = env.step(ZERO_ACTION)
    assert set(info["reward_dict"]) == (STRICT_REWARD_KEYS if strict else LENIENT_REWARD_KEYS)
    assert 0.0 <= float(reward[0]) <= 1.0 and not bool(terminated[0]) and not bool(info["success"][0])


@pytest.mark.parametrize("env_id, degrees", [(LENIENT_IDS[0], POS_DEGREES), (STRICT_IDS[1], POS_NEG_DEGREES)])
def test_targets_over_seeds(make_env, env_id, degrees):
    env = make_env(env_id)
    base = env.unwrapped
    seen, starts = set(), []
    for seed in range(40):
        env.reset(seed=seed)
        seen.add(int(target_degrees(base.task_cue)[0]))
        starts.append(float(base.initial_rotations[0]))
    assert seen <= degrees and len(seen) > 20
    if "PosNeg" in env_id:
        assert min(seen) < 0 < max(seen)
    assert np.ptp(starts) > np.pi


def test_seeded_determinism(make_env):
    env = make_env(STRICT_IDS[0])
    base = env.unwrapped

    def episode(seed: int) -> tuple:
        obs, info = env.reset(seed=seed)
        for _ in range(3):
            obs, *_ = env.step(np.array([0.3, -0.2, -0.5, 0.0, 0.0, 0.4, -1.0], dtype=np.float32))
        return base.peg.pose.raw_pose.clone(), base.task_cue.clone(), info["language_instruction"], obs

    first, again, other = episode(5), episode(5), episode(6)
    for a, b in zip(first, again, strict=True):
        assert a == b if isinstance(a, list) else torch.equal(a, b)
    assert not torch.equal(first[0], other[0]) and not torch.equal(first[1], other[1])


def test_lenient_success_is_the_turn_alone(make_env):
    env = make_env(LENIENT_IDS[0])
    base = env.unwrapped
    env.reset(seed=3)
    target = float(base.task_cue[0])
    info = _place_peg(base, target)
    assert bool(info["success"][0]) and abs(float(info["y_angle_error"][0])) < 1e-4
    assert float(info["relative_angle"][0]) == pytest.approx(target, abs=1e-4)
    assert base.oracle_info is info["y_angle_error"]
    assert bool(_place_peg(base, target + 0.095)["success"][0])
    assert not bool(_place_peg(base, target - 0.105)["success"][0])
    # Where the peg ends up does not matter.
    assert bool(_place_peg(base, target, shift=(0.09, -0.12))["success"][0])
    assert not bool(_place_peg(base, 0.0)["success"][0])
    # The peg looks the same after a half turn, but the error is then ≈ π (upstream quirk).
    info = _place_peg(base, target + math.pi)
    assert abs(float(info["y_angle_error"][0])) == pytest.approx(math.pi, abs=1e-3)
    assert not bool(info["success"][0])
    # A moving arm is not done.
    qvel = torch.zeros(1, 9)
    qvel[0, 3] = 0.3
    base.agent.robot.set_qvel(qvel)
    assert not bool(_place_peg(base, target)["success"][0])


def test_strict_success_keeps_the_centre_in_a_square(make_env):
    env = make_env(STRICT_IDS[1])
    base = env.unwrapped
    env.reset(seed=4)
    target = float(base.task_cue[0])
    info = _place_peg(base, target, shift=(0.04, -0.04))  # 5.7 cm away, inside the ±5 cm square
    assert bool(info["success"][0])
    assert float(info["x_pos_error"][0]) == pytest.approx(0.04, abs=1e-5)
    assert float(info["y_pos_error"][0]) == pytest.approx(-0.04, abs=1e-5)
    assert not bool(_place_peg(base, target, shift=(0.055, 0.0))["success"][0])
    assert not bool(_place_peg(base, target, shift=(0.0, -0.055))["success"][0])
    assert not bool(_place_peg(base, target + 0.15)["success"][0])


def test_lenient_dense_reward(make_env):
    env = make_env(LENIENT_IDS[1], reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=8)
    target = float(base.task_cue[0])
    action = torch.zeros(1, 7)
    # Far from the peg (the TCP starts ~0.3 m above the table), not turned.
    info = _place_peg(base, 0.0)
    d = float(torch.linalg.norm(base.peg.pose.p - base.agent.tcp.pose.p))
    assert d > 0.1
    assert float(base.compute_dense_reward(None, action, info)[0]) == pytest.approx(math.exp(-5 * d), rel=1e-5)
    # Peg at the TCP: reached; not turned, then turned right (success: 60, normalized 1).
    tcp_z = float(base.agent.tcp.pose.p[0, 2])
    tcp_xy = base.agent.tcp.pose.p[0, :2] - base.initial_peg_position[0, :2]
    info = _place_peg(base, 0.0, shift=tcp_xy.tolist(), z=tcp_z)
    expected = 1.0 + 15 * math.exp(-1.5 * abs(target))
    assert float(base.compute_dense_reward(None, action, info)[0]) == pytest.approx(expected, rel=1e-4)
    info = _place_peg(base, target, shift=tcp_xy.tolist(), z=tcp_z)
    assert bool(info["success"][0])
    assert float(base.compute_dense_reward(None, action, info)[0]) == 60.0
    assert float(base.compute_normalized_dense_reward(None, action, info)[0]) == 1.0
    rewards = base._reward_dict
    assert bool(rewards["reached_status"][0]) and bool(rewards["correct_angle"][0])


def test_strict_dense_reward(make_env):
    env = make_env(STRICT_IDS[0], reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=9)
    target = float(base.task_cue[0])
    action = torch.zeros(1, 7)
    info = _place_peg(base, 0.0)
    d = float(torch.linalg.norm(base.peg.pose.p - base.agent.tcp.pose.p))
    assert float(base.compute_dense_reward(None, action, info)[0]) == pytest.approx(0.5 * math.exp(-3 * d), rel=1e-5)
    # Peg (and its start) at the TCP: reached and in place.
    base.initial_peg_position[0] = base.agent.tcp.pose.p[0]
    info = _place_peg(base, 0.0)
    expected = 0.5 + 5 + 5 + 35 * math.exp(-abs(target))
    assert float(base.compute_dense_reward(None, action, info)[0]) == pytest.approx(expected, rel=1e-4)
    # In place and turned within tolerance but the arm moving: + 10, no stillness bonus.
    qvel = torch.zeros(1, 9)
    qvel[0, 1] = 0.5
    base.agent.robot.set_qvel(qvel)
    info = _place_peg(base, target + 0.05)
    expected = 0.5 + 10 + 35 * math.exp(-0.05) + 10
    assert float(base.compute_dense_reward(None, action, info)[0]) == pytest.approx(expected, rel=1e-3)
    assert 0.0 <= float(base.compute_normalized_dense_reward(None, action, info)[0]) < 1.0
    base.agent.robot.set_qvel(torch.zeros(1, 9))
    info = _place_peg(base, target)
    assert float(base.compute_dense_reward(None, action, info)[0]) == 100.0


@pytest.mark.parametrize("env_id, horizon", [(LENIENT_IDS[0], 60), (STRICT_IDS[0], 90)])
def test_success_not_latched_and_never_terminates(make_env, env_id, horizon):
    env = make_env(env_id)
    base = env.unwrapped
    env.reset(seed=2)
    target = float(base.task_cue[0])
    for step in range(1, horizon + 1):
        if step in (5, 6):
            _place_peg(base, target)  # held at the target for two steps, then put back
        elif step == 7:
            _place_peg(base, 0.0)
        *_, terminated, truncated, info = env.step(ZERO_ACTION)
        assert bool(info["success"][0]) == (step in (5, 6)), step
        assert not bool(terminated[0])
        assert bool(truncated[0]) == (step == horizon)


def test_angle_threshold_kwarg(make_env):
    env = make_env(LENIENT_IDS[0], angle_threshold=0.3)
    base = env.unwrapped
    env.reset(seed=1)
    target = float(base.task_cue[0])
    assert base.angle_threshold == 0.3 and target >= 0.3 - 1e-3
    assert bool(_place_peg(base, target + 0.25)["success"][0])
    assert not bool(_place_peg(base, target + 0.35)["success"][0])


def test_oracle_tracks_the_turn_itself(make_env):
    """The oracle turns the peg from where it saw it start, not from the env's record of it."""
    env = make_env(LENIENT_IDS[0])
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=4242424242)
    oracle.reset()
    start = base.peg.pose.q.clone()
    target = float(base.task_cue[0])
    base.initial_rotations += 0.5  # the env now measures from a wrong start
    for _ in range(60):
        obs, *_, info = env.step(oracle.forward(obs))
    turned = float(wrap_angle(xyz_euler_gamma(base.peg.pose.q) - xyz_euler_gamma(start))[0])
    assert turned == pytest.approx(target, abs=0.1)
    assert not bool(info["success"][0])


def test_rgb_wrappers_keep_task_cue_and_overlay_draws_angles(make_env):
    env = apply_mikasa_vla_wrappers(
        make_env(STRICT_IDS[1], obs_mode="rgb", render_mode="rgb_array"), include_overlays=True
    )
    base = env.unwrapped
    obs, info = env.reset(seed=0)
    # The canonical chain keeps the target as a (B, 1) observation entry (wrappers.md §2).
    assert list(obs) == ["proprio", "rgb", "task_cue"]
    assert obs["task_cue"].shape == (1, 1) and obs["task_cue"].dtype == torch.float16
    assert float(obs["task_cue"][0, 0]) == float(base.task_cue[0])
    env.step(ZERO_ACTION)

    def picture(frame) -> np.ndarray:
        return np.asarray(frame.cpu() if isinstance(frame, torch.Tensor) else frame).reshape(512, 512, 3)

    overlaid, plain = picture(env.render()), picture(base.render())
    # "Target : ... deg" (y ≈ 60) and "Current: ... deg" (y ≈ 120) in the top-left corner.
    for rows in (slice(40, 66), slice(100, 126)):
        assert (overlaid[rows, :300] != plain[rows, :300]).mean() > 0.01
    np.testing.assert_array_equal(overlaid[300:, 300:], plain[300:, 300:])
