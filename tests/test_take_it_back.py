"""TakeItBack: layout, the target's colour change, success, reward, the hidden start marker."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mani_skill.utils.structs import Pose
from mikasa_envs.building_blocks.targets import HIDDEN_Z, TARGET_Z, flat_poses
from mikasa_oracles import make_oracle

ENV_ID = "TakeItBack-VLA-v0"
ZERO = np.zeros(7, dtype=np.float32)
INFO_KEYS = {
    "elapsed_steps",
    "success",
    "task_cue",
    "language_instruction",
    "oracle_info",
    "goal_achieved",
    "goal_reached_status",
    "reward_dict",
}


def _place_cube(base, xy) -> None:
    base.cube.set_pose(Pose.create_from_pq(p=torch.tensor([[xy[0], xy[1], 0.02]], dtype=torch.float32)))
    base.cube.set_linear_velocity(torch.zeros(1, 3))
    base.cube.set_angular_velocity(torch.zeros(1, 3))


def _disc_z(actor) -> float:
    return float(actor.pose.p[0, 2])


def test_layout_state_and_info(make_env):
    env = make_env(ENV_ID)
    base = env.unwrapped
    rows = set()
    for seed in range(8):
        obs, info = env.reset(seed=seed)
        assert set(info) - {"reconfigure"} == INFO_KEYS
        assert obs.shape == (1, 39) and info["task_cue"] is None
        start, goal = base.initial_pos[0], base.goal_pos[0]
        torch.testing.assert_close(info["oracle_info"][0], start)
        assert -0.05 <= start[0] < 0.05 and start[2] == pytest.approx(TARGET_Z)
        row = round(float(torch.floor(start[1] / 0.1)))
        assert row in (-1, 0, 1) and 0.0 <= float(start[1]) - 0.1 * row < 0.05 + 1e-6
        rows.add(row)
        assert 0.20 <= goal[0] < 0.25 and -0.025 <= goal[1] < 0.025
        # The cube stands on the (hidden) start marker; the red target is down, purple up.
        torch.testing.assert_close(base.cube.pose.p[0, :2], start[:2])
        assert _disc_z(base.goal_region) == pytest.approx(TARGET_Z)
        assert _disc_z(base.changed_goal_region) == pytest.approx(HIDDEN_Z)
        torch.testing.assert_close(base.initial_region.pose.p[0, :2], start[:2])
        # state: qpos, qvel, tcp_pose, goal_pos, cube_pose, oracle_info, goal_reached_status
        torch.testing.assert_close(obs[0, 25:28], goal)
        torch.testing.assert_close(obs[0, 35:38], start)
        assert float(obs[0, 38]) == 0.0
    assert len(rows) >= 2
    assert base.initial_region in base._hidden_objects
    assert int(base.action_phase_start[0]) == 0


def test_seeded_determinism(make_env):
    env = make_env(ENV_ID)
    base = env.unwrapped
    layouts = []
    for seed in (9, 9, 10):
        env.reset(seed=seed)
        layouts.append(torch.cat([base.initial_pos[0], base.goal_pos[0], base.agent.robot.get_qpos()[0]]))
    torch.testing.assert_close(layouts[0], layouts[1])
    assert not torch.allclose(layouts[0], layouts[2])


def test_goal_swap_lags_one_step_and_success_needs_the_goal_first(make_env):
    env = make_env(ENV_ID, reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=3)
    start, goal = base.initial_pos[0, :2].tolist(), base.goal_pos[0, :2].tolist()
    # At the start (returned) but the target never reached: no success.
    _, reward, *_, info = env.step(ZERO)
    assert not bool(info["success"][0]) and float(reward[0]) < 1.0
    # Onto the target: goal achieved and latched; the colour changes only in the next frame.
    _place_cube(base, [goal[0] - 0.07, goal[1]])
    obs, _, _, _, info = env.step(ZERO)
    assert bool(info["goal_achieved"][0]) and bool(info["goal_reached_status"][0])
    assert _disc_z(base.goal_region) == pytest.approx(TARGET_Z)
    assert float(obs[0, 38]) == 1.0
    _place_cube(base, [0.12, 0.2])  # off the target again
    obs, _, _, _, info = env.step(ZERO)
    assert not bool(info["goal_achieved"][0]) and bool(info["goal_reached_status"][0])
    assert _disc_z(base.goal_region) == pytest.approx(HIDDEN_Z)
    assert _disc_z(base.changed_goal_region) == pytest.approx(TARGET_Z)
    torch.testing.assert_close(obs[0, 25:28], base.goal_pos[0])  # goal_pos unchanged by the swap
    assert not bool(info["success"][0])
    # Back within 0.08 of the start (strict): success, the maximum reward.
    _place_cube(base, [start[0] + 0.079, start[1]])
    _, reward, terminated, _, info = env.step(ZERO)
    assert bool(info["success"][0]) and float(reward[0]) == pytest.approx(1.0) and not bool(terminated[0])
    # The swap is permanent within the episode; a new episode restores the red target.
    assert _disc_z(base.changed_goal_region) == pytest.approx(TARGET_Z)
    env.reset(seed=3)
    assert _disc_z(base.goal_region) == pytest.approx(TARGET_Z)
    assert _disc_z(base.changed_goal_region) == pytest.approx(HIDDEN_Z)
    assert not bool(base.goal_reached_status[0])


def test_dense_reward_terms(make_env):
    env = make_env(ENV_ID, reward_mode="dense")
    base = env.unwrapped
    env.reset(seed=1)
    rewards = []
    for action in (ZERO, ZERO, np.ones(7, dtype=np.float32)):
        _, reward, *_, info = env.step(action)
        rewards.append(float(reward[0]))
    terms = info["reward_dict"]
    assert {"reached_push", "reached_pull", "place_back_reward", "smooth_penalty", "goal_reached_status"} <= set(terms)
    # Before the goal: 2·reaching_push + 1.5·place_goal (+ 5·place·reached) − smoothness.
    assert 0.0 < rewards[0] < 2.0 + 1.5
    # The jump in the action costs the action-delta penalty (0.08·tanh(5Δ)).
    assert rewards[2] < rewards[1]
    assert float(base.goal_reached_status[0]) == 0.0


def test_oracle_remembers_the_start_it_saw_not_oracle_info(make_env):
    env = make_env(ENV_ID)
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=4242424242)
    oracle.reset()
    base.oracle_info = torch.zeros_like(base.oracle_info)  # a blank answer; success still uses the start
    success = False
    for _ in range(60):
        obs, _, _, _, info = env.step(oracle.forward(obs))
        success |= bool(info["success"][0])
    assert success
    np.testing.assert_allclose(oracle.start_xy, base.initial_pos[0, :2].numpy(), atol=1e-6)


def test_start_marker_only_in_human_renders(make_env):
    """The blue start marker is hidden from the sensor cameras, shown in render(); the
    INTERCEPT overlay chain draws on the render."""
    from mikasa_wrappers import apply_mikasa_vla_wrappers

    env = make_env(ENV_ID, obs_mode="rgb", render_mode="rgb_array")
    base = env.unwrapped
    env.reset(seed=2)
    _place_cube(base, [-0.3, -0.4])  # uncover the start spot
    marker_xy = base.initial_pos[0, :2].clone()

    def pictures():
        obs = base.get_obs()
        images = [obs["sensor_data"][cam]["rgb"][0].numpy() for cam in ("base_camera", "hand_camera")]
        frame = env.render()
        return images, np.asarray(frame.cpu() if isinstance(frame, torch.Tensor) else frame)[0]

    with_marker, render_with = pictures()
    base.initial_region.set_pose(flat_poses(marker_xy[None], HIDDEN_Z))
    without_marker, render_without = pictures()
    for seen, unseen in zip(with_marker, without_marker, strict=True):
        np.testing.assert_array_equal(seen, unseen)
    assert (render_with != render_without).any()

    frames = []
    for include_overlays in (False, True):
        wrapped = make_env(ENV_ID, obs_mode="rgb", render_mode="rgb_array")
        wrapped = apply_mikasa_vla_wrappers(wrapped, include_overlays=include_overlays)
        wrapped.reset(seed=2)
        wrapped.step(ZERO)
        frame = wrapped.render()
        frames.append(np.asarray(frame.cpu() if isinstance(frame, torch.Tensor) else frame))
    # Step and reward text (RenderStepInfo, RenderRewardInfo) in the top-left corner only.
    assert (frames[1][..., :100, :300, :] != frames[0][..., :100, :300, :]).mean() > 0.01
    np.testing.assert_array_equal(frames[1][..., 300:, 300:, :], frames[0][..., 300:, 300:, :])


def test_arrival_hands_over_a_scene_that_does_not_show_the_start(make_env):
    """The step the cube first enters the target, the cube is set down at the target's near
    edge and the arm at its rest pose, both at rest: where the push came from (the start
    row) is no longer in view (DEVIATIONS.md, Fixed #29)."""
    from mikasa_envs.base_env import ROBOT_INIT_QPOS

    env = make_env(ENV_ID)
    base = env.unwrapped
    seen_rows = set()
    for seed in range(6):
        obs, _ = env.reset(seed=seed)
        start, goal = base.initial_pos[0, :2], base.goal_pos[0, :2]
        seen_rows.add(round(float(torch.floor(start[1] / 0.1))))
        env.step(ZERO)
        # As a push leaves it: just inside the disc, on the side facing the start.
        toward_start = (start - goal) / torch.linalg.norm(start - goal)
        _place_cube(base, (goal + 0.075 * toward_start).tolist())
        obs, _, _, _, info = env.step(ZERO)
        assert bool(info["goal_achieved"][0]) and bool(info["goal_reached_status"][0])
        cube = base.cube.pose.raw_pose[0]
        expected = torch.tensor([float(goal[0]) - base.HANDOVER_OFFSET, float(goal[1]), base.CUBE_HALFSIZE])
        torch.testing.assert_close(cube[:3], expected, atol=1e-5, rtol=0)
        torch.testing.assert_close(cube[3:], torch.tensor([1.0, 0.0, 0.0, 0.0]), atol=1e-5, rtol=0)
        # state obs: qpos (9), qvel (9) first.
        np.testing.assert_allclose(obs[0, :9].numpy(), ROBOT_INIT_QPOS, atol=1e-5)
        np.testing.assert_allclose(obs[0, 9:18].numpy(), 0.0, atol=1e-6)
        # Only the first arrival hands over: back in the disc later, the cube stays put.
        _place_cube(base, (goal + 0.05 * toward_start).tolist())
        env.step(ZERO)
        torch.testing.assert_close(base.cube.pose.p[0, :2], goal + 0.05 * toward_start, atol=2e-3, rtol=0)
    assert len(seen_rows) >= 2
