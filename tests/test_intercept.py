"""Intercept and InterceptGrab: launch, ball motion, success and reward terms, determinism."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mikasa_oracles import make_oracle, rollout

ZERO = np.zeros(7, dtype=np.float32)
INTERCEPT_IDS = ["InterceptSlow-VLA-v0", "InterceptMedium-VLA-v0", "InterceptFast-VLA-v0"]
GRAB_IDS = ["InterceptGrabSlow-VLA-v0", "InterceptGrabMedium-VLA-v0", "InterceptGrabFast-VLA-v0"]
VELOCITY_RANGES = {"Slow": (0.25, 0.50), "Medium": (0.50, 0.75), "Fast": (0.75, 1.00)}
INTERCEPT_INFO = {"elapsed_steps", "success", "task_cue", "language_instruction", "oracle_info", "reward_dict"}
GRAB_INFO = INTERCEPT_INFO | {"is_ball_grasped", "is_robot_static"}


def _speed_range(env_id: str) -> tuple[float, float]:
    return next(r for name, r in VELOCITY_RANGES.items() if name in env_id)


def _place_ball(base, xyz, velocity=(0.0, 0.0, 0.0)) -> None:
    from mani_skill.utils.structs import Pose

    base.ball.set_pose(Pose.create_from_pq(p=torch.tensor([xyz], dtype=torch.float32)))
    base.ball.set_linear_velocity(torch.tensor([velocity], dtype=torch.float32))
    base.ball.set_angular_velocity(torch.zeros(1, 3))


def _ball_drawn(base) -> bool:
    """Whether the ball's visual twin stands on the ball (else it waits out of view)."""
    twin, ball = base.ball_visual.pose.p[0], base.ball.pose.p[0]
    if torch.allclose(twin, ball):
        return True
    assert float(twin[2]) < -100, (twin, ball)
    return False


@pytest.mark.parametrize("env_id", INTERCEPT_IDS + GRAB_IDS)
def test_launch_layout_and_state(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    grab = "Grab" in env_id
    lo, hi = _speed_range(env_id)
    for seed in (0, 1, 2):
        obs, info = env.reset(seed=seed)
        assert set(info) - {"reconfigure"} == (GRAB_INFO if grab else INTERCEPT_INFO)
        assert info["task_cue"] is None and info["reward_dict"] is None
        assert obs.shape == (1, 49 if grab else 50)
        start, launch = base.ball_start_pos[0], info["oracle_info"][0]
        assert -0.35 <= start[0] < -0.05 and -0.90 <= start[1] < -0.65
        assert start[2] == pytest.approx(0.02 if grab else 0.04)
        assert 0.0 <= launch[0] < 0.05 and lo <= launch[1] < hi and launch[2] == 0
        # The ball is launched at reset; state = qpos, qvel, tcp_pose, then the task's keys.
        torch.testing.assert_close(base.ball.linear_velocity[0], launch)
        extra = obs[0, 25:]
        if grab:
            torch.testing.assert_close(extra[7:10], launch)  # after ball_pose
            assert float(extra[10]) == 0.0 and float(extra[-4]) == pytest.approx(0.08, abs=1e-3)
        else:
            goal = base.goal_pos[0]
            assert goal[0] == pytest.approx(float(start[0]) + 0.2, abs=1e-6) and -0.2 <= goal[1] < 0.2
            torch.testing.assert_close(extra[:3], goal)
            torch.testing.assert_close(extra[10:13], launch)  # after goal_pos, ball_pose
    # No phases: the curriculum wrapper never freezes these tasks.
    assert int(base.action_phase_start[0]) == 0


@pytest.mark.parametrize("env_id", ["InterceptMedium-VLA-v0", "InterceptGrabFast-VLA-v0"])
def test_seeded_determinism(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    snapshots = []
    for seed in (5, 5, 6):
        env.reset(seed=seed)
        for _ in range(4):
            env.step(ZERO)
        snapshots.append(
            torch.cat([base.oracle_info[0], base.ball.pose.raw_pose[0], base.agent.robot.get_qpos()[0]])
        )
    torch.testing.assert_close(snapshots[0], snapshots[1])
    assert not torch.allclose(snapshots[0], snapshots[2])


def test_ball_rolls_at_five_sevenths_of_the_launch_speed(make_env):
    env = make_env("InterceptGrabSlow-VLA-v0")
    base = env.unwrapped
    env.reset(seed=3)
    launch = base.launch_velocity[0, :2]
    for _ in range(8):
        env.step(ZERO)
    rolling = base.ball.linear_velocity[0, :2]
    assert float(torch.linalg.norm(rolling) / torch.linalg.norm(launch)) == pytest.approx(5 / 7, abs=0.02)
    # Heading unchanged: mostly +y, drifting +x.
    assert float(rolling[0] / rolling[1]) == pytest.approx(float(launch[0] / launch[1]), abs=0.01)


def test_intercept_success_needs_the_ball_over_the_target_and_a_touch(make_env):
    env = make_env("InterceptSlow-VLA-v0", reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=4)
    goal = base.goal_pos[0].tolist()
    # Over the target, never touched: no success (the ball may drift over it by itself).
    _place_ball(base, [goal[0] + 0.05, goal[1], 0.02])
    _, reward, terminated, _, info = env.step(ZERO)
    assert not bool(base.ball_touched[0]) and not bool(info["success"][0])
    assert 0.0 <= float(reward[0]) < 1.0 and not bool(terminated[0])
    # Touched, and over the target: success (strict < 0.1), the maximum reward.
    base.ball_touched[0] = True
    _place_ball(base, [goal[0] + 0.05, goal[1], 0.02])
    _, reward, _, _, info = env.step(ZERO)
    assert bool(info["success"][0]) and float(reward[0]) == pytest.approx(1.0)
    # Touched but 0.1 away: no success.
    _place_ball(base, [goal[0], goal[1] - 0.101, 0.02])
    _, reward, _, _, info = env.step(ZERO)
    assert not bool(info["success"][0]) and float(reward[0]) < 1.0
    assert set(info["reward_dict"]) == {"reaching_reward", "reached_status", "place_reward", "tcp_to_hit_pose_dist"}
    # A new episode forgets the touch.
    env.reset(seed=4)
    assert not bool(base.ball_touched[0])


def test_robot_contact_marks_the_ball_touched(make_env):
    from mikasa_oracles.controller import move_towards

    env = make_env("InterceptFast-VLA-v0")
    base = env.unwrapped
    env.reset(seed=0)
    tcp = base.agent.tcp.pose.raw_pose[0].numpy()
    # A ball at rest 4 cm in front of where the fingertips come down, then a push into it.
    _place_ball(base, [tcp[0] + 0.04, tcp[1], 0.02])
    for target in [(tcp[0], tcp[1], 0.02)] * 12 + [(tcp[0] + 0.05, tcp[1], 0.02)] * 3:
        tcp = base.agent.tcp.pose.raw_pose[0].numpy()
        env.step(move_towards(tcp, np.array(target), gain=1.5, gripper=-1.0))
        if int(base.elapsed_steps[0]) == 12:
            assert not bool(base.ball_touched[0])  # down beside the ball, not yet touching
            assert not bool(base.ball_visible[0])  # out of view after its first 10 frames
    assert bool(base.ball_touched[0])
    assert bool(base.ball_visible[0]) and _ball_drawn(base)  # back in view


def test_intercept_dense_reward_latches_reached_status(make_env):
    env = make_env("InterceptMedium-VLA-v0", reward_mode="dense")
    base = env.unwrapped
    env.reset(seed=2)
    _, reward, *_ = env.step(ZERO)
    assert 0.0 < float(reward[0]) < 2.0  # 2·reaching, far from the hit point
    assert float(base.reached_status[0]) == 0.0
    # Put the ball 7 cm in front of the TCP along the goal→ball line: the TCP is at the hit point.
    goal = base.goal_pos[0]
    tcp = base.agent.tcp.pose.p[0]
    away = torch.nn.functional.normalize(tcp - goal, dim=0)
    _place_ball(base, (tcp - away * 0.07).tolist())
    env.step(ZERO)
    assert float(base.reached_status[0]) == 1.0
    _place_ball(base, [0.3, 0.3, 0.02])
    env.step(ZERO)
    assert float(base.reached_status[0]) == 1.0  # latched until the next episode


@pytest.mark.parametrize("env_id", ["InterceptFast-VLA-v0", "InterceptGrabMedium-VLA-v0"])
def test_oracle_estimates_the_launch_from_frames_not_oracle_info(make_env, env_id):
    """The oracle solves the episode with the published launch velocity blanked out."""
    env = make_env(env_id)
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=4242424242)
    oracle.reset()
    base.oracle_info = torch.zeros_like(base.oracle_info)
    success = False
    for _ in range(60):
        obs, _, _, _, info = env.step(oracle.forward(obs))
        success |= bool(info["success"][0])
    assert success


def test_grab_success_is_grasped_and_static(make_env):
    env = make_env("InterceptGrabFast-VLA-v0", reward_mode="normalized_dense")
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, info = env.reset(seed=4242424243)
    oracle.reset()
    assert not bool(info["is_ball_grasped"][0])
    for _ in range(60):
        obs, reward, _, _, info = env.step(oracle.forward(obs))
        if bool(info["success"][0]):
            break
    assert bool(info["is_ball_grasped"][0]) and bool(info["is_robot_static"][0])
    assert float(reward[0]) == pytest.approx(1.0)
    assert float(base.gripper_width()[0]) < 0.04  # closed on the 4 cm ball
    # Open the gripper: the ball is released, no success.
    release = ZERO.copy()
    release[6] = 1.0
    for _ in range(3):
        *_, info = env.step(release)
    assert not bool(info["is_ball_grasped"][0]) and not bool(info["success"][0])
    assert "ball_in_gripper" in info["reward_dict"] and "robot_static_reward" in info["reward_dict"]


@pytest.mark.parametrize("env_id", ["InterceptSlow-VLA-v0", "InterceptGrabSlow-VLA-v0"])
def test_zero_actions_never_succeed(make_env, env_id):
    class Zero:
        def reset(self) -> None:
            pass

        def forward(self, obs):
            return ZERO

    env = make_env(env_id)
    # 4242424242: a slow ball drifting over the target by itself (touch rule, DEVIATIONS.md).
    assert not any(rollout(env, Zero(), seed).success_once for seed in (4242424242, 4242424247))


@pytest.mark.parametrize("env_id", ["InterceptMedium-VLA-v0", "InterceptGrabSlow-VLA-v0"])
def test_ball_in_view_for_ten_frames_then_until_touched(make_env, env_id):
    """The cameras show the ball in frames 0-9, then not until a robot link touches it; a
    restored state brings back the view of its frame."""
    env = make_env(env_id)
    base = env.unwrapped
    env.reset(seed=3)
    shown, saved = [], None
    for frame in range(14):
        shown.append(bool(base.ball_visible[0]))
        assert _ball_drawn(base) == shown[-1]
        if frame == 5:
            saved = env.unwrapped.get_state_dict()
        env.step(ZERO)
    assert shown == [True] * 10 + [False] * 4
    # The physics and the privileged state go on as before: the ball keeps rolling.
    assert float(base.ball.linear_velocity[0, 1]) > 0.1
    env.unwrapped.set_state_dict(saved)
    assert int(base.elapsed_steps[0]) == 5 and _ball_drawn(base)
    for _ in range(6):
        env.step(ZERO)
    assert not _ball_drawn(base)
    base.ball_touched[0] = True  # as a push on the ball would latch it
    env.step(ZERO)
    assert bool(base.ball_visible[0]) and _ball_drawn(base)
    env.reset(seed=3)  # a new episode: in view, untouched
    assert bool(base.ball_visible[0]) and not bool(base.ball_touched[0])


def test_ball_view_option_and_the_rl_release_keep_it_in_view(make_env):
    import mikasa_robo_rl  # noqa: F401  (registers the RL ids)

    always = make_env("InterceptGrabFast-VLA-v0", ball_shown_steps=None)
    rl = make_env("InterceptMedium-v0")
    rl_hidden = make_env("InterceptSlow-v0", ball_shown_steps=3)
    for env in (always, rl, rl_hidden):
        env.reset(seed=0)
        for _ in range(12):
            env.step(ZERO)
    assert bool(always.unwrapped.ball_visible[0]) and bool(rl.unwrapped.ball_visible[0])
    assert not bool(rl_hidden.unwrapped.ball_visible[0])
    for bad in (0, -2, 2.5, True, "10"):
        with pytest.raises(ValueError, match="ball_shown_steps=.*accepted values: an int >= 1"):
            make_env("InterceptSlow-VLA-v0", ball_shown_steps=bad)


def test_camera_frames_lose_the_ball_after_ten_frames(make_env):
    """rgb: the red ball's pixels in the base camera are there in frame 9, gone in frame 10."""
    env = make_env("InterceptGrabSlow-VLA-v0", obs_mode="rgb")
    obs, _ = env.reset(seed=0)

    def red_pixels(obs) -> int:
        rgb = obs["sensor_data"]["base_camera"]["rgb"][0].int()
        return int(((rgb[..., 0] > 150) & (rgb[..., 1] < 60) & (rgb[..., 2] < 60)).sum())

    counts = [red_pixels(obs)]
    for _ in range(10):
        obs, *_ = env.step(ZERO)
        counts.append(red_pixels(obs))
    assert min(counts[:10]) > 0 and counts[10] == 0


def test_grab_oracle_reads_no_ball_position_out_of_view(make_env):
    """The oracle succeeds when the ball's position is NaN whenever the cameras do not show
    it: it predicts the path from the frames it saw. (InterceptGrab's own success test does
    not read ``ball_position``.)"""
    env = make_env("InterceptGrabMedium-VLA-v0")
    base = env.unwrapped
    seen = base.ball_position
    base.ball_position = lambda: seen() if bool(base.ball_visible[0]) else torch.full((1, 3), float("nan"))
    assert rollout(env, make_oracle(env), 4242424242, stop_on_success=True).success_once


def test_memoryless_oracle_meets_the_ball_only_while_it_stays_in_view(make_env):
    """The leak this closes (DEVIATIONS.md, Fixed #35): with the ball in view every frame,
    the memoryless oracle (a guessed velocity, the ball it sees now) catches slow balls; out
    of view, its guessed path catches none of the same seeds."""
    seeds = [4242424242 + i for i in range(8)]
    in_view = make_env("InterceptGrabSlow-VLA-v0", ball_shown_steps=None)
    out_of_view = make_env("InterceptGrabSlow-VLA-v0")
    caught = {}
    for name, env in (("in view", in_view), ("out of view", out_of_view)):
        policy = make_oracle(env, memoryless=True)
        caught[name] = sum(rollout(env, policy, seed, stop_on_success=True).success_once for seed in seeds)
    assert caught["in view"] >= 3 and caught["out of view"] == 0
