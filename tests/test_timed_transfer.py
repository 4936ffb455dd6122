"""TimedTransfer: instruction, layout, lamp timeline, window success / failure, reward, oracle."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mani_skill.utils.structs import Pose
from mikasa_oracles import make_oracle
from mikasa_wrappers import apply_mikasa_vla_wrappers

ZERO = np.zeros(7, dtype=np.float32)
EASY = "TimedTransferEasy-VLA-v0"
SHOWN_BELOW_Z = 1.0  # bulbs not shown are parked 1000 m up


def _shown_bulb(base) -> str:
    names = [n for n, bulb in zip(base.lamp.bulb_names, base.lamp.bulbs, strict=True) if bulb.pose.p[0, 2] < SHOWN_BELOW_Z]
    assert len(names) == 1
    return names[0]


def _step_to(env, e: int):
    info = None
    while int(env.unwrapped.elapsed_steps[0]) < e:
        *_, info = env.step(ZERO)
    return info


def _put_cube_on_red(base) -> None:
    red = base.red_disc_center[0].clone()
    red[2] = base.disc_top_z + base.CUBE_HALF_SIZE
    base.blue_cube.set_pose(Pose.create_from_pq(red[None]))
    base.blue_cube.set_linear_velocity(torch.zeros(1, 3))
    base.blue_cube.set_angular_velocity(torch.zeros(1, 3))


@pytest.mark.parametrize(
    "env_id, delay, window",
    [(EASY, 100, (95, 105)), ("TimedTransferMedium-VLA-v0", 150, (142, 157)), ("TimedTransferHard-Long-VLA-v0", 1000, (950, 1050))],
)
def test_instruction_window_and_answer(make_env, env_id, delay, window):
    env = make_env(env_id)
    obs, info = env.reset(seed=3)
    base = env.unwrapped
    assert info["language_instruction"].endswith(f"exactly on step {delay} of that count.")
    assert info["language_instruction"].startswith("When the white lamp turns green, start counting steps")
    signal = int(base.signal_step[0])
    assert 1 <= signal <= 3
    assert (int(base.window_start[0]), int(base.window_end[0])) == (signal + window[0], signal + window[1])
    assert info["oracle_info"].dtype == torch.float32 and float(info["oracle_info"][0]) == delay
    assert info["task_cue"] is None
    assert base.DELAY_STEPS == delay
    # Extra state: tcp, green disc, red disc and cube poses (7 each), 3 flags and D.
    assert obs.shape == (1, 9 + 9 + 7 * 4 + 4)


def test_layout(make_env):
    env = make_env(EASY)
    env.reset(seed=11)
    base = env.unwrapped
    green, red = base.green_disc_center[0], base.red_disc_center[0]
    cx, cy = float(green[0]), float(green[1]) + 0.11
    assert -0.15 <= cx < -0.05 and -0.05 <= cy < 0.05
    np.testing.assert_allclose(red.numpy(), [cx, cy + 0.11, 0.003], atol=1e-6)
    np.testing.assert_allclose(base.cube_position()[0].numpy(), [cx, cy - 0.11, 0.026], atol=1e-4)
    np.testing.assert_allclose(base.lamp.position[0].numpy(), [cx + 0.22, cy, 0.0], atol=1e-6)


def test_lamp_turns_green_at_signal_and_stays(make_env):
    env = make_env(EASY)
    _, info = env.reset(seed=5)
    base = env.unwrapped
    signal = int(base.signal_step[0])
    for e in range(signal + 4):
        info = _step_to(env, e) or info
        assert _shown_bulb(base) == ("green" if e >= signal else "off")
        assert bool(info["signal_on"][0]) == (e >= signal)
        assert bool(info["before_window"][0]) == (e >= signal)
    assert not bool(info["in_window"][0]) and not bool(info["failed"][0])


def test_placement_in_window_succeeds_and_terminates(make_env):
    env = make_env(EASY, reward_mode="dense")
    env.reset(seed=7)
    base = env.unwrapped
    start = int(base.window_start[0])
    _step_to(env, start - 1)
    _put_cube_on_red(base)
    _, reward, terminated, _, info = env.step(ZERO)
    assert int(info["elapsed_steps"][0]) == start
    assert bool(info["cube_on_red"][0]) and bool(info["in_window"][0])
    assert bool(info["success"][0]) and not bool(info["failed"][0]) and bool(terminated[0])
    assert float(reward[0]) == 30.0


def test_early_placement_fails(make_env):
    env = make_env(EASY, reward_mode="dense")
    env.reset(seed=7)
    base = env.unwrapped
    _step_to(env, int(base.window_start[0]) - 2)
    _put_cube_on_red(base)
    _, reward, terminated, _, info = env.step(ZERO)
    assert bool(info["too_early"][0]) and bool(info["failed"][0]) and bool(terminated[0])
    assert not bool(info["success"][0]) and float(reward[0]) == -25.0
    # Latched: still failed, never successful, once the window opens.
    *_, info = env.step(ZERO)
    assert bool(info["failed"][0]) and not bool(info["success"][0])


def test_no_placement_fails_right_after_the_window(make_env):
    env = make_env(EASY, reward_mode="normalized_dense")
    env.reset(seed=9)
    base = env.unwrapped
    end = int(base.window_end[0])
    rewards = []
    for _ in range(end + 1):
        _, reward, terminated, _, info = env.step(ZERO)
        rewards.append(float(reward[0]))
        e = int(info["elapsed_steps"][0])
        assert bool(terminated[0]) == (e > end)
    assert bool(info["past_window"][0]) and bool(info["failed"][0]) and not bool(info["success"][0])
    assert all(0.0 <= r <= 1.0 for r in rewards)
    assert set(info["reward_dict"]) >= {"reaching_reward", "place_reward", "smooth_penalty"}


def test_seeded_determinism(make_env):
    env = make_env(EASY)

    def layout(seed):
        env.reset(seed=seed)
        base = env.unwrapped
        return int(base.signal_step[0]), base.red_disc_center[0].clone(), base.agent.robot.get_qpos()[0].clone()

    first, again, other = layout(21), layout(21), layout(22)
    assert first[0] == again[0] and torch.equal(first[1], again[1]) and torch.equal(first[2], again[2])
    assert not torch.equal(first[1], other[1])


def test_oracle_times_the_drop_from_the_lamp(make_env):
    """Delaying the lamp after reset delays the oracle's placement by as much."""
    env = make_env(EASY)
    obs, _ = env.reset(seed=4242424242)
    base = env.unwrapped
    oracle = make_oracle(env)
    oracle.reset()
    shift = 4
    base.signal_step += shift
    base.window_start += shift
    base.window_end += shift
    terminated = torch.zeros(1, dtype=torch.bool)
    while not bool(terminated[0]):
        obs, _, terminated, _, info = env.step(oracle.forward(obs))
    assert bool(info["success"][0])
    assert int(info["elapsed_steps"][0]) == int(base.signal_step[0]) + base.DELAY_STEPS


def test_timer_overlay_draws(make_env):
    frames = []
    for include_overlays in (False, True):
        env = make_env(EASY, obs_mode="rgb", render_mode="rgb_array")
        env = apply_mikasa_vla_wrappers(env, include_overlays=include_overlays)
        env.reset(seed=0)
        env.step(ZERO)
        frame = env.render()
        frames.append(np.asarray(frame.cpu() if isinstance(frame, torch.Tensor) else frame))
    plain, overlaid = frames
    width = plain.shape[-2]
    # The timer is drawn near the right edge (x = width - 260), in the top rows.
    assert (overlaid[..., :120, width - 260 :, :] != plain[..., :120, width - 260 :, :]).mean() > 0.01
