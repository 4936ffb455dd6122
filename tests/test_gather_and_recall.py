"""GatherAndRecall: layout, on-disc counting, the flash, button presses, reward, oracle."""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils.structs import Pose
from mikasa_oracles import make_oracle
from mikasa_oracles.controller import move_towards

ZERO = np.zeros(7, dtype=np.float32)
SHOWN_BELOW_Z = 1.0  # bulbs not shown are parked 1000 m up


def _shown_bulb(base) -> str:
    names = [n for n, bulb in zip(base.lamp.bulb_names, base.lamp.bulbs, strict=True) if bulb.pose.p[0, 2] < SHOWN_BELOW_Z]
    assert len(names) == 1
    return names[0]


def _put_on_disc(base, indices) -> None:
    """Teleport cubes ``indices`` to separate spots on the disc, at rest."""
    for k in indices:
        angle = 2 * np.pi * k / base.N_CUBES
        xy = base.disc_xy[0] + 0.06 * torch.tensor([np.cos(angle), np.sin(angle)], dtype=torch.float32)
        position = torch.cat([xy, torch.tensor([base.disc_top_z + base.CUBE_HALF_SIZE])])
        base.cubes[k].set_pose(Pose.create_from_pq(position[None]))
        base.cubes[k].set_linear_velocity(torch.zeros(1, 3))
        base.cubes[k].set_angular_velocity(torch.zeros(1, 3))


def _press(env, button: int, max_steps: int = 80):
    """Drive the TCP over ``button`` and down to press height; the info of each step."""
    base = env.unwrapped
    bx, by = base.buttons_xy[button, 0].tolist()
    infos = []
    for _ in range(max_steps):
        tcp = base.agent.tcp.pose.raw_pose[0].numpy().astype(np.float64)
        z = 0.07 if np.hypot(tcp[0] - bx, tcp[1] - by) < 0.01 else 0.15
        *_, terminated, _, info = env.step(move_towards(tcp, np.array([bx, by, z]), gripper=-1.0))
        infos.append(info)
        if bool(terminated[0]) or int(info["pressed_button"][0]) >= 0:
            break
    return infos


def test_layout_and_draws(make_env):
    env = make_env("GatherAndRecall9-VLA-v0")
    obs, info = env.reset(seed=4)
    base = env.unwrapped
    dx, dy = base.disc_xy[0].tolist()
    assert 0.0 <= dx < 0.08 and 0.10 <= dy < 0.18
    cubes = base.cube_positions()[0].numpy()
    expected_x = dx - 0.08 + np.tile([-0.09, 0.0, 0.09], 3)
    expected_y = -0.26 + np.repeat([-0.09, 0.0, 0.09], 3)
    assert np.abs(cubes[:, 0] - expected_x).max() <= 0.005 + 1e-6
    assert np.abs(cubes[:, 1] - expected_y).max() <= 0.005 + 1e-6
    np.testing.assert_allclose(cubes[:, 2], 0.02, atol=1e-4)
    assert base.buttons_xy.shape == (3, 1, 2)
    np.testing.assert_allclose(base.buttons_xy[:, 0].numpy(), [[dx - 0.22, dy + d] for d in (-0.14, 0, 0.14)], atol=1e-6)
    np.testing.assert_allclose(base.lamp.position[0].numpy(), [dx + 0.24, dy + 0.06, 0.0], atol=1e-6)
    assert 1 <= int(base.flash_trigger_count[0]) <= 8 and 8 <= int(base.flash_duration[0]) <= 14
    assert info["oracle_info"].dtype == torch.uint8 and int(info["oracle_info"][0]) == int(base.flash_color[0])
    assert info["task_cue"] is None and int(info["pressed_button"][0]) == -1
    assert _shown_bulb(base) == "off"
    # Extra state: tcp 7, goal 3, answer 1, disc 7, sticky flags N, 5 scalars, N cube poses.
    assert obs.shape == (1, 9 + 9 + 7 + 3 + 1 + 7 + 9 + 5 + 7 * 9)
    for name in ("cubes", "disc", "button_top_z", "flash_color", "N_CUBES", "DISC_RADIUS", "BUTTON_CAP_TRAVEL"):
        assert hasattr(base, name)


def test_trigger_count_range(make_env):
    env = make_env("GatherAndRecall3-VLA-v0")
    counts = set()
    for seed in range(12):
        env.reset(seed=seed)
        counts.add(int(env.unwrapped.flash_trigger_count[0]))
    assert counts == {1, 2}  # K < N: the flash always comes before the last cube


def test_flash_starts_at_kth_cube_and_lasts_f_steps(make_env):
    env = make_env("GatherAndRecall5-VLA-v0")
    for seed in range(20):  # a seed with K >= 2, so the first cube does not trigger
        env.reset(seed=seed)
        if int(env.unwrapped.flash_trigger_count[0]) >= 2:
            break
    base = env.unwrapped
    k, duration, color = int(base.flash_trigger_count[0]), int(base.flash_duration[0]), int(base.flash_color[0])
    for placed in range(1, k):
        _put_on_disc(base, [placed - 1])
        *_, info = env.step(ZERO)
        assert int(info["n_on_disc"][0]) == placed and not bool(info["flash_triggered"][0])
        assert _shown_bulb(base) == "off"
    _put_on_disc(base, [k - 1])
    *_, info = env.step(ZERO)
    start = int(info["elapsed_steps"][0])
    flash_bulb = base.lamp.bulb_names[color + 1]
    for _ in range(duration + 2):
        e = int(info["elapsed_steps"][0])
        active = start <= e < start + duration
        assert bool(info["flash_active"][0]) == active
        assert _shown_bulb(base) == (flash_bulb if active else "off")
        *_, info = env.step(ZERO)
    assert bool(info["flash_triggered"][0]) and not bool(info["all_on_disc"][0])


def test_on_disc_is_sticky_but_all_on_disc_is_current(make_env):
    env = make_env("GatherAndRecall3-VLA-v0")
    env.reset(seed=1)
    base = env.unwrapped
    _put_on_disc(base, [0, 1, 2])
    *_, info = env.step(ZERO)
    assert bool(info["all_on_disc"][0]) and int(info["n_on_disc"][0]) == 3
    base.cubes[2].set_pose(Pose.create_from_pq(torch.tensor([[-0.1, -0.3, 0.02]])))
    *_, info = env.step(ZERO)
    assert not bool(info["all_on_disc"][0]) and int(info["n_on_disc"][0]) == 3


def test_press_ignored_until_all_cubes_are_on_disc(make_env):
    env = make_env("GatherAndRecall1-VLA-v0")
    env.reset(seed=2)
    base = env.unwrapped
    infos = _press(env, int(base.flash_color[0]), max_steps=45)
    assert float(base.agent.tcp.pose.p[0, 2]) < 0.0831  # pressed, but not recorded
    assert all(int(i["pressed_button"][0]) == -1 and not bool(i["failed"][0]) for i in infos)
    assert not bool(infos[-1]["success"][0])


def test_wrong_button_fails(make_env):
    env = make_env("GatherAndRecall1-VLA-v0", reward_mode="dense")
    env.reset(seed=2)
    base = env.unwrapped
    _put_on_disc(base, [0])
    wrong = (int(base.flash_color[0]) + 1) % 3
    infos = _press(env, wrong)
    last = infos[-1]
    assert int(last["pressed_button"][0]) == wrong
    assert bool(last["failed"][0]) and not bool(last["success"][0])
    _, reward, terminated, _, _ = env.step(ZERO)
    assert bool(terminated[0]) and float(reward[0]) == -25.0


def test_right_button_succeeds(make_env):
    env = make_env("GatherAndRecall1-VLA-v0", reward_mode="normalized_dense")
    env.reset(seed=2)
    base = env.unwrapped
    _put_on_disc(base, [0])
    rewards = []
    for _ in range(3):
        rewards.append(float(env.step(ZERO)[1][0]))
    infos = _press(env, int(base.flash_color[0]))
    assert bool(infos[-1]["success"][0]) and int(infos[-1]["pressed_button"][0]) == int(base.flash_color[0])
    _, reward, terminated, _, info = env.step(ZERO)
    assert bool(terminated[0]) and float(reward[0]) == 1.0
    assert all(0.0 <= r <= 1.0 for r in rewards)
    assert set(info["reward_dict"]) >= {"reaching_reward", "progress", "press_reward", "smooth_penalty"}


def test_reward_goal_follows_the_task(make_env):
    env = make_env("GatherAndRecall1-VLA-v0")
    _, info = env.reset(seed=3)
    base = env.unwrapped
    tcp = base.agent.tcp.pose.p[0]
    np.testing.assert_allclose(info["obj_to_goal_pos"][0].numpy(), (base.cube_positions()[0, 0] - tcp).numpy(), atol=1e-5)
    _put_on_disc(base, [0])
    *_, info = env.step(ZERO)
    tcp = base.agent.tcp.pose.p[0]
    button = base.buttons_xy[int(base.flash_color[0]), 0]
    goal = torch.cat([button, torch.tensor([0.063])])
    np.testing.assert_allclose(info["obj_to_goal_pos"][0].numpy(), (goal - tcp).numpy(), atol=1e-5)


def test_seeded_determinism(make_env):
    env = make_env("GatherAndRecall5-VLA-v0")

    def draw(seed):
        env.reset(seed=seed)
        base = env.unwrapped
        return base.cube_positions()[0].clone(), [int(v[0]) for v in (base.flash_trigger_count, base.flash_duration, base.flash_color)]

    first, again, other = draw(8), draw(8), draw(9)
    assert torch.equal(first[0], again[0]) and first[1] == again[1]
    assert not torch.equal(first[0], other[0])


def test_oracle_presses_the_colour_it_saw(make_env):
    """Changing the env's answer after the flash does not change the button the oracle presses."""
    env = make_env("GatherAndRecall1-VLA-v0")
    obs, _ = env.reset(seed=4242424242)
    base = env.unwrapped
    oracle = make_oracle(env)
    oracle.reset()
    seen = None
    for _ in range(200):
        obs, _, terminated, _, info = env.step(oracle.forward(obs))
        if seen is None and bool(info["flash_active"][0]):
            seen = int(base.flash_color[0])
            base.flash_color[0] = (seen + 1) % 3
        if bool(terminated[0]):
            break
    assert seen is not None
    assert int(info["pressed_button"][0]) == seen and bool(info["failed"][0])
