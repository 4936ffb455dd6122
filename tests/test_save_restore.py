"""Save, restore and replay: ManiSkill's state API carries each task's own state.

``env.get_state_dict()`` / ``env.set_state_dict(state)`` must restore everything stepping reads,
so that the steps after a restore repeat the steps after the save, in the same env or in
another one, and ManiSkill's ``RecordEpisode`` + ``replay_trajectory --use-env-states``
reproduce an episode.

PhysX keeps contact caches (warm starting) that no state API restores, so bodies resting on
each other move by float noise (~1e-6) differently after a restore; observations, rewards
and float task state are compared to 1e-4 (a missing piece of task state shows as a whole
phase, count or layout), success / terminated / truncated, integer and boolean state and the
restored state itself exactly. Where the robot pushes an object, a restored step differs by
more than noise (see REPLAY_IDS).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import h5py
import mikasa_robo_rl  # noqa: F401  (registers the RL ids)
import numpy as np
import pytest
import torch
from conftest import REGISTERED_IDS
from mani_skill.trajectory import utils as trajectory_utils
from mani_skill.utils.wrappers import RecordEpisode
from mikasa_envs import get_task
from mikasa_oracles import ORACLES, make_oracle, rollout
from mikasa_oracles.rollout import reset_with_seed
from mikasa_robo_rl.manifest import get_rl_task, rl_env_ids

RL_IDS = list(rl_env_ids())
ALL_IDS = REGISTERED_IDS + RL_IDS
# One id per family (its first variant), and two RL ids (their timing mixins): the default
# run checks every family's TASK_STATE declaration; -m slow checks every id.
FAMILY_IDS = list({get_task(i).family: i for i in reversed(REGISTERED_IDS)}.values())
FAST_IDS = FAMILY_IDS + ["InterceptSlow-v0", "ShellGameTouch-v0"]
SLOW_IDS = [i for i in ALL_IDS if i not in FAST_IDS]

# The other env runs its oracle to the end of its episode (at most this long) before the
# restore, so that its latches, counters and stages differ from the saved ones.
OTHER_ENV_ORACLE_STEPS = 400
ORACLE_SNAPSHOT_EVERY = 10
ATOL, RTOL = 1e-4, 1e-5
# Against an uninterrupted recording: a restore rewrites PhysX's link poses from the joint
# positions, which the uninterrupted run kept slightly differently (grows to ~1e-4 rad/s).
RECORDING_ATOL = 1e-3
SAVE_AFTER, REPEAT = 4, 8
# ManiSkill's own bookkeeping, which no state restore carries over (seeds for the next reset,
# the last observation it returned, the first state and observation it built the spaces from).
MANISKILL_OWN = {"_episode_seed", "_main_seed", "_last_obs", "_init_raw_obs", "_init_raw_state"}


def _make(env_id: str, **kwargs) -> gym.Env:
    kwargs.setdefault("obs_mode", "state")
    kwargs.setdefault("control_mode", "pd_ee_delta_pose")
    kwargs.setdefault("reward_mode", "normalized_dense")
    return gym.make(env_id, sim_backend="cpu", **kwargs)


@pytest.fixture
def make():
    made: list[gym.Env] = []

    def _made(env_id: str, **kwargs) -> gym.Env:
        made.append(_make(env_id, **kwargs))
        return made[-1]

    yield _made
    for env in made:
        env.close()


def _random_actions(env: gym.Env, n: int, seed: int) -> np.ndarray:
    shape = env.unwrapped.single_action_space.shape
    return np.random.default_rng(seed).uniform(-1, 1, (n, *shape)).astype(np.float32)


def _run_oracle(env: gym.Env, env_id: str, seed: int, max_steps: int, every: int) -> list[tuple[dict, dict]]:
    """Reset ``env`` with ``seed`` and step its family's oracle (end-effector actions) to the
    episode's end or ``max_steps``; returns (state, attributes) every ``every`` steps and at the end."""
    family = get_rl_task(env_id).family if env_id in RL_IDS else get_task(env_id).family
    base = env.unwrapped
    obs, _ = env.reset(seed=seed)
    oracle = ORACLES[family](env)
    reset_with_seed(oracle, seed)
    saved = []
    for step in range(1, max_steps + 1):
        obs, _, terminated, truncated, _ = env.step(oracle.forward(obs))
        done = bool(terminated[0] | truncated[0]) or step == max_steps
        if step % every == 0 or done:
            saved.append((base.get_state_dict(), _episode_attributes(base)))
        if done:
            return saved
    return saved


def _steps(env: gym.Env, actions: np.ndarray) -> list[dict[str, Any]]:
    """Step ``actions``; per step the outputs and the info entries (copies)."""
    out = []
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(action)
        step = {"obs": obs, "reward": reward, "terminated": terminated, "truncated": truncated}
        # reward_dict is the previous step's reward terms: None after a restore (TRANSIENT_STATE).
        step.update({f"info.{k}": v for k, v in info.items() if k != "reward_dict"})
        out.append(_copy(step))
    return out


def _copy(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.detach().clone()
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_copy(v) for v in value]
    return value


def _assert_same(a: Any, b: Any, path: str, exact: bool = False) -> None:
    """Equal structure; tensors equal (floats to ATOL/RTOL unless ``exact``)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), f"{path}: keys {set(a)} != {set(b)}"
        for key in a:
            _assert_same(a[key], b[key], f"{path}.{key}", exact)
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), f"{path}: {a} != {b}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{path}[{i}]", exact)
    elif isinstance(a, (torch.Tensor, np.ndarray)):
        x, y = torch.as_tensor(a), torch.as_tensor(b)
        assert x.shape == y.shape and x.dtype == y.dtype, f"{path}: {x.shape} {x.dtype} != {y.shape} {y.dtype}"
        if exact or not x.is_floating_point():
            assert torch.equal(x, y), f"{path}: {x} != {y}"
        else:
            assert torch.allclose(x, y, atol=ATOL, rtol=RTOL), f"{path}: max diff {(x - y).abs().max()}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def _is_ours(value: Any) -> bool:
    module = type(value).__module__ or ""
    return module.startswith(("mikasa_envs.tasks", "mikasa_envs.building_blocks", "mikasa_robo_rl"))


_SKIP = object()


def _freeze(value: Any) -> Any:
    """A comparable copy of an attribute's value; _SKIP for simulator and other objects."""
    if isinstance(value, (torch.Tensor, np.ndarray)):
        return _copy(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, dict):
        items = {k: _freeze(v) for k, v in value.items()}
    elif isinstance(value, (list, tuple)):
        items = {str(i): _freeze(v) for i, v in enumerate(value)}
    elif _is_ours(value):
        items = {k: _freeze(v) for k, v in vars(value).items()}
    else:
        return _SKIP
    return {k: v for k, v in items.items() if v is not _SKIP}


def _episode_attributes(base) -> dict[str, Any]:
    """The env's own attributes (building blocks walked into), frozen, by name."""
    frozen = {name: _freeze(value) for name, value in vars(base).items() if name not in MANISKILL_OWN}
    return {name: value for name, value in frozen.items() if value is not _SKIP}


def _assert_attributes_restored(base, saved: dict[str, Any], env_id: str) -> None:
    """Every attribute of ``base`` but its TRANSIENT_STATE equals the ``saved`` snapshot."""
    transient = set(base.transient_state_names())
    restored = _episode_attributes(base)
    assert restored.keys() == saved.keys()
    for name, value in saved.items():
        if name not in transient:
            what = f"{env_id}: attribute {name} after a restore (add it to TASK_STATE, or to TRANSIENT_STATE if it need not be saved)"
            _assert_same(restored[name], value, what, exact=True)


def check_save_restore(make, env_id: str) -> None:
    env = make(env_id)
    base = env.unwrapped
    env.reset(seed=5)
    actions = _random_actions(env, SAVE_AFTER + REPEAT, seed=0)
    _steps(env, actions[:SAVE_AFTER])
    state = base.get_state_dict()
    attributes = _episode_attributes(base)
    # The reference run starts from a restore too: restoring rewrites PhysX's link poses from
    # the joint positions, which an uninterrupted run keeps slightly differently (float noise).
    base.set_state_dict(state)
    reference = _steps(env, actions[SAVE_AFTER:])
    final_state = base.get_task_state()

    # Same env, restored after it has stepped on.
    base.set_state_dict(state)
    _assert_attributes_restored(base, attributes, env_id)
    _assert_same(_steps(env, actions[SAVE_AFTER:]), reference, f"{env_id} restored")

    # Another env, freshly reset with another seed.
    other = make(env_id)
    other.reset(seed=6)
    other.unwrapped.set_state_dict(state)
    _assert_attributes_restored(other.unwrapped, attributes, env_id)
    _assert_same(_steps(other, actions[SAVE_AFTER:]), reference, f"{env_id} restored in a fresh env")
    _assert_same(other.unwrapped.get_task_state(), final_state, f"{env_id} task state after the repeat")

    # The same env in another episode that its oracle has played (latches set, stages on):
    # its states along that episode, restored in reverse order, then the saved one. Every
    # attribute not in TRANSIENT_STATE must come back each time, so an attribute that changes
    # along an episode and is not saved fails here.
    played = _run_oracle(other, env_id, seed=7, max_steps=OTHER_ENV_ORACLE_STEPS, every=ORACLE_SNAPSHOT_EVERY)
    for i, (played_state, played_attributes) in enumerate(reversed(played)):
        other.unwrapped.set_state_dict(played_state)
        _assert_attributes_restored(other.unwrapped, played_attributes, f"{env_id} (oracle state {i})")
    other.unwrapped.set_state_dict(state)
    _assert_attributes_restored(other.unwrapped, attributes, env_id)
    _assert_same(_steps(other, actions[SAVE_AFTER:]), reference, f"{env_id} restored after an oracle episode")


@pytest.mark.parametrize("env_id", FAST_IDS)
def test_save_restore(make, env_id):
    check_save_restore(make, env_id)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", SLOW_IDS)
def test_save_restore_every_id(make, env_id):
    check_save_restore(make, env_id)


# ----------------------------------------------------------------------------- layout
def _leaves(tree: dict, prefix: str = ""):
    for key, value in tree.items():
        if isinstance(value, dict):
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield prefix + key, value


@pytest.mark.parametrize("env_id", FAST_IDS)
def test_task_state_declarations(make, env_id):
    """Declared names exist, TASK_STATE and TRANSIENT_STATE do not overlap, and every saved
    entry is a (num_envs, D) tensor, the layout of ManiSkill's own entries."""
    base = make(env_id).unwrapped
    base.reset(seed=0)
    saved, transient = base.task_state_names(), base.transient_state_names()
    assert not set(saved) & set(transient)
    for name in saved + transient:
        assert hasattr(base, name), f"{type(base).__name__} declares {name!r} but has no such attribute"
    task = base.get_state_dict()["task"]
    assert "elapsed_steps" in task
    for path, value in _leaves(task):
        assert isinstance(value, torch.Tensor) and value.ndim == 2 and value.shape[0] == base.num_envs, path


# ------------------------------------------------------- other forms of the same state
def _unbatched_numpy(tree: dict) -> dict:
    """One env's row of every entry, as numpy without the batch dim (an .h5 step)."""
    return {k: _unbatched_numpy(v) if isinstance(v, dict) else v[0].cpu().numpy() for k, v in tree.items()}


@pytest.mark.parametrize("form", ["unbatched_numpy", "flat_vector", "reset_to_env_states", "env_idx"])
@pytest.mark.parametrize("env_id", ["BlinkCountButtonPressEasy-VLA-v0", "RotateStrictPosNeg-VLA-v0"])
def test_state_forms(make, env_id, form):
    """The state as replay_trajectory feeds it (numpy rows from an .h5), as get_state()'s flat
    vector (set_state), through reset(options=reset_to_env_states), and restored with env_idx."""
    env = make(env_id)
    env.reset(seed=5)
    actions = _random_actions(env, SAVE_AFTER + REPEAT, seed=0)
    _steps(env, actions[:SAVE_AFTER])
    base = env.unwrapped
    state = base.get_state_dict()
    flat = base.get_state()
    base.set_state_dict(state)
    reference = _steps(env, actions[SAVE_AFTER:])

    other = make(env_id)
    other.reset(seed=6)
    _steps(other, _random_actions(other, 3, seed=1))
    target = other.unwrapped
    if form == "unbatched_numpy":
        target.set_state_dict(_unbatched_numpy(state))
    elif form == "flat_vector":
        target.set_state(flat)
    elif form == "reset_to_env_states":
        other.reset(options={"reset_to_env_states": {"env_states": state}})
    else:
        target.set_state_dict(state, env_idx=torch.tensor([0]))
    # The flat vector holds float32: exact for these entries' values (small ints, flags, float32).
    _assert_same(target.get_task_state(), state["task"], f"{env_id} {form}", exact=True)
    _assert_same(_steps(other, actions[SAVE_AFTER:]), reference, f"{env_id} {form}")


def test_controller_state_restored(make):
    """The *_target_* control modes keep a target in the controller: restored too."""
    env = make("TakeItBack-VLA-v0", control_mode="pd_ee_target_delta_pose")
    env.reset(seed=5)
    actions = _random_actions(env, SAVE_AFTER + REPEAT, seed=0)
    _steps(env, actions[:SAVE_AFTER])
    state = env.unwrapped.get_state_dict()
    assert state["controller"], "pd_ee_target_delta_pose should have a controller state"
    env.unwrapped.set_state_dict(state)
    reference = _steps(env, actions[SAVE_AFTER:])
    other = make("TakeItBack-VLA-v0", control_mode="pd_ee_target_delta_pose")
    other.reset(seed=6)
    _steps(other, _random_actions(other, 5, seed=1))
    other.unwrapped.set_state_dict(state)
    _assert_same(_steps(other, actions[SAVE_AFTER:]), reference, "controller")


# ------------------------------------------------------------------- record and replay
# Tasks whose oracle does not push objects around: there PhysX's contact caches (not part
# of any state) make a restored step differ from the recorded one by more than float noise
# (TakeItBack: ~0.05 rad/s of joint velocity on the first step after a restore mid-push).
REPLAY_IDS = ["RememberColor3-VLA-v0", "BlinkCountButtonPressEasy-VLA-v0", "ShellGameTouch-VLA-v0"]


def _record_oracle_episode(env_id: str, out: Path, seed: int = 5) -> Path:
    env = RecordEpisode(_make(env_id), str(out), save_trajectory=True, save_video=False,
                        trajectory_name=env_id, record_reward=True, source_type="oracle")
    try:
        assert rollout(env, make_oracle(env), seed=seed).success_once
    finally:
        env.close()
    return out / f"{env_id}.h5"


def _task_states(h5: Path) -> dict:
    with h5py.File(h5, "r") as f:
        return {k: v[:] for k, v in _leaves_h5(f["traj_0/env_states/task"])}


def _leaves_h5(group: h5py.Group, prefix: str = ""):
    for key, value in group.items():
        if isinstance(value, h5py.Group):
            yield from _leaves_h5(value, f"{prefix}{key}.")
        else:
            yield prefix + key, value


@pytest.mark.parametrize("env_id", REPLAY_IDS)
def test_maniskill_replay_reproduces_oracle_episode(tmp_path, env_id):
    """Record an oracle episode with ManiSkill's RecordEpisode, replay it with ManiSkill's
    replay_trajectory --use-env-states (through ``python -m mikasa_envs.replay_trajectory``,
    which registers the MIKASA ids first) and get its success and task states back."""
    traj = _record_oracle_episode(env_id, tmp_path)
    episode = json.loads(traj.with_suffix(".json").read_text())["episodes"][0]
    assert episode["success"]
    result = subprocess.run(
        [sys.executable, "-m", "mikasa_envs.replay_trajectory", "--traj-path", str(traj), "--use-env-states", "--save-traj"],
        capture_output=True, text=True, timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert result.returncode == 0, result.stderr[-3000:]
    # Only successful replays are saved (without --allow-failure).
    assert "1/1=100.00% demos saved" in result.stdout, result.stdout[-2000:]
    replayed = tmp_path / f"{env_id}.state.pd_ee_delta_pose.physx_cpu.h5"
    replay_json = json.loads(replayed.with_suffix(".json").read_text())
    assert replay_json["episodes"][0]["success"]
    with h5py.File(replayed, "r") as f:
        assert bool(f["traj_0/success"][-1])
    recorded, replayed_states = _task_states(traj), _task_states(replayed)
    assert recorded.keys() == replayed_states.keys()
    for key, values in recorded.items():
        # Row 0 differs: ManiSkill 3.0.1's replay overwrites its first saved state with the
        # trajectory's second one (an off-by-one in replay_cpu_sim).
        _assert_close_or_equal(replayed_states[key][1:], values[1:], key)


@pytest.mark.parametrize("env_id", REPLAY_IDS)
def test_restore_recorded_state_mid_episode(tmp_path, env_id):
    """A mid-episode state read from the .h5 of an oracle episode, restored into an env reset
    with another seed: the recorded actions from there on give the recorded episode (task
    states exactly, observations to float noise) and its success."""
    traj = _record_oracle_episode(env_id, tmp_path)
    with h5py.File(traj, "r") as f:
        group = f["traj_0"]
        states = trajectory_utils.dict_to_list_of_dicts(group["env_states"])
        actions, success, obs = group["actions"][:], group["success"][:], group["obs"][:]
    start = len(actions) // 2
    env = _make(env_id)
    env.reset(seed=123)
    env.unwrapped.set_state_dict(states[start])
    for t in range(start, len(actions)):
        o, _, _, _, info = env.step(actions[t])
        np.testing.assert_allclose(o[0].numpy(), obs[t + 1], atol=RECORDING_ATOL, rtol=RTOL, err_msg=f"obs {t}")
        assert bool(info["success"][0]) == bool(success[t]), f"success at step {t}"
        task = env.unwrapped.get_task_state()
        for key, value in _leaves(task):
            _assert_close_or_equal(value[0].numpy(), _h5_leaf(states[t + 1]["task"], key), f"{key} at {t}")
    assert bool(success[-1])
    env.close()


def _assert_close_or_equal(actual: np.ndarray, expected: np.ndarray, what: str) -> None:
    """Floats (what the physics moved) to RECORDING_ATOL, everything else exactly."""
    if np.issubdtype(np.asarray(expected).dtype, np.floating):
        np.testing.assert_allclose(actual, expected, atol=RECORDING_ATOL, rtol=RTOL, err_msg=what)
    else:
        np.testing.assert_array_equal(actual, expected, err_msg=what)


def _h5_leaf(tree: dict, dotted: str) -> np.ndarray:
    for part in dotted.split("."):
        tree = tree[part]
    return np.asarray(tree)
