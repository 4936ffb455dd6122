"""BatteriesCheckerEasy / BatteriesCheckerHard: layout, stage machine, lamp, button, success, reward."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mani_skill.utils.gym_utils import find_max_episode_steps_value
from mani_skill.utils.registration import REGISTERED_ENVS
from mani_skill.utils.structs import Pose
from mikasa_envs import get_task
from mikasa_envs.tasks._batteries_checker import slot_offsets
from mikasa_oracles import make_oracle
from mikasa_oracles.controller import move_towards

BENCH_SEED = 4242424242
HARD_IDS = [f"BatteriesCheckerHard-{n}-VLA-v0" for n in (3, 6, 9, 12, 15)]
EASY_IDS = [f"BatteriesCheckerEasy-{n}-VLA-v0" for n in (3, 6, 9, 12, 15)]
# (active, working, horizon) per variant (batteries_checker_hard.md §1, _easy.md §1).
VARIANTS = {
    **dict(zip(HARD_IDS, [(3, 1, 1080), (6, 3, 2160), (9, 5, 3240), (12, 7, 4320), (15, 9, 4320)], strict=True)),
    **dict(zip(EASY_IDS, [(3, 1, 540), (6, 3, 1080), (9, 5, 1620), (12, 7, 2160), (15, 9, 2400)], strict=True)),
}
INFO_KEYS = [
    "elapsed_steps", "success", "action_mask", "cue_mask", "action_stage", "active_battery_idx",
    "socket_has_battery", "socket_battery_idx", "socket_has_working", "active_battery_count", "checked_count",
    "found_working_count", "target_working_count", "all_checked", "new_insert_event", "new_return_event",
    "new_confirm_event", "new_button_press_event", "button_press_depth", "obj_to_goal_pos", "task_cue",
    "language_instruction", "oracle_info", "reward_dict",
]
ZERO = np.zeros(7, dtype=np.float32)


def _put_battery(base, k: int, position) -> None:
    """Stand battery k upright at ``position``, at rest."""
    p = torch.as_tensor(position, dtype=torch.float32).reshape(1, 3)
    base.batteries[k].set_pose(Pose.create_from_pq(p, torch.tensor([base.BATTERY_QUAT])))
    base.batteries[k].set_linear_velocity(torch.zeros(1, 3))
    base.batteries[k].set_angular_velocity(torch.zeros(1, 3))


def _socket_rest(base) -> np.ndarray:
    rest = base.socket_slot_pos[0].numpy().copy()
    rest[2] = 0.0405  # on the socket's floor plate
    return rest


def _lamp_on(base) -> bool:
    on_bulb = base.lamp.bulbs[base.lamp.bulb_index("on")]
    return float(on_bulb.pose.p[0, 2]) < 1.0


def _drive_tcp(env, goal, steps: int, gripper: float = -1.0):
    """Step a proportional controller towards ``goal``; returns the infos."""
    base = env.unwrapped
    infos = []
    for _ in range(steps):
        tcp = base.agent.tcp.pose.raw_pose[0].numpy()
        *_, info = env.step(move_towards(tcp, np.asarray(goal, dtype=np.float64), gain=1.0, gripper=gripper))
        infos.append(info)
    return infos


def _press_button(env):
    """Lower the TCP over the button to z 0.07, then lift it above the re-arm height."""
    base = env.unwrapped
    bx, by = base.button_xy[0].tolist()
    infos = _drive_tcp(env, (bx, by, 0.15), 25)
    infos += _drive_tcp(env, (bx, by, 0.07), 15)
    infos += _drive_tcp(env, (bx, by, 0.15), 10)
    return infos


# ------------------------------------------------------------------- registration
def test_every_variant_is_registered_with_its_counts_and_horizon(make_env):
    for env_id, (active, working, horizon) in VARIANTS.items():
        task = get_task(env_id)
        assert task.max_episode_steps == horizon
        assert task.family == ("batteries_checker_hard" if "Hard" in env_id else "batteries_checker_easy")
        env_class = REGISTERED_ENVS[env_id].cls
        assert (env_class.ACTIVE_BATTERIES, env_class.WORKING_BATTERIES) == (active, working)
    env = make_env("BatteriesCheckerHard-15-VLA-v0")
    base = env.unwrapped
    assert (base.ACTIVE_BATTERIES, base.WORKING_BATTERIES) == (15, 9)
    assert find_max_episode_steps_value(env) == 4320


def test_instructions_differ_only_by_the_return_clause(make_env):
    easy = make_env("BatteriesCheckerEasy-3-VLA-v0").unwrapped.LANGUAGE_INSTRUCTION
    hard = make_env("BatteriesCheckerHard-3-VLA-v0").unwrapped.LANGUAGE_INSTRUCTION
    clause = "returning it from the socket to its initial slot, "
    assert hard.replace(clause, "") == easy
    assert easy == get_task("BatteriesCheckerEasy-3-VLA-v0").language_instruction


# ------------------------------------------------------------------------- layout
def test_slot_layout_matches_the_measured_example():
    slots = np.array([-0.0897, -0.0394]) + slot_offsets()
    np.testing.assert_allclose(slots[0], [-0.0397, -0.1434], atol=1e-4)
    np.testing.assert_allclose(slots[1], [-0.0897, -0.1434], atol=1e-4)
    np.testing.assert_allclose(slots[3], [-0.0397, -0.0914], atol=1e-4)


def test_reset_layout_info_and_observation(make_env):
    env = make_env("BatteriesCheckerHard-6-VLA-v0")
    base = env.unwrapped
    obs, info = env.reset(seed=BENCH_SEED)
    assert list(info)[: len(INFO_KEYS)] == INFO_KEYS
    tx, ty = base.tray_center[0].tolist()
    assert -0.09 <= tx < -0.01 and -0.05 <= ty < 0.05
    np.testing.assert_allclose(base.socket_slot_pos[0].numpy(), [tx + 0.20, ty, 0.030], atol=1e-6)
    np.testing.assert_allclose(base.button_xy[0].numpy(), [tx, ty + 0.24], atol=1e-6)
    np.testing.assert_allclose(base.lamp.position[0].numpy(), [tx + 0.28, ty, 0.0], atol=1e-6)
    np.testing.assert_allclose(base.tray.pose.p[0].numpy(), [tx, ty, 0.015], atol=1e-6)
    positions = base.battery_positions()[0].numpy()
    np.testing.assert_allclose(positions[:6], base.tray_slot_positions[0, :6].numpy(), atol=1e-5)
    assert (positions[6:, 2] > 999).all()  # the inactive batteries are hidden
    # The working set: WORKING distinct active indices, published as oracle_info (uint8).
    working = info["oracle_info"][0]
    assert info["oracle_info"].dtype == torch.uint8 and info["oracle_info"].shape == (1, 3)
    assert len(set(working.tolist())) == 3 and max(working.tolist()) < 6
    assert sorted(torch.nonzero(base.working_mask[0]).flatten().tolist()) == sorted(working.tolist())
    assert bool(info["action_mask"][0]) and not bool(info["cue_mask"][0])
    assert int(info["action_stage"][0]) == base.STAGE_INSERT and int(info["active_battery_idx"][0]) == -1
    assert int(info["target_working_count"][0]) == 3 and int(info["active_battery_count"][0]) == 6
    assert info["task_cue"] is None and not _lamp_on(base)
    # Attributes the tools and overlays read (batteries_checker_hard.md §7).
    for name in (
        "batteries", "tray_slot_positions", "socket_slot_pos", "button_xy", "button_top_z", "action_stage",
        "active_battery_idx", "checked_mask", "working_mask", "active_battery_count", "STAGE_INSERT",
        "STAGE_RETURN", "STAGE_CONFIRM", "BATTERY_HALF_HEIGHT", "BUTTON_PRESS_RADIUS", "BUTTON_TOP_Z",
    ):
        assert hasattr(base, name), name
    assert len(base.batteries) == 15 and base.active_battery_count == 6 and base.button_top_z == 0.058
    # state: qpos 9 + qvel 9 + tcp 7 + batteries 105 + 6 poses × 7 + stage + mask + active 15 + oracle 3.
    assert obs.shape == (1, 9 + 9 + 7 + 105 + 42 + 1 + 1 + 15 + 3)
    state = env.unwrapped.get_obs(info, unflattened=True)["extra"]
    assert list(state) == [
        "tcp_pose", "battery_pose", "tray_pose", "socket_pose", "button_base_pose", "button_cap_pose",
        "lamp_off_pose", "lamp_on_pose", "action_stage", "action_mask", "active_mask", "oracle_info",
    ]
    assert state["active_mask"][0].tolist() == [True] * 6 + [False] * 9


def test_seeded_episodes_are_deterministic(make_env):
    env = make_env("BatteriesCheckerEasy-6-VLA-v0")
    base = env.unwrapped
    layouts = []
    for seed in (11, 12, 11):
        env.reset(seed=seed)
        layouts.append((base.tray_center[0].tolist(), base.oracle_info[0].tolist()))
    assert layouts[0] == layouts[2] and layouts[0] != layouts[1]


# ------------------------------------------------------------------ stage machine
def _working_and_dead(base) -> tuple[int, int]:
    working = torch.nonzero(base.working_mask[0]).flatten().tolist()
    dead = [k for k in range(base.ACTIVE_BATTERIES) if k not in working]
    return working[0], dead[0]


def test_hard_full_cycle_lamp_return_confirm_and_success(make_env):
    env = make_env("BatteriesCheckerHard-3-VLA-v0", reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=BENCH_SEED)
    work, dead = _working_and_dead(base)

    # Dead battery in the socket: inserted, lamp stays white.
    _put_battery(base, dead, _socket_rest(base))
    _, reward, terminated, _, info = env.step(ZERO)
    assert bool(info["new_insert_event"][0]) and bool(info["socket_has_battery"][0])
    assert int(info["socket_battery_idx"][0]) == dead and not bool(info["socket_has_working"][0])
    assert int(info["action_stage"][0]) == base.STAGE_RETURN and int(info["active_battery_idx"][0]) == dead
    assert not _lamp_on(base) and 0.0 <= float(reward[0]) <= 1.0
    # A press now is in the wrong stage: nothing changes, and it is penalised.
    infos = _press_button(env)
    assert any(bool(i["new_button_press_event"][0]) for i in infos)
    assert not any(bool(i["new_confirm_event"][0]) for i in infos)
    assert any(bool(i["reward_dict"]["wrong_phase_press"][0]) for i in infos[1:] if i["reward_dict"])
    # Back home: the return event, then a press confirms it.
    _put_battery(base, dead, base.tray_slot_positions[0, dead])
    *_, info = env.step(ZERO)
    assert bool(info["new_return_event"][0]) and int(info["action_stage"][0]) == base.STAGE_CONFIRM
    infos = _press_button(env)
    assert sum(bool(i["new_confirm_event"][0]) for i in infos) == 1
    info = infos[-1]
    assert int(info["checked_count"][0]) == 1 and int(info["found_working_count"][0]) == 0
    assert int(info["action_stage"][0]) == base.STAGE_INSERT and int(info["active_battery_idx"][0]) == -1

    # Working battery: the lamp is yellow while it sits in the socket.
    _put_battery(base, work, _socket_rest(base))
    *_, info = env.step(ZERO)
    assert bool(info["new_insert_event"][0]) and bool(info["socket_has_working"][0]) and _lamp_on(base)
    for _ in range(10):
        *_, info = env.step(ZERO)
        assert _lamp_on(base) and bool(info["socket_has_battery"][0])
    # Out of the socket (afterglow long over): white again, and returned.
    _put_battery(base, work, base.tray_slot_positions[0, work])
    *_, info = env.step(ZERO)
    assert bool(info["new_return_event"][0]) and not _lamp_on(base)
    infos = _press_button(env)
    assert int(infos[-1]["found_working_count"][0]) == 1 and int(infos[-1]["checked_count"][0]) == 2
    assert not any(bool(i["success"][0]) for i in infos)  # one battery is still unchecked

    # Success needs every battery checked and every checked one near home.
    base.checked_mask[0, : base.ACTIVE_BATTERIES] = True
    far = base.tray_slot_positions[0, dead].clone()
    far[0] += 0.08
    _put_battery(base, dead, far)
    *_, terminated, _, info = env.step(ZERO)
    assert bool(info["all_checked"][0]) and not bool(info["success"][0]) and not bool(terminated[0])
    _put_battery(base, dead, base.tray_slot_positions[0, dead])
    _, reward, terminated, _, info = env.step(ZERO)
    assert bool(info["success"][0]) and bool(terminated[0]) and float(reward[0]) == 1.0


def test_success_needs_the_working_count(make_env):
    env = make_env("BatteriesCheckerHard-3-VLA-v0")
    base = env.unwrapped
    env.reset(seed=3)
    base.checked_mask[0, :3] = True  # all checked, but none found working
    *_, info = env.step(ZERO)
    assert bool(info["all_checked"][0]) and not bool(info["success"][0])
    base.found_mask[0] = base.working_mask[0]
    *_, info = env.step(ZERO)
    assert bool(info["success"][0])


def test_easy_returns_the_battery_at_once_and_lamp_shows_seven_frames(make_env):
    env = make_env("BatteriesCheckerEasy-3-VLA-v0", reward_mode="normalized_dense")
    base = env.unwrapped
    env.reset(seed=BENCH_SEED)
    work, dead = _working_and_dead(base)
    _put_battery(base, work, _socket_rest(base))
    lamp = []
    _, reward, _, _, info = env.step(ZERO)
    lamp.append(_lamp_on(base))
    assert bool(info["new_insert_event"][0]) and bool(info["new_return_event"][0])
    assert not bool(info["socket_has_battery"][0]) and not bool(info["socket_has_working"][0])
    assert int(info["socket_battery_idx"][0]) == -1 and int(info["action_stage"][0]) == base.STAGE_CONFIRM
    np.testing.assert_allclose(
        base.battery_positions()[0, work].numpy(), base.tray_slot_positions[0, work].numpy(), atol=1e-5
    )
    assert 0.2 < float(reward[0]) < 0.35  # insert (5) + return (6) bonuses, normalised by 40
    for _ in range(9):
        env.step(ZERO)
        lamp.append(_lamp_on(base))
    assert lamp == [True] * 7 + [False] * 3
    infos = _press_button(env)
    assert int(infos[-1]["found_working_count"][0]) == 1 and int(infos[-1]["checked_count"][0]) == 1
    # A dead battery never lights the lamp.
    _put_battery(base, dead, _socket_rest(base))
    *_, info = env.step(ZERO)
    assert bool(info["new_insert_event"][0]) and not _lamp_on(base)


def test_grasped_battery_does_not_count_as_inserted(make_env):
    env = make_env("BatteriesCheckerHard-3-VLA-v0")
    base = env.unwrapped
    env.reset(seed=BENCH_SEED)
    socket = base.socket_slot_pos[0]
    pos = torch.zeros(1, base.MAX_BATTERIES, 3)
    pos[0, 0] = socket
    grasped = torch.zeros(1, base.MAX_BATTERIES, dtype=torch.bool)
    assert bool(base._in_socket(pos, grasped)[0, 0])
    grasped[0, 0] = True
    assert not bool(base._in_socket(pos, grasped)[0, 0])


def test_evaluate_twice_does_not_advance_the_machine(make_env):
    env = make_env("BatteriesCheckerEasy-3-VLA-v0")
    base = env.unwrapped
    env.reset(seed=BENCH_SEED)
    work, _ = _working_and_dead(base)
    _put_battery(base, work, _socket_rest(base))
    *_, info = env.step(ZERO)
    again = base.evaluate()
    assert bool(again["new_insert_event"][0]) and int(again["action_stage"][0]) == base.STAGE_CONFIRM
    assert int(base.lamp_afterglow[0]) == base.LAMP_AFTERGLOW_STEPS


def test_zero_actions_keep_reward_in_range_and_fail(make_env):
    env = make_env("BatteriesCheckerHard-3-VLA-v0", reward_mode="normalized_dense", max_episode_steps=30)
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(30):
        _, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 7).astype(np.float32))
        assert 0.0 <= float(reward[0]) <= 1.0 and not bool(info["success"][0])
    assert bool(truncated[0])


# ------------------------------------------------------------------------- oracle
def test_oracle_reads_the_working_set_off_the_lamp(make_env):
    env = make_env("BatteriesCheckerEasy-3-VLA-v0")
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=BENCH_SEED + 1)
    oracle.reset()
    while True:
        obs, _, terminated, truncated, info = env.step(oracle.forward(obs))
        if bool(terminated[0] | truncated[0]):
            break
    assert bool(info["success"][0])
    assert oracle.working_seen == set(base.oracle_info[0].tolist())


@pytest.mark.parametrize("env_id", ["BatteriesCheckerHard-3-VLA-v0"])
def test_rgb_lamp_is_visible_to_the_base_camera(make_env, env_id):
    env = make_env(env_id, obs_mode="rgb")
    base = env.unwrapped
    env.reset(seed=BENCH_SEED)
    work, _ = _working_and_dead(base)
    off = env.step(ZERO)[0]["sensor_data"]["base_camera"]["rgb"][0].int()
    _put_battery(base, work, _socket_rest(base))
    on = env.step(ZERO)[0]["sensor_data"]["base_camera"]["rgb"][0].int()
    assert _lamp_on(base)
    changed = (on - off).abs().sum(-1) > 60
    # The bulb turning yellow (and the battery) changes a patch of pixels, not the whole frame.
    assert 5 < int(changed.sum()) < 0.1 * changed.numel()
