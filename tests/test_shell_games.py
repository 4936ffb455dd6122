"""The six shell-game families: mug, timelines, shuffle, lamp, success rules, rewards, seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest
import sapien
import torch
from mani_skill.utils.gym_utils import find_max_episode_steps_value
from mikasa_envs import get_task
from mikasa_envs.building_blocks.cups import MUG_HANDLE_OFFSET, MUG_MASS, mug_rest_height
from mikasa_envs.tasks._shell_game import swap_schedule
from mikasa_oracles import make_oracle
from mikasa_wrappers import apply_mikasa_vla_wrappers
from mikasa_wrappers.wrappers import CurriculumPhaseNoopActionWrapper, StateOnlyTensorToDictWrapper

ZERO = np.zeros(7, dtype=np.float32)
IN_VIEW = 1.0  # hidden objects are parked 1000 m up
SEED = 4242424242

TOUCH, PUSH, PICK = "ShellGameTouch-VLA-v0", "ShellGamePush-VLA-v0", "ShellGamePick-VLA-v0"
LAMP, SHUFFLE = "ShellGameColorLampTouch-VLA-v0", "ShellGameShuffleTouch-VLA-v0"
SHUFFLE_LAMP = "ShellGameShuffleColorLampTouch-VLA-v0"
SHUFFLE_LONG, SHUFFLE_LAMP_LONG = "ShellGameShuffleTouch-Long-VLA-v0", "ShellGameShuffleColorLampTouch-Long-VLA-v0"
SHORT_IDS = [TOUCH, PUSH, PICK, LAMP, SHUFFLE, SHUFFLE_LAMP]
ALL_IDS = [*SHORT_IDS, SHUFFLE_LONG, SHUFFLE_LAMP_LONG]
# Flattened state dimension per family (task files).
STATE_DIM = {TOUCH: 40, PUSH: 43, PICK: 47, LAMP: 30, SHUFFLE: 40, SHUFFLE_LAMP: 30}


def _run_to(env, t: int) -> dict:
    info = {}
    while int(env.unwrapped.elapsed_steps[0]) < t:
        *_, info = env.step(ZERO)
    return info


def _oracle_until_success(env, seed: int = SEED) -> list[dict]:
    """Roll the oracle out until the first success; the infos of every step."""
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=seed)
    oracle.reset()
    infos = []
    for _ in range(find_max_episode_steps_value(env)):
        obs, reward, terminated, _, info = env.step(oracle.forward(obs))
        info = dict(info, reward=float(reward[0]), terminated=bool(terminated[0]))
        infos.append(info)
        if bool(info["success"][0]):
            return infos
    raise AssertionError("the oracle did not succeed")


def _positions(base, actors) -> np.ndarray:
    return base.actor_raw_poses(actors)[0, :, :3].numpy()


# ------------------------------------------------------------------------------- mug
def test_procedural_mug_geometry_and_rest(make_env):
    assert mug_rest_height() == pytest.approx(0.0527, abs=2e-4)
    env = make_env(TOUCH)
    env.reset(seed=1)
    base = env.unwrapped
    mug = base.mugs[0]
    assert mug._bodies[0].mass == pytest.approx(MUG_MASS, rel=0.01)
    _run_to(env, int(base.cue_steps_per_env[0]) + 10)
    # Standing upside down on its rim: it stays put at the rest height, handle along the quaternion.
    pose = base.actor_raw_poses([mug])[0, 0].numpy()
    np.testing.assert_allclose(pose[:2], base.slot_positions[0, 0, :2].numpy(), atol=1e-3)
    assert pose[2] == pytest.approx(mug_rest_height(), abs=1e-3)
    np.testing.assert_allclose(np.abs(pose[3:]), [0.0, 2 / math.sqrt(5), 1 / math.sqrt(5), 0.0], atol=2e-3)


def test_pick_handle_points_toward_the_robot(make_env):
    env = make_env(PICK)
    obs, _ = env.reset(seed=3)
    base = env.unwrapped
    _run_to(env, int(base.cue_steps_per_env[0]))
    q = base.target_mug_pose()[0, 3:].numpy()
    handle = sapien.Pose(q=q).to_transformation_matrix()[:3, 0]
    np.testing.assert_allclose(handle, [-0.724, 0.690, 0.0], atol=2e-3)
    # The reference's fixed handle offset lands on the loop centre of the procedural mug.
    centre = base.target_mug_pose()[0, :3].numpy()
    handle_pos = base.handle_position(base.target_mug_pose()[:, :3])[0].numpy()
    np.testing.assert_allclose(handle_pos, centre + MUG_HANDLE_OFFSET * handle, atol=2e-3)


def test_scripted_families_use_kinematic_mugs(make_env):
    assert all(m._bodies[0].kinematic for m in make_env(SHUFFLE).unwrapped.mugs)
    assert not any(m._bodies[0].kinematic for m in make_env(TOUCH).unwrapped.mugs)


# ------------------------------------------------------------------------- registry
@pytest.mark.parametrize("env_id", ALL_IDS)
def test_registration_and_observation_layout(make_env, env_id):
    env = make_env(env_id)
    obs, info = env.reset(seed=0)
    base = env.unwrapped
    assert find_max_episode_steps_value(env) == get_task(env_id).max_episode_steps
    assert info["language_instruction"] == get_task(env_id).language_instruction
    assert obs.shape == (1, STATE_DIM[env_id.replace("-Long", "")])
    assert info["oracle_info"].dtype == torch.uint8 and info["oracle_info"].shape == (1,)
    assert "fail" not in info
    assert base.slot_positions.shape == (1, 3, 3)
    lamp_family = "ColorLamp" in env_id
    assert (info["task_cue"] is not None) == lamp_family
    if lamp_family:
        assert info["task_cue"].dtype == torch.uint8 and int(info["task_cue"][0]) == int(base.target_color[0])


# ------------------------------------------------------------------------- timelines
@pytest.mark.parametrize("env_id", [TOUCH, PUSH, PICK])
def test_hidden_ball_timeline(make_env, env_id):
    env = make_env(env_id)
    env.reset(seed=8)
    base = env.unwrapped
    t_ball = int(base.cup_with_ball_number[0])
    slot = base.slot_positions[0].numpy()
    cue = int(base.cue_steps_per_env[0])
    assert int(base.empty_steps_per_env[0]) == 0
    for t in range(cue + 3):
        _run_to(env, t)
        mugs, ball = _positions(base, base.mugs), _positions(base, [base.red_ball])[0]
        np.testing.assert_allclose(ball, [slot[t_ball, 0], slot[t_ball, 1], 0.02], atol=1e-4)
        if t < cue:  # parked 1000 m up, pinned (no free fall)
            np.testing.assert_allclose(mugs[:, 2], slot[:, 2] + 1000.0, atol=1e-3)
        else:  # standing at rest on their slots from the first action frame
            np.testing.assert_allclose(mugs, slot, atol=1e-3)
            speed = np.abs(base.mugs[0]._bodies[0].linear_velocity).max()
            assert speed < 1e-2


def test_shuffle_schedule_function():
    pairs = torch.tensor([[[0, 1], [1, 2], [0, 2], [0, 1]]])
    schedule = swap_schedule(pairs, torch.tensor([3]))
    expected = [[0, 1, 2], [1, 0, 2], [2, 0, 1], [0, 2, 1], [0, 2, 1]]
    assert schedule[0].tolist() == expected


@pytest.mark.parametrize("env_id", [SHUFFLE, SHUFFLE_LAMP, SHUFFLE_LONG, SHUFFLE_LAMP_LONG])
def test_shuffle_draws_within_ranges(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped
    long = "-Long-" in env_id
    for seed in range(4):
        env.reset(seed=seed)
        c, s, n = (int(x[0]) for x in (base.cue_steps_per_env, base.shuffle_steps_per_env, base.num_swaps_per_env))
        assert (10 <= c <= 100) if long else (1 <= c <= 5)
        assert (100 <= s <= 400) if long else (20 <= s <= 35)
        assert (5 <= n <= 15) if long else (2 <= n <= 4)
        assert int(base.empty_steps_per_env[0]) == s and int(base.steps_per_swap_per_env[0]) == s // n
        assert base.swap_pairs.shape == (1, 15 if long else 4, 2)
        assert base.slot_of_mug.shape == (1, (15 if long else 4) + 1, 3)
        assert base.final_slot_of_mug[0].tolist() == base.slot_of_mug[0, n].tolist()


def test_shuffle_animation_and_answer(make_env):
    env = make_env(SHUFFLE)
    env.reset(seed=3)
    base = env.unwrapped
    c, s, n, k = (int(x[0]) for x in (base.cue_steps_per_env, base.shuffle_steps_per_env,
                                     base.num_swaps_per_env, base.steps_per_swap_per_env))
    slots = base.slot_positions[0].numpy()
    h = base.mug_rest_z
    som = base.slot_of_mug[0].tolist()
    ball_mug = int(base.cup_with_ball_number[0])
    assert int(base.oracle_info[0]) == som[n][ball_mug]
    for t in range(c + s + 2):
        _run_to(env, t)
        mugs = _positions(base, base.mugs)
        ball = _positions(base, [base.red_ball])[0]
        if t < c:
            assert (mugs[:, 2] > IN_VIEW).all() and ball[2] == pytest.approx(0.02, abs=1e-4)
            continue
        if t >= c + s:  # action: final arrangement, ball under its mug again
            np.testing.assert_allclose(mugs, slots[som[n]], atol=1e-4)
            np.testing.assert_allclose(ball[:2], slots[som[n][ball_mug], :2], atol=1e-4)
            continue
        assert ball[2] > IN_VIEW  # hidden during the shuffle
        j = t - c
        swap = j // k
        if swap >= n:  # remainder frames show the final arrangement at rest
            np.testing.assert_allclose(mugs, slots[som[n]], atol=1e-4)
            continue
        tau = (j - swap * k) / k
        phi = math.pi * tau * tau * (3 - 2 * tau)
        before, after = slots[som[swap]], slots[som[swap + 1]]
        middle = (before + after) / 2
        np.testing.assert_allclose(mugs[:, 2], h + 0.06 * math.sin(phi), atol=1e-4)  # all three bob
        np.testing.assert_allclose(np.linalg.norm(mugs[:, :2] - middle[:, :2], axis=1),
                                   np.linalg.norm(before[:, :2] - middle[:, :2], axis=1), atol=1e-4)
        for m in range(3):  # counter-clockwise seen from above: going +y passes on the +x side
            dy = after[m, 1] - before[m, 1]
            if dy != 0 and 0 < tau:
                assert np.sign(mugs[m, 0] - middle[m, 0]) == np.sign(dy)


@pytest.mark.parametrize("env_id", [LAMP, SHUFFLE_LAMP])
def test_color_lamp_timeline(make_env, env_id):
    env = make_env(env_id)
    env.reset(seed=5)
    base = env.unwrapped
    k = int(base.target_color[0])
    slots = base.slot_positions[0].numpy()
    np.testing.assert_allclose(base.lamp.position[0].numpy(), [slots[1, 0] + 0.25, slots[1, 1], 0.06], atol=1e-5)
    start = int(base.action_phase_start[0])
    bulbs = base.lamp.bulb_names
    for t in (0, int(base.cue_steps_per_env[0]), start, start + 1):
        _run_to(env, t)
        balls = _positions(base, base.balls)
        lit = [bulbs[i] for i, p in enumerate(_positions(base, base.lamp.bulbs)) if p[2] < IN_VIEW]
        if t < int(base.cue_steps_per_env[0]):  # red, green, blue at slots 0, 1, 2
            np.testing.assert_allclose(balls[:, :2], slots[:, :2], atol=1e-5)
            assert (balls[:, 2] == pytest.approx(0.02)) and (_positions(base, base.mugs)[:, 2] > IN_VIEW).all()
        else:
            assert (balls[:, 2] > IN_VIEW).all()
        assert lit == (["white"] if t < start else [("red", "green", "blue")[k]])
    target_slot = int(base.final_slot_of_mug[0, k])
    assert int(base.oracle_info[0]) == target_slot
    if env_id == LAMP:
        assert target_slot == k


# ---------------------------------------------------------------------- success rules
@pytest.mark.parametrize("env_id", SHORT_IDS)
def test_oracle_success_rules_and_rewards(make_env, env_id):
    env = make_env(env_id, reward_mode="normalized_dense")
    infos = _oracle_until_success(env)
    base = env.unwrapped
    start = int(base.action_phase_start[0])
    rewards = [i["reward"] for i in infos]
    assert all(0.0 <= r <= 1.0 for r in rewards)
    assert rewards[-1] == pytest.approx(1.0)
    assert all(r == 0.0 for i, r in zip(infos, rewards, strict=True) if int(i["elapsed_steps"][0]) < start)
    # Touch / Push / Pick end on success; the others never terminate.
    assert infos[-1]["terminated"] == (env_id in (TOUCH, PUSH, PICK))
    # The same state in a cue frame is not a success: success is gated on the action phase.
    base.cue_steps_per_env[0] = 10_000
    info = base.evaluate()
    assert bool(info["is_obj_placed"][0]) and not bool(info["success"][0])


def test_touch_fails_when_a_mug_was_moved(make_env):
    env = make_env(TOUCH)
    _oracle_until_success(env)
    base = env.unwrapped
    other = base.mugs[(int(base.cup_with_ball_number[0]) + 1) % 3]
    pose = other.pose.raw_pose.clone()
    pose[0, 0] += 0.06
    other.set_pose(sapien.Pose(pose[0, :3].numpy(), pose[0, 3:].numpy()))
    info = base.evaluate()
    assert info["mug_max_displacement"][0] == pytest.approx(0.06, abs=1e-3)
    assert not bool(info["is_mug_displacement_ok"][0]) and not bool(info["success"][0])


def test_touch_wrong_mug_is_not_placed(make_env):
    env = make_env(TOUCH)
    _oracle_until_success(env)
    base = env.unwrapped
    base.cup_with_ball_number[0] = (int(base.cup_with_ball_number[0]) + 1) % 3
    info = base.evaluate()
    assert not bool(info["is_obj_placed"][0]) and not bool(info["success"][0])


def test_push_moves_the_mug_forward_and_pick_lifts_it(make_env):
    env = make_env(PUSH)
    _oracle_until_success(env)
    base = env.unwrapped
    slot = base.slot_positions[0, int(base.cup_with_ball_number[0])].numpy()
    assert base.target_mug_pose()[0, 0] - slot[0] > 0.01  # pushed along +x
    np.testing.assert_allclose(base.goal_pos[0].numpy(), [slot[0] + 0.1, slot[1], 0.05], atol=1e-5)

    env = make_env(PICK)
    infos = _oracle_until_success(env)
    base = env.unwrapped
    assert bool(infos[-1]["is_grasped"][0])
    mug = base.target_mug_pose()[0, :3].numpy()
    ball = _positions(base, [base.red_ball])[0]
    assert mug[2] > base.mug_rest_z + 0.05
    assert ball[2] == pytest.approx(0.02) and np.linalg.norm(ball[:2] - mug[:2]) > 0.005  # left on the table


@pytest.mark.parametrize("env_id", [TOUCH, SHUFFLE, LAMP])
def test_zero_actions_never_succeed(make_env, env_id):
    env = make_env(env_id)
    env.reset(seed=SEED)
    for _ in range(find_max_episode_steps_value(env)):
        *_, info = env.step(ZERO)
        assert not bool(info["success"][0])


def test_oracle_remembers_the_cue(make_env):
    """Changing the answer after the cue does not change the mug the oracle touches."""
    env = make_env(SHUFFLE)
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=SEED)
    oracle.reset()
    shown = int(base.cup_with_ball_number[0])
    for t in range(find_max_episode_steps_value(env)):
        if t == int(base.cue_steps_per_env[0]):
            base.cup_with_ball_number[0] = (shown + 1) % 3
        obs, *_, info = env.step(oracle.forward(obs))
    tcp = base.agent.tcp.pose.p[0].numpy()
    shown_mug = _positions(base, base.mugs)[shown]
    assert np.linalg.norm(tcp[:2] - shown_mug[:2]) < 0.03
    assert not bool(info["success"][0])


# ------------------------------------------------------------------------ wrappers
def test_curriculum_wrapper_freezes_through_cue_and_shuffle(make_env):
    env = make_env(SHUFFLE)
    wrapped = CurriculumPhaseNoopActionWrapper(StateOnlyTensorToDictWrapper(env))
    wrapped.reset(seed=2)
    base = env.unwrapped
    start = int(base.action_phase_start[0])
    assert start == int(base.cue_steps_per_env[0] + base.empty_steps_per_env[0])
    push = np.array([0.0, 0.0, -1.0, 0, 0, 0, 1.0], dtype=np.float32)
    tcp0 = base.agent.tcp.pose.p[0].clone()
    for _ in range(start):
        wrapped.step(push)
    assert torch.linalg.norm(base.agent.tcp.pose.p[0] - tcp0) < 5e-3  # frozen
    wrapped.step(push)
    wrapped.step(push)
    assert base.agent.tcp.pose.p[0, 2] < tcp0[2] - 0.02  # the first action-phase action moves it


# ----------------------------------------------------------------------- determinism
@pytest.mark.parametrize("env_id", [PUSH, SHUFFLE_LAMP])
def test_seeded_determinism(make_env, env_id):
    env = make_env(env_id)
    base = env.unwrapped

    def episode(seed: int) -> tuple:
        obs, info = env.reset(seed=seed)
        states = [obs.clone()]
        for _ in range(6):
            obs, *_ = env.step(np.full(7, 0.3, dtype=np.float32))
            states.append(obs.clone())
        return (base.slot_positions.clone(), int(info["oracle_info"][0]), int(base.cue_steps_per_env[0]),
                int(base.empty_steps_per_env[0]), torch.stack(states))

    first, again, other = episode(17), episode(17), episode(18)
    assert torch.equal(first[0], again[0]) and first[1:4] == again[1:4]
    # PhysX keeps contact caches across resets of one scene: contacts may differ by ~1e-7.
    torch.testing.assert_close(first[4], again[4], atol=1e-5, rtol=0)
    assert not torch.equal(first[0], other[0])


# ------------------------------------------------------------------------------ rgb
def test_rgb_goal_site_hidden_from_cameras_and_lamp_cue(make_env):
    env = make_env(PUSH, obs_mode="rgb", render_mode="rgb_array")
    obs, _ = env.reset(seed=1)  # the goal site is placed from the first frame

    def green(image) -> int:
        image = np.asarray(image.cpu() if isinstance(image, torch.Tensor) else image).astype(int)
        return int(((image[..., 1] > 150) & (image[..., 0] < 80) & (image[..., 2] < 80)).sum())

    assert green(obs["sensor_data"]["base_camera"]["rgb"]) == 0
    assert green(env.render()) > 50  # shown in human renders

    env = apply_mikasa_vla_wrappers(make_env(LAMP, obs_mode="rgb"))
    obs, _ = env.reset(seed=4)
    assert list(obs) == ["proprio", "rgb", "task_cue"]
    assert obs["task_cue"].shape == (1, 1) and int(obs["task_cue"][0, 0]) == int(env.unwrapped.target_color[0])
