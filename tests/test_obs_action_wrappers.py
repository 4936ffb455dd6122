"""Tests of the single wrappers of mikasa-wrappers on the fake env of ``wrappers_fakes``:
StateOnlyTensorToDict, FlattenRGBD, ConvertJointsToEEFXyzRpyGripper, the action wrappers
and CameraShutdown.
"""

from __future__ import annotations

import mikasa_wrappers as mw
import numpy as np
import pytest
import torch
from wrappers_fakes import FakeVLAEnv, _ref_rpy

# ----------------------------------------------------------------------------------------
# StateOnlyTensorToDictWrapper
# ----------------------------------------------------------------------------------------


def test_state_only_adds_entries_and_sentinel():
    env = FakeVLAEnv(num_envs=3)
    env.oracle_info = torch.tensor([[1, 2], [0, 1], [2, 0]], dtype=torch.uint8)
    w = mw.StateOnlyTensorToDictWrapper(env)
    obs, _ = w.reset()
    assert mw.MISSING_VALUE_SENTINEL == 4242424242
    assert obs["task_cue"].shape == (3, 1) and obs["task_cue"].dtype == torch.float32
    assert (obs["task_cue"] == mw.MISSING_VALUE_SENTINEL).all()
    assert torch.equal(obs["oracle_info"], env.oracle_info)  # (B, 2) kept
    assert list(obs)[:4] == ["agent", "extra", "sensor_param", "sensor_data"]
    assert w.observation_space["oracle_info"].shape == (3, 2)
    assert w.observation_space["task_cue"].shape == (3, 1)


def test_state_only_reshapes_1d_and_wraps_flat_obs():
    env = FakeVLAEnv(num_envs=2, obs_mode="state")
    env.task_cue = torch.tensor([3, 4], dtype=torch.uint8)
    w = mw.StateOnlyTensorToDictWrapper(env)
    obs, _ = w.reset()
    assert list(obs) == ["state", "task_cue", "oracle_info"]
    assert obs["state"].shape == (2, 25)
    assert obs["task_cue"].tolist() == [[3], [4]]
    assert obs["oracle_info"].shape == (2, 1)
    assert w.observation_space["state"].shape == (2, 25)


# ----------------------------------------------------------------------------------------
# FlattenRGBDObservationWrapper
# ----------------------------------------------------------------------------------------


def _flattened(env, **flags) -> mw.FlattenRGBDObservationWrapper:
    """``env`` behind the state-dict wrapper and the flattening wrapper (no depth)."""
    return mw.FlattenRGBDObservationWrapper(mw.StateOnlyTensorToDictWrapper(env), depth=False, **flags)


def test_flatten_drops_sentinel_and_oracle():
    env = FakeVLAEnv(num_envs=2)
    w = _flattened(env, rgb=True, state=False, oracle=False, joints=True)
    obs, _ = w.reset()
    assert list(obs) == ["proprio", "rgb"]
    assert obs["proprio"].shape == (2, 25)
    assert torch.equal(obs["proprio"][:, :7], env.tcp_pose)
    assert torch.equal(obs["proprio"][:, 7:16], env.qpos)
    assert list(w.observation_space.keys()) == ["proprio", "rgb"]


def test_flatten_oracle_true_keeps_real_oracle_but_not_sentinel():
    env = FakeVLAEnv(num_envs=2)
    w = _flattened(env, rgb=True, state=False, oracle=True, joints=True)
    obs, _ = w.reset()
    assert list(obs) == ["proprio", "rgb", "oracle_info"]
    assert obs["oracle_info"].tolist() == [[0], [1]]
    env.oracle_info = None
    obs, *_ = w.step(torch.zeros(2, 7))
    assert "oracle_info" not in obs


def test_flatten_state_only_configuration():
    env = FakeVLAEnv(num_envs=2, obs_mode="state")
    env.task_cue = torch.tensor([1.0, 2.0])
    w = _flattened(env, rgb=False, state=True, oracle=False, joints=False)
    obs, _ = w.reset()
    assert list(obs) == ["state", "task_cue"]
    assert obs["state"].shape == (2, 25)
    assert list(w.observation_space.keys()) == ["state", "task_cue"]


def test_flatten_rgb_needs_cameras():
    env = FakeVLAEnv(num_envs=2, obs_mode="state")
    with pytest.raises(ValueError, match="obs_mode='rgb'"):
        mw.FlattenRGBDObservationWrapper(
            mw.StateOnlyTensorToDictWrapper(env), rgb=True, depth=False, state=False, joints=True
        )


# ----------------------------------------------------------------------------------------
# ConvertJointsToEEFXyzRpyGripperWrapper
# ----------------------------------------------------------------------------------------


def _convert_wrapper(**kwargs):
    env = FakeVLAEnv(num_envs=2)
    flat = mw.FlattenRGBDObservationWrapper(
        mw.StateOnlyTensorToDictWrapper(env), rgb=True, depth=False, state=False, joints=True
    )
    return mw.ConvertJointsToEEFXyzRpyGripperWrapper(flat, **kwargs)


def test_convert_rpy_matches_transforms3d_and_gripper_is_finger_sum():
    w = _convert_wrapper()
    assert w.qpos_dim == 9  # read from the (fake) robot
    rng = np.random.default_rng(0)
    n = 64
    quats = rng.normal(size=(n, 4)) * rng.uniform(0.2, 3.0, size=(n, 1))  # not normalised
    quats[0] = [0.0, 1.0, 0.0, 0.0]  # TCP pointing down: roll at the +-pi wrap
    quats[1] = [np.cos(0.6), 0.0, np.sin(0.6), 0.0]  # pure pitch
    qpos = rng.uniform(-1, 1, size=(n, 9))
    vec = np.concatenate([rng.normal(size=(n, 3)), quats, qpos, rng.normal(size=(n, 9))], -1)
    out_t = w.convert(torch.tensor(vec, dtype=torch.float64))
    out_n = w.convert(vec)
    assert isinstance(out_t, torch.Tensor) and out_t.dtype == torch.float32
    assert isinstance(out_n, np.ndarray) and out_n.dtype == np.float32
    np.testing.assert_allclose(out_t.numpy(), out_n, atol=1e-5)
    np.testing.assert_allclose(out_n[:, :3], vec[:, :3], atol=1e-6)
    np.testing.assert_allclose(out_n[:, 6], qpos[:, 7] + qpos[:, 8], atol=1e-5)
    for k in range(n):
        ref = _ref_rpy(quats[k])
        got = out_n[k, 3:6].astype(np.float64)
        # roll/yaw live on a circle: compare modulo 2*pi (relevant only at the +-pi wrap)
        diff = (got - ref + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(diff, 0, atol=2e-4)
    assert np.all(np.abs(out_n[:, 3]) <= np.pi + 1e-6)
    assert np.all(np.abs(out_n[:, 4]) <= np.pi / 2 + 1e-6)
    assert abs(abs(out_n[0, 3]) - np.pi) < 1e-5


def test_convert_layouts_and_errors():
    w = _convert_wrapper()
    v1 = w.convert(torch.arange(25, dtype=torch.float32))
    assert v1.shape == (7,)  # 1-D in, 1-D out
    seven = torch.ones(2, 7, dtype=torch.float64)
    assert w.convert(seven).dtype == torch.float32 and w.convert(seven).shape == (2, 7)
    with pytest.raises(RuntimeError):
        w.convert(torch.zeros(2, 5))
    with pytest.raises(RuntimeError):
        w.convert(torch.zeros(2, 12))  # 7 + qpos_dim (9) > 12
    inferred = _convert_wrapper(qpos_dim=None)
    inferred.qpos_dim = None  # no robot: infer (D - 7) / 2
    v = np.zeros(7 + 4 + 4, np.float32)
    v[3] = 1.0
    v[7:11] = [0.0, 0.0, 0.01, 0.02]
    assert inferred.convert(v)[6] == pytest.approx(0.03)
    with pytest.raises(ValueError):
        _convert_wrapper(gripper_finger_dims=0)
    assert w.observation({"x": 1}) == {"x": 1}
    flat = torch.zeros(3)
    assert w.observation(flat) is flat


# ----------------------------------------------------------------------------------------
# action wrappers
# ----------------------------------------------------------------------------------------


def _curriculum_env(num_envs=3, empty=True):
    env = FakeVLAEnv(num_envs=num_envs)
    env.cue_steps_per_env = torch.tensor([1, 2, 3, 99], dtype=torch.int64)  # longer than B
    env.empty_steps_per_env = torch.tensor([1, 0, 2, 99], dtype=torch.int64) if empty else None
    return env, mw.CurriculumPhaseNoopActionWrapper(env)


def test_curriculum_passes_through_before_reset_and_without_attribute():
    env, w = _curriculum_env()
    a = torch.ones(3, 7)
    w.step(a)
    assert env.actions[-1] is a
    plain = FakeVLAEnv(num_envs=3)
    pw = mw.CurriculumPhaseNoopActionWrapper(plain)
    pw.reset()
    pw.step(a)
    assert plain.actions[-1] is a


def test_curriculum_zeroes_rows_per_env_torch():
    env, w = _curriculum_env()
    w.reset()
    limits = [2, 2, 5]  # cue + empty
    for t in range(7):
        a = torch.arange(1, 22, dtype=torch.float32).reshape(3, 7)
        w.step(a)
        sent = env.actions[-1]
        frozen = [t < lim for lim in limits]
        if not any(frozen):
            assert sent is a  # passed through unchanged
            continue
        assert isinstance(sent, torch.Tensor) and sent is not a
        for i in range(3):
            if frozen[i]:
                assert (sent[i] == 0).all()  # whole row, gripper included
            else:
                assert torch.equal(sent[i], a[i])
        assert torch.equal(a, torch.arange(1, 22, dtype=torch.float32).reshape(3, 7))


def test_curriculum_numpy_and_1d_broadcast():
    env, w = _curriculum_env()
    w.reset()
    w.step(np.ones((3, 7), np.float32))  # t = 0: all frozen
    assert (env.actions[-1] == 0).all() and isinstance(env.actions[-1], np.ndarray)
    w.step(np.ones((3, 7), np.float32))  # t = 1: all frozen
    w.step(np.ones((3, 7), np.float32))  # t = 2: only env 2 frozen (limits 2, 2, 5)
    sent = env.actions[-1]
    assert isinstance(sent, np.ndarray)
    assert sent[2].tolist() == [0] * 7 and sent[:2].tolist() == [[1] * 7] * 2
    one_d = np.full(7, 0.5, np.float32)
    w.step(one_d)  # t = 3
    sent = env.actions[-1]
    assert isinstance(sent, np.ndarray) and sent.shape == (3, 7)
    assert (sent[2] == 0).all() and (sent[:2] == 0.5).all()
    w.step(torch.full((7,), 0.5))  # t = 4
    sent = env.actions[-1]
    assert isinstance(sent, torch.Tensor) and sent.shape == (3, 7)
    assert (sent[2] == 0).all() and (sent[:2] == 0.5).all()


def test_curriculum_without_empty_attribute_uses_cue_only():
    env, w = _curriculum_env(empty=False)
    w.reset()
    w.step(torch.ones(3, 7))  # t = 0: all frozen (cue 1, 2, 3)
    assert (env.actions[-1] == 0).all()
    w.step(torch.ones(3, 7))  # t = 1: envs 1, 2 frozen
    assert env.actions[-1][:, 0].tolist() == [1, 0, 0]


def test_curriculum_pd_joint_pos_holds_pose():
    env = FakeVLAEnv(num_envs=2)
    env.cue_steps_per_env = torch.tensor([5, 0])
    w = mw.CurriculumPhaseNoopActionWrapperPdJointPos(env)
    w.reset()
    a = torch.full((2, 8), 0.7)
    w.step(a)
    sent = env.actions[-1]
    assert torch.allclose(sent[0, :7], env.qpos[0, :7])
    assert sent[0, 7].item() == pytest.approx((0.025 - 0.015) / 0.025)
    assert torch.equal(sent[1], a[1])
    w.step(np.full((2, 8), 0.7, np.float32))
    sent = env.actions[-1]
    assert isinstance(sent, np.ndarray)
    np.testing.assert_allclose(sent[0, :7], env.qpos[0, :7].numpy(), atol=1e-6)


def test_initial_zero_action_wrapper():
    env = FakeVLAEnv(num_envs=2)
    w = mw.InitialZeroActionWrapper(env, n_initial_steps=2)
    w.reset()
    for t in range(3):
        a = torch.ones(2, 7)
        w.step(a)
        if t < 2:
            assert (env.actions[-1] == 0).all()
        else:
            assert env.actions[-1] is a


# ----------------------------------------------------------------------------------------
# CameraShutdownWrapper
# ----------------------------------------------------------------------------------------


def test_camera_shutdown_blacks_out_cameras_and_render():
    env = FakeVLAEnv(num_envs=1)
    env._human_render_camera_configs = {"render_camera": type("C", (), {"width": 300})()}
    w = mw.CameraShutdownWrapper(mw.StateOnlyTensorToDictWrapper(env), n_initial_steps=2)
    obs, _ = w.reset()
    assert (obs["sensor_data"]["base_camera"]["rgb"] == 10).all()
    for _ in range(2):
        obs, *_ = w.step(torch.zeros(1, 7))
    assert (obs["sensor_data"]["hand_camera"]["rgb"] == 200).all()
    assert (w.render() == 100).all()
    obs, *_ = w.step(torch.zeros(1, 7))  # elapsed 3 > 2
    assert (obs["sensor_data"]["base_camera"]["rgb"] == 0).all()
    assert (obs["sensor_data"]["hand_camera"]["rgb"] == 0).all()
    frame = w.render()
    assert (frame[0, :, :300] == 100).all() and (frame[0, :, 300:] == 0).all()
