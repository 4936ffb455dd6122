"""BlinkCountButtonPress: blink schedule and phases, press counting, submit, reward, oracle."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mani_skill.utils.registration import REGISTERED_ENVS
from mikasa_envs import get_task
from mikasa_envs.building_blocks.buttons import BUTTON_CAP_REST_Z
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z
from mikasa_envs.tasks.blink_count_button_press import BlinkCountButtonPressVLABaseEnv
from mikasa_oracles import make_oracle
from mikasa_oracles.controller import move_towards
from mikasa_wrappers import apply_mikasa_vla_wrappers

EASY = "BlinkCountButtonPressEasy-VLA-v0"
MEDIUM = "BlinkCountButtonPressMedium-VLA-v0"
HARD_LONG = "BlinkCountButtonPressHard-Long-VLA-v0"
VARIANTS = {
    EASY: ((1, 3), (5, 10)),
    MEDIUM: ((1, 5), (5, 10)),
    "BlinkCountButtonPressHard-VLA-v0": ((1, 7), (5, 10)),
    "BlinkCountButtonPressEasy-Long-VLA-v0": ((1, 10), (5, 50)),
    "BlinkCountButtonPressMedium-Long-VLA-v0": ((10, 20), (5, 50)),
    HARD_LONG: ((20, 30), (5, 50)),
}
INFO_KEYS = [
    "elapsed_steps", "success", "failed", "submit_attempted", "submit_success", "action_mask", "phase_ready",
    "light_on", "press_count", "raw_press_count", "target_blinks", "new_raw_press_event", "new_press_event",
    "new_release_event", "new_confirm_press_event", "press_ready", "pending_press", "lift_target_z",
    "at_lift_target", "xy_dist_to_button", "press_depth", "xy_dist_to_confirm_button", "confirm_press_depth",
    "obj_to_goal_pos", "task_cue", "language_instruction", "oracle_info", "reward_dict",
]
EXTRA_OBS_KEYS = [
    "tcp_pose", "button_base_pose", "button_cap_pose", "confirm_button_base_pose", "confirm_button_cap_pose",
    "indicator_pose", "phase_indicator_pose", "press_count", "target_blinks", "action_mask", "phase_ready",
    "press_ready", "pending_press", "submit_attempted", "submit_success", "at_lift_target", "oracle_info",
]
PARK_Z, PUSH_Z, LIFT_Z = 0.16, 0.065, 0.18


class _Driver:
    """Steps an env with the TCP driven to goals (gripper closed); keeps the latest outcome."""

    def __init__(self, env) -> None:
        self.env = env
        self.base: BlinkCountButtonPressVLABaseEnv = env.unwrapped
        self.infos: list[dict] = []
        self.rewards: list[float] = []
        self.terminated = False

    def step(self, action: np.ndarray) -> dict:
        _, reward, terminated, _, info = self.env.step(action)
        self.infos.append(info)
        self.rewards.append(float(reward[0]))
        self.terminated = bool(terminated[0])
        return info

    def tcp(self) -> np.ndarray:
        return self.base.agent.tcp.pose.raw_pose[0].numpy()

    def go(self, xy, z: float, tol: float = 0.005, max_steps: int = 30) -> None:
        goal = np.array([float(xy[0]), float(xy[1]), z])
        for _ in range(max_steps):
            if np.linalg.norm(self.tcp()[:3] - goal) < tol or self.terminated:
                return
            self.step(move_towards(self.tcp(), goal, gripper=-1.0))

    def park_until_ready(self) -> None:
        """Wait above the red button until the phase lamp turns green."""
        xy = self.base.button_xy[0]
        while not bool(self.base.action_mask[0]):
            self.step(move_towards(self.tcp(), np.array([float(xy[0]), float(xy[1]), PARK_Z]), gripper=-1.0))

    def press(self, which: str = "red") -> None:
        xy = (self.base.button_xy if which == "red" else self.base.confirm_button_xy)[0]
        self.go(xy, PARK_Z, tol=0.01)
        self.go(xy, PUSH_Z)
        self.go(xy, LIFT_Z, tol=0.01)


def _reset(make_env, env_id: str, seed: int, **kwargs) -> _Driver:
    kwargs.setdefault("reward_mode", "normalized_dense")
    env = make_env(env_id, **kwargs)
    env.reset(seed=seed)
    return _Driver(env)


# ----------------------------------------------------------------------- contract
@pytest.mark.parametrize("env_id", list(VARIANTS))
def test_variants_registered_with_their_ranges(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    counts, pre = VARIANTS[env_id]
    assert base.BLINK_COUNT_RANGE == counts and base.PRE_BLINK_STEPS == pre
    assert base.BLINK_ON_STEPS == 3 and base.BLINK_OFF_STEPS == (3, 5)
    assert REGISTERED_ENVS[env_id].max_episode_steps == get_task(env_id).max_episode_steps
    assert base.LANGUAGE_INSTRUCTION == get_task(env_id).language_instruction
    # The schedule is consistent for a few seeds: N, P and dark times in range, C as specified.
    for seed in range(3):
        env.reset(seed=seed)
        n = int(base.target_blinks[0])
        starts = base.blink_start_steps[0, :n]
        off = base.blink_off_schedule[0, :n]
        assert counts[0] <= n <= counts[1]
        assert pre[0] <= int(starts[0]) <= pre[1]
        assert bool(((off >= 3) & (off <= 5)).all()) and bool((base.blink_on_schedule[0, :n] == 3).all())
        assert torch.equal(starts[1:] - starts[:-1], 3 + off[:-1])
        assert int(base.cue_steps_per_env[0]) == int(starts[0]) + int((3 + off).sum())
        assert int(base.empty_steps_per_env[0]) == 0
        assert bool((base.blink_start_steps[0, n:] == -1).all())


def test_info_and_observation_layout(make_env):
    env = make_env(MEDIUM, obs_mode="state_dict")
    obs, info = env.reset(seed=11)
    base = env.unwrapped
    assert list(info) == INFO_KEYS + ["reconfigure"]
    _, _, _, _, info = env.step(np.zeros(7, dtype=np.float32))
    assert list(info) == INFO_KEYS
    assert info["task_cue"] is None
    assert info["press_count"].dtype == torch.int64
    assert info["oracle_info"].dtype == torch.uint8
    assert int(info["oracle_info"][0]) == int(info["target_blinks"][0]) == int(base.target_blinks[0])
    assert list(obs["extra"]) == EXTRA_OBS_KEYS
    xy, confirm_xy = base.button_xy[0], base.confirm_button_xy[0]
    assert -0.15 <= float(xy[0]) < -0.05 and -0.12 <= float(xy[1]) < 0.12
    assert torch.allclose(confirm_xy, xy + torch.tensor([0.0, 0.16]))
    assert base.button_top_z == base.confirm_button_top_z == pytest.approx(0.058)
    np.testing.assert_allclose(obs["extra"]["button_cap_pose"][0, :3], [*xy.tolist(), BUTTON_CAP_REST_Z], atol=1e-6)
    np.testing.assert_allclose(obs["extra"]["indicator_pose"][0, :3], [float(xy[0]) + 0.22, float(xy[1]), 0], atol=1e-6)
    np.testing.assert_allclose(
        obs["extra"]["phase_indicator_pose"][0, :3], [float(xy[0]) + 0.22, float(xy[1]) - 0.2, 0], atol=1e-6
    )


def test_seeded_episodes_are_deterministic(make_env):
    env = make_env(HARD_LONG)
    base = env.unwrapped

    def episode(seed):
        env.reset(seed=seed)
        return (
            base.target_blinks.clone(), base.blink_start_steps.clone(), base.blink_off_schedule.clone(),
            base.button_xy.clone(), base.agent.robot.get_qpos().clone(),
        )

    first, again, other = episode(5), episode(5), episode(6)
    assert all(torch.equal(a, b) for a, b in zip(first, again, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(first, other, strict=True))


def test_blink_color_kwarg(make_env):
    for color in ((1.0, 0.0, 0.0, 1.0), (255, 0, 0)):
        base = make_env(EASY, blink_color=color).unwrapped
        assert base.blink_color == (255.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="blink_color"):
        make_env(EASY, blink_color=(0.0, 1.0))


# ----------------------------------------------------------------------- timeline
def test_lamps_follow_the_blink_schedule(make_env):
    driver = _reset(make_env, MEDIUM, seed=3)
    base = driver.base
    n, cue = int(base.target_blinks[0]), int(base.cue_steps_per_env[0])
    starts = base.blink_start_steps[0, :n].tolist()
    blink_on_bulb = base.blink_lamp.bulbs[base.blink_lamp.bulb_index("on")]
    ready_bulb = base.phase_lamp.bulbs[base.phase_lamp.bulb_index("ready")]
    lamp_z = float(base.blink_lamp.position[0, 2])
    lit_steps = []
    for _ in range(cue + 3):
        info = driver.step(np.zeros(7, dtype=np.float32))
        e = int(info["elapsed_steps"][0])
        expected = any(s <= e < s + 3 for s in starts)
        assert bool(info["light_on"][0]) == expected
        # What the cameras see: the lit bulb stands on the lamp, else it is parked far above.
        assert float(blink_on_bulb.pose.p[0, 2]) == pytest.approx(lamp_z if expected else lamp_z + HIDE_OFFSET_Z)
        assert bool(info["action_mask"][0]) == bool(info["phase_ready"][0]) == (e >= cue)
        assert (float(ready_bulb.pose.p[0, 2]) < 1.0) == (e >= cue)
        lit_steps += [e] * expected
    assert len(lit_steps) == 3 * n and lit_steps[-1] < cue


def test_presses_during_the_cue_only_move_the_cap(make_env):
    driver = _reset(make_env, HARD_LONG, seed=1)
    base = driver.base
    driver.go(base.button_xy[0], PARK_Z, tol=0.01)
    driver.go(base.button_xy[0], PUSH_Z)
    info = driver.infos[-1]
    assert not bool(info["action_mask"][0])
    assert float(info["press_depth"][0]) > 0.01
    assert float(base.button.cap.pose.p[0, 2]) == pytest.approx(BUTTON_CAP_REST_Z - float(info["press_depth"][0]))
    driver.go(base.button_xy[0], LIFT_Z, tol=0.01)
    driver.press("black")
    assert not bool(base.action_mask[0])
    assert int(base.raw_press_count[0]) == int(base.press_count[0]) == 0
    assert not bool(base.submit_attempted[0] | base.failed[0])
    assert all(r == 0.0 for r in driver.rewards)


# ------------------------------------------------------------------ press counting
def test_exact_count_then_submit_succeeds_and_terminates(make_env):
    driver = _reset(make_env, EASY, seed=2)
    base = driver.base
    n = int(base.target_blinks[0])
    driver.park_until_ready()
    for k in range(n):
        driver.press()
        assert int(base.press_count[0]) == int(base.raw_press_count[0]) == k + 1
    assert not driver.terminated
    events = {key: sum(bool(i[key][0]) for i in driver.infos) for key in ("new_raw_press_event", "new_press_event")}
    assert events == {"new_raw_press_event": n, "new_press_event": n}
    driver.press("black")
    info = driver.infos[-1]
    assert driver.terminated and bool(info["success"][0]) and bool(info["submit_success"][0])
    assert bool(info["new_confirm_press_event"][0]) and not bool(info["failed"][0])
    assert driver.rewards[-1] == 1.0
    assert all(0.0 <= r <= 1.0 for r in driver.rewards)


def test_a_push_counts_only_after_lifting(make_env):
    driver = _reset(make_env, MEDIUM, seed=4)
    base = driver.base
    xy = base.button_xy[0]
    driver.park_until_ready()
    driver.go(xy, PUSH_Z)
    assert int(base.raw_press_count[0]) == 1 and bool(base.latch.pending[0])
    # Up past the release height but short of the lift target, then down again: ignored.
    driver.go(xy, 0.11)
    assert bool(driver.infos[-1]["press_ready"][0]) and not bool(driver.infos[-1]["at_lift_target"][0])
    driver.go(xy, PUSH_Z)
    assert int(base.raw_press_count[0]) == 1 and int(base.press_count[0]) == 0
    driver.go(xy, LIFT_Z, tol=0.01)
    assert int(base.press_count[0]) == 1 and not bool(base.latch.pending[0])
    # evaluate() again for the same frame changes nothing.
    again = base.evaluate()
    assert int(again["press_count"][0]) == 1 and int(again["raw_press_count"][0]) == 1


def test_pressing_once_too_often_fails_immediately(make_env):
    driver = _reset(make_env, EASY, seed=6)
    base = driver.base
    n = int(base.target_blinks[0])
    driver.park_until_ready()
    for _ in range(n):
        driver.press()
    driver.go(base.button_xy[0], PUSH_Z)
    info = driver.infos[-1]
    assert driver.terminated and bool(info["failed"][0]) and not bool(info["success"][0])
    assert int(info["raw_press_count"][0]) == n + 1
    assert driver.rewards[-1] == 0.0


def test_submitting_a_wrong_count_fails(make_env):
    driver = _reset(make_env, EASY, seed=8)
    base = driver.base
    driver.park_until_ready()
    driver.press("black")
    info = driver.infos[-1]
    assert driver.terminated and bool(info["failed"][0]) and bool(info["submit_attempted"][0])
    assert not bool(info["success"][0] | info["submit_success"][0])
    assert int(base.press_count[0]) == 0 < int(base.target_blinks[0])


def test_dense_reward_stages(make_env):
    driver = _reset(make_env, EASY, seed=9, reward_mode="dense")
    driver.park_until_ready()
    driver.step(np.zeros(7, dtype=np.float32))
    hovering = driver.rewards[-1]
    driver.go(driver.base.button_xy[0], PUSH_Z)
    assert driver.rewards[-1] > hovering  # closer and pressing pays
    driver.go(driver.base.button_xy[0], LIFT_Z, tol=0.01)
    driver.press("black")  # the count is only right for N = 1
    final = driver.rewards[-1]
    # Success pays 30; a wrong submit pays its +10 event bonus and the -25 failure penalty.
    assert final == 30.0 if int(driver.base.target_blinks[0]) == 1 else final < -10.0


# ---------------------------------------------------------------------- oracle, rgb
def test_oracle_counts_what_the_lamp_showed(make_env):
    """The oracle presses the number of blinks it saw, not the env's answer."""
    env = make_env(EASY)
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=4242424242)
    oracle.reset()
    shown = int(base.target_blinks[0])
    for _ in range(150):
        if bool(base.action_mask[0]):
            base.target_blinks[0] = shown + 1
        obs, _, terminated, _, info = env.step(oracle.forward(obs))
        if bool(terminated[0]):
            break
    assert oracle.blinks_seen == shown
    assert int(info["press_count"][0]) == shown and bool(info["failed"][0]) and bool(info["submit_attempted"][0])


def test_rgb_lamp_blink_is_visible_with_overlays(make_env):
    env = make_env(EASY, obs_mode="rgb", render_mode="rgb_array", reward_mode="normalized_dense")
    env = apply_mikasa_vla_wrappers(env)
    obs, _ = env.reset(seed=1)
    base = env.unwrapped
    first_lit = int(base.blink_start_steps[0, 0])
    frames = {}
    for _ in range(first_lit):
        obs, _, _, _, info = env.step(np.zeros(7, dtype=np.float32))
        frames[int(info["elapsed_steps"][0])] = obs["rgb"][0, ..., :3].float()
    assert bool(info["light_on"][0])
    # The base camera sees the lamp light up.
    assert (frames[first_lit] - frames[first_lit - 1]).abs().max() > 50
    render = env.render()
    assert np.asarray(render.cpu() if isinstance(render, torch.Tensor) else render).shape[-1] == 3
