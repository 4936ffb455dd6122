"""BunchOfColors, SeqOfColors and ChainOfColors: phases, touch / order / press rules, reward."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mikasa_envs.building_blocks.buttons import BUTTON_CAP_REST_Z, CONFIRM_LIFT
from mikasa_envs.tasks.bunch_of_colors import cue_spot_xyz
from mikasa_oracles import make_oracle
from mikasa_oracles.controller import move_towards

ZERO = np.zeros(7, dtype=np.float32)
ON_TABLE = 1.0  # hidden cubes are parked at z = 1000
SEED = 4242424242


def _visible(base) -> list[int]:
    return np.flatnonzero(base.cube_positions()[0, :, 2].numpy() < ON_TABLE).tolist()


def _run_to(env, t: int, action=ZERO):
    info = None
    while int(env.unwrapped.elapsed_steps[0]) < t:
        *_, info = env.step(action)
    return info


def _run_oracle(env, oracle, obs, steps: int) -> list[dict]:
    infos = []
    for _ in range(steps):
        obs, reward, _, _, info = env.step(oracle.forward(obs))
        info["reward"] = float(reward[0])
        infos.append(info)
    return infos


# --------------------------------------------------------------------- timeline
def test_bunch_cue_shows_targets_at_their_spots_then_nothing_then_all(make_env):
    env = make_env("BunchOfColors5-VLA-v0")
    env.reset(seed=11)
    base = env.unwrapped
    targets = sorted(base.oracle_info[0].tolist())
    cue, start = int(base.cue_steps_per_env[0]), int(base.action_phase_start[0])
    spots = cue_spot_xyz()
    for t in range(start + 7):
        _run_to(env, t)
        positions = base.cube_positions()[0].numpy()
        if t < cue:
            assert _visible(base) == targets
            np.testing.assert_allclose(positions[targets], spots[targets], atol=1e-4)
        elif t < start:
            assert _visible(base) == []
        else:
            assert _visible(base) == list(range(9))
            np.testing.assert_allclose(positions, base.layout_poses[0, :, :3].numpy(), atol=2e-3)
        # The button is on the table in every phase, cap up (nothing presses it).
        assert base.button.cap.pose.p[0, 2] == pytest.approx(BUTTON_CAP_REST_Z, abs=1e-5)


@pytest.mark.parametrize("env_id", ["SeqOfColors5-VLA-v0", "ChainOfColors3-VLA-v0"])
def test_ordered_cue_shows_one_target_at_a_time_at_the_origin(make_env, env_id):
    env = make_env(env_id)
    env.reset(seed=5)
    base = env.unwrapped
    targets = base.oracle_info[0].tolist()
    d = int(base.cue_step_duration_per_env[0])
    cue, start = int(base.cue_steps_per_env[0]), int(base.action_phase_start[0])
    assert cue == d * len(targets) and base.CUE_STEP_DURATION[0] <= d <= base.CUE_STEP_DURATION[1]
    for t in range(start + 1):
        _run_to(env, t)
        if t < cue:
            shown = targets[min(t // d, len(targets) - 1)]
            assert _visible(base) == [shown]
            np.testing.assert_allclose(base.cube_positions()[0, shown].numpy(), [0.0, 0.0, 0.02], atol=1e-4)
        elif t < start:
            assert _visible(base) == []
        else:
            assert _visible(base) == list(range(9))


def test_layout_and_button_placement(make_env):
    env = make_env("ChainOfColors7-VLA-v0")
    env.reset(seed=3)
    base = env.unwrapped
    xy = base.layout_poses[0, :, :2]
    distances = torch.cdist(xy, xy) + torch.eye(9)
    assert distances.min() >= 0.06  # jittered ≥ 6 cm apart (or kept at the nominal point)
    expected = xy.mean(dim=0) + torch.tensor([-0.04, 0.0])
    torch.testing.assert_close(base.button_xy[0], expected)
    assert base.button_xy[0, 0] == pytest.approx(-0.127, abs=0.01)


def test_seeded_determinism(make_env):
    env = make_env("SeqOfColors5-VLA-v0")
    base = env.unwrapped
    draws = []
    for seed in (21, 22, 21):
        obs, _ = env.reset(seed=seed)
        for _ in range(3):
            obs, *_ = env.step(ZERO)
        draws.append(
            (
                base.oracle_info.clone(), base.layout_poses.clone(), base.button_xy.clone(),
                int(base.cue_steps_per_env[0]), int(base.empty_steps_per_env[0]), obs.clone(),
            )
        )
    first, other, again = draws
    for a, b in zip(first, again, strict=True):
        assert torch.equal(a, b) if isinstance(a, torch.Tensor) else a == b
    assert not torch.equal(first[1], other[1])


# ------------------------------------------------------------- contract details
def test_state_observation_and_info_layout(make_env):
    env = make_env("BunchOfColors3-VLA-v0", obs_mode="state_dict")
    obs, info = env.reset(seed=1)
    extra = obs["extra"]
    expected = ["tcp_pose", "obj_to_goal_pos", "oracle_info", "button_xy", "button_pressed"]
    for k in range(9):
        expected += [f"cube_{k}_pose", f"touched_{k}", f"cube_{k}_in_seq", f"next_target_{k}"]
    assert list(extra) == expected
    assert extra["oracle_info"].shape == (1, 3) and extra["oracle_info"].dtype == torch.uint8
    assert extra["cube_0_pose"].shape == (1, 3)
    assert list(info)[:14] == [
        "elapsed_steps", "obj_to_goal_pos", "is_robot_static", "success", "task_cue", "language_instruction",
        "oracle_info", "strong_cube_displacement", "max_cube_displacement_xy", "button_pressed",
        "button_pressable", "button_press_depth", "xy_dist_to_button", "reward_dict",
    ]
    assert info["task_cue"] is None
    flat = make_env("BunchOfColors3-VLA-v0")
    state, _ = flat.reset(seed=1)
    assert state.shape == (1, 9 + 9 + 7 + 3 + 3 + 2 + 1 + 9 * 6)


def test_attributes_the_overlay_reads(make_env):
    env = make_env("ChainOfColors5-VLA-v0")
    env.reset(seed=0)
    base = env.unwrapped
    assert base.touched_cubes.shape == (1, 9) and base.touched_cubes.dtype == torch.bool
    assert torch.equal(base.true_color_indices, base.oracle_info)
    assert sorted(base.color_dict) == list(range(9)) and sorted(base.cubes) == list(range(9))
    assert base.cue_steps_per_env.dtype == torch.int64 and base.empty_steps_per_env.dtype == torch.int64
    assert base.button_top_z == pytest.approx(0.058) and base.CUBE_HALFSIZE == pytest.approx(0.02)
    assert base.touched_cubes_idx.tolist() == [[-1] * 5]


def test_overlay_marks_targets_in_rgb(make_env):
    from mikasa_wrappers import apply_mikasa_vla_wrappers

    frames = []
    for include_overlays in (False, True):
        env = make_env("BunchOfColors3-VLA-v0", obs_mode="rgb", render_mode="rgb_array")
        env = apply_mikasa_vla_wrappers(env, include_overlays=include_overlays)
        env.reset(seed=0)
        env.step(ZERO)
        frame = env.render()
        frames.append(np.asarray(frame.cpu() if isinstance(frame, torch.Tensor) else frame))
    plain, overlaid = frames
    assert (overlaid[..., 40:65, :250, :] != plain[..., 40:65, :250, :]).mean() > 0.01


# ------------------------------------------------------------ success and failure
@pytest.mark.parametrize("env_id", ["BunchOfColors3-VLA-v0", "SeqOfColors3-VLA-v0", "ChainOfColors3-VLA-v0"])
def test_oracle_episode_rewards_and_latches(make_env, env_id):
    env = make_env(env_id, reward_mode="normalized_dense")
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=SEED)
    oracle.reset()
    start = int(base.action_phase_start[0])
    infos = _run_oracle(env, oracle, obs, start + 80)
    rewards = np.array([i["reward"] for i in infos])
    assert ((rewards >= 0) & (rewards <= 1)).all()
    assert (rewards[: start - 1] == 0).all()  # cue and memory frames earn nothing
    success_steps = [t for t, i in enumerate(infos) if bool(i["success"][0])]
    assert success_steps and rewards[success_steps[0]] == 1.0
    assert base.touched_cubes[0].tolist() == base.sequence_cubes_mask[0].tolist()
    assert bool(base.button_pressed[0]) and int(base.button_press_count[0]) == 1
    assert infos[success_steps[0] + 1]["reward_dict"]["all_seq_touched"].tolist() == [True]
    if hasattr(base, "touched_cubes_idx"):
        assert base.touched_cubes_idx[0].tolist() == base.oracle_info[0].tolist()


def _count_success(infos: list[dict]) -> int:
    return sum(bool(i["success"][0]) for i in infos)


def _bunch_episode(make_env):
    """A BunchOfColors3 episode at its reset, with its oracle: (env, base env, oracle, obs)."""
    env = make_env("BunchOfColors3-VLA-v0")
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=SEED)
    oracle.reset()
    return env, env.unwrapped, oracle, obs


def _oracle_until_pressable(make_env):
    """A BunchOfColors3 episode driven by its oracle up to the first pressable frame."""
    env, base, oracle, obs = _bunch_episode(make_env)
    while not bool(base.button_pressable[0]):
        obs, *_ = env.step(oracle.forward(obs))
    return env, base


def _push_a_non_target_cube(base, dx: float = 0.07) -> None:
    key = next(k for k in range(9) if not base.sequence_cubes_mask[0, k])
    pose = base.cubes[key].pose.raw_pose.clone()
    pose[0, 0] += dx
    base.cubes[key].set_pose(pose)


def test_bunch_wrong_touch_blocks_pressing(make_env):
    env, base, oracle, obs = _bunch_episode(make_env)
    targets = base.oracle_info[0].tolist()
    wrong = next(k for k in range(9) if k not in targets)
    oracle.plan = [wrong, *targets]
    infos = _run_oracle(env, oracle, obs, int(base.action_phase_start[0]) + 110)
    assert base.touched_cubes[0, wrong] and base.touched_cubes[0, targets].all()
    assert _count_success(infos) == 0 and not bool(base.button_pressed[0])
    assert not any(bool(i["button_pressable"][0]) for i in infos)
    # The oracle did push the TCP down over the button: the press was ignored entirely.
    assert min(float(i["xy_dist_to_button"][0]) for i in infos) < 0.065
    assert oracle.press_start is not None and not bool(base.press_latch.pending[0])
    assert int(infos[-1]["reward_dict"]["wrong_touches"][0]) == 1
    # No goal is left: the reaching term pays nothing (DEVIATIONS.md Fixed #30), not 1 − tanh(0).
    assert float(infos[-1]["reward_dict"]["reaching_reward"][0]) == 0.0


@pytest.mark.parametrize("env_id", ["SeqOfColors3-VLA-v0", "ChainOfColors3-VLA-v0"])
def test_ordered_families_reject_the_right_set_in_the_wrong_order(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=SEED)
    oracle.reset()
    targets = base.oracle_info[0].tolist()
    oracle.plan = targets[::-1]
    infos = _run_oracle(env, oracle, obs, int(base.action_phase_start[0]) + 100)
    assert base.touched_cubes[0].tolist() == base.sequence_cubes_mask[0].tolist()
    assert base.touched_cubes_idx[0].tolist() == targets[::-1]
    assert _count_success(infos) == 0 and not bool(base.button_pressed[0])
    assert not any(bool(i["button_pressable"][0]) for i in infos)
    rd = infos[-1]["reward_dict"]
    if env_id.startswith("Chain"):
        # Only the middle slot holds its target; the two others count as wrong, and the
        # next target stays stuck at the first slot.
        assert int(rd["correct_touches_in_order"][0]) == 1 and int(rd["wrong_touches"][0]) == 2
        assert np.flatnonzero(base.next_target_mask[0].numpy()).tolist() == [targets[0]]
    else:
        # Seq counts touched targets regardless of order; after the wrong-order touch
        # there is no next target.
        assert int(rd["correct_touches"][0]) == 3 and int(rd["wrong_touches"][0]) == 0
        assert not bool(base.next_target_mask.any())


def test_press_needs_a_lift_and_the_cap_follows_the_tcp(make_env):
    env, base = _oracle_until_pressable(make_env)
    tcp_pose = base.agent.tcp.pose.raw_pose[0].numpy()
    button = np.array([*base.button_xy[0].tolist(), 0.07])
    lowest = 1.0
    for _ in range(25):  # down over the button and stay down: no confirmed press
        tcp_pose = base.agent.tcp.pose.raw_pose[0].numpy()
        *_, info = env.step(move_towards(tcp_pose, button, gain=1.5, gripper=-1.0))
        depth = float(info["button_press_depth"][0])
        assert base.button.cap.pose.p[0, 2] == pytest.approx(BUTTON_CAP_REST_Z - depth, abs=1e-5)
        lowest = min(lowest, float(base.agent.tcp.pose.p[0, 2]))
    assert lowest < 0.0831 and bool(base.press_latch.pending[0]) and not bool(base.button_pressed[0])
    assert float(info["button_press_depth"][0]) > 0.0049
    # Once the press has registered the goal is the lift that confirms it (DEVIATIONS.md
    # Fixed #31), straight above the button: rising is what the reaching term pays for.
    lift_z = float(base.press_latch.press_start_z[0]) + CONFIRM_LIFT + base.LIFT_GOAL_MARGIN
    goal = base.agent.tcp.pose.p[0] + info["obj_to_goal_pos"][0]
    np.testing.assert_allclose(goal.numpy(), [*base.button_xy[0].tolist(), lift_z], atol=1e-6)
    for _ in range(30):  # lift 0.1 m: confirmed
        tcp_pose = base.agent.tcp.pose.raw_pose[0].numpy()
        *_, info = env.step(move_towards(tcp_pose, button + [0, 0, 0.11], gain=1.5, gripper=-1.0))
    assert bool(base.button_pressed[0]) and bool(info["success"][0])
    assert base.button.cap.pose.p[0, 2] == pytest.approx(BUTTON_CAP_REST_Z, abs=1e-5)


def test_the_rise_that_confirms_a_press_is_paid_for(make_env):
    env, base = _oracle_until_pressable(make_env)
    button = np.array([*base.button_xy[0].tolist(), 0.07])

    def step_towards(goal):
        tcp_pose = base.agent.tcp.pose.raw_pose[0].numpy()
        _, reward, *_, info = env.step(move_towards(tcp_pose, goal, gain=1.5, gripper=-1.0))
        rise = float(base.agent.tcp.pose.p[0, 2] - base.press_latch.press_start_z[0])
        return float(reward[0]) * base.DENSE_REWARD_MAX, rise, info  # the VLA id's normalized_dense

    for _ in range(25):  # down over the button: a press registers
        reward_down, rise_down, _ = step_towards(button)
    assert bool(base.press_latch.pending[0]) and rise_down < 0.01
    rewards = []  # (reward, rise) while the press waits for its lift
    while not bool(base.button_pressed[0]):
        reward, rise, info = step_towards(button + [0, 0, 0.11])
        if bool(base.press_latch.pending[0]):
            rewards.append((reward, rise))
    # The lift term pays 90 x the share of the 0.085 m rise done (DEVIATIONS.md Fixed #33); the
    # other terms (reaching, static) move by less than 1.5 a step.
    reward_up, rise_up = max(rewards, key=lambda r: r[1])
    assert rise_up > CONFIRM_LIFT / 2
    lift_paid = base.LIFT_REWARD * (min(rise_up / CONFIRM_LIFT, 1.0) - max(rise_down, 0.0) / CONFIRM_LIFT)
    assert reward_up - reward_down == pytest.approx(lift_paid, abs=1.5)
    # Confirmed: the term stays whole (touch 90 + lift 90 + the rest), or the step is a success.
    reward_confirmed = step_towards(button + [0, 0, 0.11])[0]
    assert reward_confirmed == 400.0 or reward_confirmed > base.CORRECT_TOUCH_REWARD + base.LIFT_REWARD


def test_strong_displacement_blocks_success(make_env):
    env, base, oracle, obs = _bunch_episode(make_env)
    infos = _run_oracle(env, oracle, obs, int(base.action_phase_start[0]) + 80)
    assert _count_success(infos) > 0 and bool(infos[-1]["success"][0])
    _push_a_non_target_cube(base)  # 7 cm: the success flag (not latched) drops
    *_, info = env.step(oracle.forward(obs))
    assert bool(info["strong_cube_displacement"][0]) and not bool(info["success"][0])
    assert float(info["max_cube_displacement_xy"][0]) > 0.06


def test_displacement_before_the_press_ends_the_reaching_and_touch_rewards(make_env):
    env, base = _oracle_until_pressable(make_env)
    _, reward_clean, *_, info = env.step(ZERO)
    assert float(info["reward_dict"]["reaching_reward"][0]) > 0.0  # aiming at the button
    _push_a_non_target_cube(base)
    env.step(ZERO)
    _, reward_shoved, *_, info = env.step(ZERO)  # reward_dict is the previous step's
    assert not bool(info["button_pressable"][0]) and not info["obj_to_goal_pos"].any()
    # No goal left: no reaching term (DEVIATIONS.md Fixed #30); a cube pushed > 6 cm: no touch
    # term either (Fixed #32), so the step earns at most the static term's 0.5, not 90 + 0.5.
    assert float(info["reward_dict"]["reaching_reward"][0]) == 0.0
    assert int(info["reward_dict"]["correct_touches"][0]) == 3
    assert 0.0 < float(reward_shoved[0]) < float(reward_clean[0]) / 150


@pytest.mark.parametrize(("push", "care"), [(0.01, 1.0), (0.04, 0.5)])
def test_a_push_short_of_six_cm_shrinks_the_touch_term(make_env, push, care):
    # Fixed #34: the touch (and lift) terms shrink linearly from a 2 cm push to nothing at 6 cm.
    env, base = _oracle_until_pressable(make_env)
    env.step(ZERO)
    _, reward_clean, *_ = env.step(ZERO)
    _push_a_non_target_cube(base, dx=push)
    env.step(ZERO)
    _, reward_pushed, *_, info = env.step(ZERO)
    assert bool(info["button_pressable"][0])  # still pressable: the push stays under 6 cm
    assert float(info["max_cube_displacement_xy"][0]) == pytest.approx(push, abs=0.003)
    lost = (1.0 - care) * base.CORRECT_TOUCH_REWARD  # the rest moves by < 1.5 (normalized: / 400)
    assert float(reward_clean[0] - reward_pushed[0]) == pytest.approx(lost / base.DENSE_REWARD_MAX, abs=1.5 / 400)


def test_touches_during_the_cue_do_not_count(make_env):
    env = make_env("BunchOfColors3-Long-VLA-v0", reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=3)  # C = 45, cube 0 is a target and shown at (0.038, -0.157)
    assert 0 in base.oracle_info[0].tolist() and int(base.cue_steps_per_env[0]) >= 40
    goal = base.cube_positions()[0, 0].numpy() + [0.0, 0.0, 0.035]
    reached_still = False
    while int(base.elapsed_steps[0]) < int(base.cue_steps_per_env[0]) - 1:
        tcp_pose = base.agent.tcp.pose.raw_pose[0].numpy()
        _, reward, *_, info = env.step(move_towards(tcp_pose, goal, gain=1.5, gripper=-1.0))
        assert float(reward[0]) == 0.0
        near = np.linalg.norm(base.agent.tcp.pose.p[0].numpy() - (goal - [0, 0, 0.01])) < 0.02
        reached_still |= near and bool(info["is_robot_static"][0])
    assert reached_still and not bool(base.touched_cubes.any())
