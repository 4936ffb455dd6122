"""Tests of the mikasa-wrappers package (canonical VLA chain, wrappers, overlays).

Most tests use the fake env of ``wrappers_fakes``; a few run ManiSkill's own PushCube-v1 /
PickCube-v1 (CPU sim, rgb mode) through the chain. PushCube is used for proprio values
because, like the MIKASA tasks, its rgb-mode ``extra`` holds only ``tcp_pose``.
"""

from __future__ import annotations

import mikasa_wrappers as mw
import numpy as np
import pytest
import torch
from gymnasium import spaces
from mikasa_wrappers import overlays as ov
from mikasa_wrappers.apply_wrappers import _apply_config
from transforms3d.euler import quat2euler
from wrappers_fakes import CAM, RENDER_HW, FakeVLAEnv

# ----------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------


def _chain(env):
    """Wrapper classes from outermost to innermost."""
    out = []
    while hasattr(env, "env"):
        out.append(type(env))
        env = env.env
    return out


def _ref_rpy(q_wxyz):
    return np.array(quat2euler(np.asarray(q_wxyz, np.float64), "sxyz"))


def _expand(groups):
    return [i for g in groups for i in g]


# The §5 table of wrappers.md, written out independently of the implementation.
EXPECTED_IDS = _expand(
    [
        [
            "ShellGameTouch-VLA-v0",
            "ShellGamePush-VLA-v0",
            "ShellGameShuffleTouch-VLA-v0",
            "ShellGameShuffleColorLampTouch-VLA-v0",
            "ShellGameColorLampTouch-VLA-v0",
            "ShellGameShuffleTouch-Long-VLA-v0",
            "ShellGameShuffleColorLampTouch-Long-VLA-v0",
        ],
        [f"Intercept{s}-VLA-v0" for s in ("Slow", "Medium", "Fast")],
        [f"InterceptGrab{s}-VLA-v0" for s in ("Slow", "Medium", "Fast")],
        ["RotateLenientPos-VLA-v0", "RotateLenientPosNeg-VLA-v0"],
        ["RotateStrictPos-VLA-v0", "RotateStrictPosNeg-VLA-v0", "TakeItBack-VLA-v0"],
        [f"RememberColor{n}-VLA-v0" for n in (3, 5, 9)],
        [f"RememberColor{n}-Long-VLA-v0" for n in (3, 5, 9)],
        [f"RememberShape{n}-VLA-v0" for n in (3, 5, 9)],
        [f"RememberShape{n}-Long-VLA-v0" for n in (3, 5, 9)],
        [f"RememberShapeAndColor{n}-VLA-v0" for n in ("3x2", "3x3", "5x3")],
        [f"RememberShapeAndColor{n}-Long-VLA-v0" for n in ("3x2", "3x3", "5x3")],
        [f"FindImposterColor{n}-VLA-v0" for n in (3, 5, 9)],
        [f"FindImposterShape{n}-VLA-v0" for n in (3, 5, 9)],
        [f"FindImposterShapeAndColor{n}-VLA-v0" for n in ("3x2", "3x3", "5x3")],
        *[
            [f"{fam}{n}{suf}-VLA-v0" for n in (3, 5, 7)]
            for fam in ("BunchOfColors", "SeqOfColors", "ChainOfColors")
            for suf in ("", "-Long")
        ],
        ["BatteriesCheckerEasy-3-VLA-v0", "BatteriesCheckerEasy-6-VLA-v0"],
        ["BatteriesCheckerHard-3-VLA-v0", "BatteriesCheckerHard-6-VLA-v0"],
        [f"BlinkCountButtonPress{d}-VLA-v0" for d in ("Easy", "Medium", "Hard")],
        [f"BlinkCountButtonPress{d}-Long-VLA-v0" for d in ("Easy", "Medium", "Hard")],
        [f"TraceShape{d}-VLA-v0" for d in ("Easy", "Medium", "Hard")],
        [f"TraceShapeSeq{d}-VLA-v0" for d in ("Easy", "Medium", "Hard")],
        [f"TimedTransfer{d}-VLA-v0" for d in ("Easy", "Medium", "Hard")],
        [f"TimedTransfer{d}-Long-VLA-v0" for d in ("Easy", "Medium", "Hard")],
        [f"GatherAndRecall{n}-VLA-v0" for n in (1, 3, 5, 7, 9)],
    ]
)


# ----------------------------------------------------------------------------------------
# configuration table
# ----------------------------------------------------------------------------------------


def test_config_table_ids_and_order():
    assert len(EXPECTED_IDS) == 90
    assert list(mw.VLA_WRAPPER_CONFIGS) == EXPECTED_IDS
    assert mw.MIKASA_VLA_ENV_IDS == tuple(EXPECTED_IDS)
    assert isinstance(mw.MIKASA_VLA_ENV_IDS, tuple)


def test_config_table_curriculum_and_overlays():
    cfgs = mw.VLA_WRAPPER_CONFIGS
    with_curriculum = {i for i, c in cfgs.items() if c.curriculum_wrapper is not None}
    expected = {i for i in EXPECTED_IDS[:5]} | {
        i for i in EXPECTED_IDS if i.startswith(("Remember", "FindImposter")) and "-Long-" not in i
    }
    assert len(expected) == 23
    assert with_curriculum == expected
    assert all(cfgs[i].curriculum_wrapper is mw.CurriculumPhaseNoopActionWrapper for i in expected)
    assert all(c.expected_control_mode is None for c in cfgs.values())
    chain_of = {
        "ShellGameShuffleTouch-Long-VLA-v0": mw.SHELL_GAME,
        "InterceptFast-VLA-v0": mw.INTERCEPT,
        "TakeItBack-VLA-v0": mw.INTERCEPT,
        "RotateStrictPosNeg-VLA-v0": mw.ROTATE,
        "RememberColor9-Long-VLA-v0": mw.COLOR_MEMORY,
        "FindImposterColor5-VLA-v0": mw.COLOR_MEMORY,
        "FindImposterShape3-VLA-v0": mw.SHAPE_MEMORY,
        "FindImposterShapeAndColor5x3-VLA-v0": mw.SHAPE_COLOR_MEMORY,
        "ChainOfColors7-Long-VLA-v0": mw.MEMORY_CAPACITY,
        "BatteriesCheckerHard-6-VLA-v0": mw.BATTERIES_CHECKER,
        "BlinkCountButtonPressHard-Long-VLA-v0": mw.BLINK_COUNT,
        "TraceShapeSeqHard-VLA-v0": mw.TRACE_SHAPE,
        "TimedTransferEasy-Long-VLA-v0": mw.TIMED_TRANSFER,
        "GatherAndRecall9-VLA-v0": mw.STEP_REWARD,
    }
    for env_id, chain in chain_of.items():
        assert cfgs[env_id].overlays == chain, env_id


def test_named_chains_match_spec():
    assert mw.COLOR_MEMORY == (
        mw.RememberColorInfoWrapper,
        mw.RenderStepInfoWrapper,
        mw.RenderRewardInfoWrapper,
    )
    assert mw.SHELL_GAME == (
        mw.RenderStepInfoWrapper,
        mw.ShellGameRenderCupInfoWrapper,
        mw.RenderRewardInfoWrapper,
    )
    assert mw.ROTATE == (
        mw.RenderStepInfoWrapper,
        mw.RenderRewardInfoWrapper,
        mw.RotateRenderAngleInfoWrapper,
    )
    assert mw.STEP_REWARD == mw.INTERCEPT == (mw.RenderStepInfoWrapper, mw.RenderRewardInfoWrapper)
    assert set(mw.OVERLAY_CHAINS) == {
        "COLOR_MEMORY",
        "SHAPE_MEMORY",
        "SHAPE_COLOR_MEMORY",
        "SHELL_GAME",
        "INTERCEPT",
        "ROTATE",
        "MEMORY_CAPACITY",
        "BATTERIES_CHECKER",
        "BLINK_COUNT",
        "TRACE_SHAPE",
        "TIMED_TRANSFER",
        "STEP_REWARD",
    }


def test_config_dataclass_defaults_and_frozen():
    cfg = mw.VLAWrapperConfig()
    assert cfg.overlays == () and cfg.curriculum_wrapper is None
    assert cfg.expected_control_mode is None
    with pytest.raises(AttributeError):
        cfg.overlays = ()  # type: ignore[misc]


# ----------------------------------------------------------------------------------------
# errors
# ----------------------------------------------------------------------------------------


def test_unknown_id_error_names_id_suggests_and_counts():
    env = FakeVLAEnv(env_id="RememberColour3-VLA-v0")
    with pytest.raises(ValueError) as exc:
        mw.apply_mikasa_vla_wrappers(env)
    msg = str(exc.value)
    assert "'RememberColour3-VLA-v0'" in msg
    assert "RememberColor3-VLA-v0" in msg  # difflib suggestion
    assert "90" in msg


def test_registered_extra_variant_is_rejected():
    env = FakeVLAEnv(env_id="BatteriesCheckerEasy-9-VLA-v0")
    with pytest.raises(ValueError, match="BatteriesCheckerEasy-9-VLA-v0"):
        mw.apply_mikasa_vla_wrappers(env)


def test_env_without_spec_id_asks_for_gym_make():
    with pytest.raises(ValueError, match="gym.make"):
        mw.apply_mikasa_vla_wrappers(FakeVLAEnv(env_id=None))


def test_wrong_obs_mode_names_rgb():
    env = FakeVLAEnv(obs_mode="state")
    with pytest.raises(ValueError) as exc:
        mw.apply_mikasa_vla_wrappers(env)
    assert "obs_mode='rgb'" in str(exc.value) and "'state'" in str(exc.value)


def test_control_mode_mismatch_warns():
    env = FakeVLAEnv()
    cfg = mw.VLAWrapperConfig(expected_control_mode="pd_joint_pos")
    with pytest.warns(RuntimeWarning, match="pd_joint_pos"):
        _apply_config(env, cfg)


# ----------------------------------------------------------------------------------------
# the whole chain on the fake env
# ----------------------------------------------------------------------------------------


def test_chain_on_fake_env_keys_shapes_order_and_space():
    env = FakeVLAEnv(num_envs=3)
    wrapped = mw.apply_mikasa_vla_wrappers(env)
    assert env.reset_calls == 0  # no reset during construction
    assert wrapped.max_episode_steps == 25
    assert _chain(wrapped) == [
        mw.ConvertJointsToEEFXyzRpyGripperWrapper,
        mw.FlattenRGBDObservationWrapper,
        mw.CurriculumPhaseNoopActionWrapper,
        mw.StateOnlyTensorToDictWrapper,
    ]
    obs, info = wrapped.reset(seed=0)
    assert list(obs) == ["proprio", "rgb"]
    assert obs["proprio"].shape == (3, 7) and obs["proprio"].dtype == torch.float32
    assert obs["rgb"].shape == (3, CAM, CAM, 6) and obs["rgb"].dtype == torch.uint8
    assert (obs["rgb"][..., :3] == 10).all() and (obs["rgb"][..., 3:] == 200).all()
    assert "oracle_info" in info  # the answer stays in info only
    space = wrapped.observation_space
    assert list(space.keys()) == ["proprio", "rgb"]
    assert space["proprio"] == spaces.Box(-np.inf, np.inf, (3, 7), np.float32)
    assert space["rgb"] == spaces.Box(0, 255, (3, CAM, CAM, 6), np.uint8)
    assert wrapped.single_observation_space["proprio"].shape == (7,)
    assert wrapped.single_observation_space["rgb"].shape == (CAM, CAM, 6)
    assert space.contains({k: v.numpy() for k, v in obs.items()})


def test_chain_keeps_task_cue_when_env_sets_one():
    env = FakeVLAEnv(num_envs=2, env_id="RotateLenientPos-VLA-v0")
    env.task_cue = torch.tensor([0.5, -0.25], dtype=torch.float16)
    wrapped = mw.apply_mikasa_vla_wrappers(env)
    obs, _ = wrapped.reset()
    assert list(obs) == ["proprio", "rgb", "task_cue"]
    assert obs["task_cue"].shape == (2, 1)
    assert torch.equal(obs["task_cue"][:, 0], env.task_cue)
    assert list(wrapped.observation_space.keys()) == ["proprio", "rgb", "task_cue"]
    assert wrapped.observation_space["task_cue"].shape == (2, 1)
    assert wrapped.observation_space["task_cue"].dtype == np.float16
    assert _chain(wrapped)[2] is mw.StateOnlyTensorToDictWrapper  # no curriculum for Rotate


def test_chain_with_overlays_and_max_episode_steps_override():
    env = FakeVLAEnv(num_envs=1, env_id="ShellGameTouch-VLA-v0", max_episode_steps=7)
    wrapped = mw.apply_mikasa_vla_wrappers(env, include_overlays=True)
    assert wrapped.max_episode_steps == 7
    assert _chain(wrapped)[2:5] == list(reversed(mw.SHELL_GAME))
    wrapped.reset()
    frame = wrapped.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8
    assert (frame != 100).any()


def test_include_overlays_defaults_to_false():
    env = FakeVLAEnv(num_envs=1)
    wrapped = mw.apply_mikasa_vla_wrappers(env)
    assert not any(issubclass(c, ov._RenderOverlayWrapper) for c in _chain(wrapped))


def test_chain_without_wrist_camera_has_three_channels():
    env = FakeVLAEnv(num_envs=2, cameras=("base_camera",))
    wrapped = mw.apply_mikasa_vla_wrappers(env)
    assert wrapped.observation_space["rgb"].shape == (2, CAM, CAM, 3)
    obs, _ = wrapped.reset()
    assert obs["rgb"].shape == (2, CAM, CAM, 3)


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


def test_flatten_drops_sentinel_and_oracle():
    env = FakeVLAEnv(num_envs=2)
    w = mw.FlattenRGBDObservationWrapper(
        mw.StateOnlyTensorToDictWrapper(env),
        rgb=True,
        depth=False,
        state=False,
        oracle=False,
        joints=True,
    )
    obs, _ = w.reset()
    assert list(obs) == ["proprio", "rgb"]
    assert obs["proprio"].shape == (2, 25)
    assert torch.equal(obs["proprio"][:, :7], env.tcp_pose)
    assert torch.equal(obs["proprio"][:, 7:16], env.qpos)
    assert list(w.observation_space.keys()) == ["proprio", "rgb"]


def test_flatten_oracle_true_keeps_real_oracle_but_not_sentinel():
    env = FakeVLAEnv(num_envs=2)
    w = mw.FlattenRGBDObservationWrapper(
        mw.StateOnlyTensorToDictWrapper(env),
        rgb=True,
        depth=False,
        state=False,
        oracle=True,
        joints=True,
    )
    obs, _ = w.reset()
    assert list(obs) == ["proprio", "rgb", "oracle_info"]
    assert obs["oracle_info"].tolist() == [[0], [1]]
    env.oracle_info = None
    obs, *_ = w.step(torch.zeros(2, 7))
    assert "oracle_info" not in obs


def test_flatten_state_only_configuration():
    env = FakeVLAEnv(num_envs=2, obs_mode="state")
    env.task_cue = torch.tensor([1.0, 2.0])
    w = mw.FlattenRGBDObservationWrapper(
        mw.StateOnlyTensorToDictWrapper(env),
        rgb=False,
        depth=False,
        state=True,
        oracle=False,
        joints=False,
    )
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


# ----------------------------------------------------------------------------------------
# overlays
# ----------------------------------------------------------------------------------------


def _render_pair(wrapper_cls, env, steps=1):
    """(raw frame batch, overlaid frame batch) after reset + `steps` zero steps."""
    w = wrapper_cls(env)
    w.reset()
    for _ in range(steps):
        w.step(torch.zeros(env.num_envs, 7))
    raw = env.render().numpy()
    return raw, w.render()


def _changed(raw, out, env_index=0, region=None):
    a, b = raw[env_index], out[env_index]
    if region is not None:
        (y0, y1), (x0, x1) = region
        a, b = a[y0:y1, x0:x1], b[y0:y1, x0:x1]
    return bool((a != b).any())


def test_overlay_passes_step_results_through():
    env = FakeVLAEnv(num_envs=2)
    w = mw.RenderRewardInfoWrapper(mw.RenderStepInfoWrapper(env))
    obs, info = w.reset()
    assert set(obs) == {"agent", "extra", "sensor_param", "sensor_data"}
    _, reward, _, _, info = w.step(torch.zeros(2, 7))
    assert torch.equal(reward, env.reward_value)
    assert info["elapsed_steps"].tolist() == [1, 1]


def test_step_and_reward_overlays_draw_per_env(monkeypatch):
    monkeypatch.delenv("MIKASA_DISABLE_REWARD_OVERLAY", raising=False)
    env = FakeVLAEnv(num_envs=2)
    raw, out = _render_pair(mw.RenderStepInfoWrapper, env)
    assert out.dtype == np.uint8 and out.shape == (2, *RENDER_HW, 3)
    assert _changed(raw, out, 0, ((5, 40), (0, 200))) and _changed(raw, out, 1, ((5, 40), (0, 200)))
    assert not _changed(raw, out, 0, ((100, 480), (0, 640)))
    raw, out = _render_pair(mw.RenderRewardInfoWrapper, env)
    assert _changed(raw, out, 0, ((60, 100), (0, 260)))
    assert not _changed(raw, out, 0, ((0, 55), (0, 640)))


@pytest.mark.parametrize("value", ["1", "TRUE", "yes", "Y", "on"])
def test_reward_overlay_respects_disable_env_var(monkeypatch, value):
    monkeypatch.setenv("MIKASA_DISABLE_REWARD_OVERLAY", value)
    raw, out = _render_pair(mw.RenderRewardInfoWrapper, FakeVLAEnv(num_envs=1))
    assert not _changed(raw, out)


def test_reward_overlay_not_disabled_by_other_values(monkeypatch):
    monkeypatch.setenv("MIKASA_DISABLE_REWARD_OVERLAY", "0")
    raw, out = _render_pair(mw.RenderRewardInfoWrapper, FakeVLAEnv(num_envs=1))
    assert _changed(raw, out)


def test_reward_overlay_before_first_step_shows_zero():
    env = FakeVLAEnv(num_envs=1)
    w = mw.RenderRewardInfoWrapper(env)
    w.reset()
    zero_frame = w.render()
    w.step(torch.zeros(1, 7))
    env.reward_value = torch.zeros(1)
    w.step(torch.zeros(1, 7))
    assert np.array_equal(zero_frame, w.render())  # "Reward: 0.000" both times


def test_remember_color_overlay_draws_target_swatch():
    env = FakeVLAEnv(num_envs=2)
    env.oracle_info = torch.tensor([2, 0], dtype=torch.uint8)
    env.color_dict = {
        0: np.array([1.0, 0, 0, 1]),
        1: np.array([0, 1.0, 0, 1]),
        2: np.array([0, 0, 1.0, 1]),
    }
    raw, out = _render_pair(mw.RememberColorInfoWrapper, env)
    w_txt, _ = ov.text_size("Target:", 1.0, 2)
    cx, cy = 10 + w_txt + 10 + 11, 38 + 11
    assert out[0, cy, cx].tolist() == [0, 0, 255]
    assert out[1, cy, cx].tolist() == [255, 0, 0]
    assert out[0, 38, cx].tolist() == [255, 255, 255]  # white border
    env.oracle_info = torch.tensor([7, 7], dtype=torch.uint8)  # unknown colour -> white
    _, out = _render_pair(mw.RememberColorInfoWrapper, env)
    assert out[0, cy, cx].tolist() == [255, 255, 255]


def test_remember_shape_and_shell_game_overlays():
    env = FakeVLAEnv(num_envs=1)
    raw, out = _render_pair(mw.RememberShapeInfoWrapper, env)
    assert _changed(raw, out, 0, ((35, 70), (0, 400)))
    env.oracle_info = None
    raw, out = _render_pair(mw.RememberShapeInfoWrapper, env)
    assert not _changed(raw, out)  # nothing to show
    raw, out = _render_pair(mw.ShellGameRenderCupInfoWrapper, env)
    assert _changed(raw, out)  # "Target: N/A"
    env.oracle_info = torch.tensor([1], dtype=torch.uint8)
    _, center = _render_pair(mw.ShellGameRenderCupInfoWrapper, env)
    env.oracle_info = torch.tensor([2], dtype=torch.uint8)
    _, right = _render_pair(mw.ShellGameRenderCupInfoWrapper, env)
    assert not np.array_equal(center, right)


def test_remember_shape_and_color_overlay_uses_palette():
    env = FakeVLAEnv(num_envs=1)
    env.oracle_info = torch.tensor([[1, 2]], dtype=torch.uint8)
    env.COLOR_PALETTE = {0: [1.0, 0, 0, 1], 1: [0, 1.0, 0, 1], 2: [0, 0, 1.0, 1]}
    env.BASE_SHAPES = {0: "cube", 1: "sphere"}
    raw, out = _render_pair(mw.RememberShapeAndColorInfoWrapper, env)
    w_txt, _ = ov.text_size("Target:", 1.0, 2)
    x = 10 + w_txt + 10
    assert out[0, 49, x + 11].tolist() == [0, 0, 255]
    assert _changed(raw, out, 0, ((35, 70), (x + 34, 640)))  # shape name


def test_rotate_overlay_draws_both_angles():
    env = FakeVLAEnv(num_envs=1)
    env.task_cue = torch.tensor([0.5], dtype=torch.float16)
    env.info_extra = {"relative_angle": torch.tensor([0.1])}
    raw, out = _render_pair(mw.RotateRenderAngleInfoWrapper, env)
    assert _changed(raw, out, 0, ((35, 70), (0, 400)))
    assert _changed(raw, out, 0, ((95, 130), (0, 400)))
    env.task_cue = None
    env.info_extra = {}
    raw, out = _render_pair(mw.RotateRenderAngleInfoWrapper, env)
    assert not _changed(raw, out)


def test_memory_capacity_overlay_marks_touched():
    env = FakeVLAEnv(num_envs=1)
    env.oracle_info = torch.tensor([[0, 4]], dtype=torch.uint8)
    env.touched_cubes = torch.tensor(
        [[False, False, False, False, True, False, False, False, False]]
    )
    raw, out = _render_pair(mw.MemoryCapacityInfoWrapper, env)
    x = 10 + ov.text_size("Target: ", 1.0, 2)[0]
    assert out[0, 52, x + 7].tolist() == [255, 0, 0]  # colour 0 fill
    assert out[0, 45, x + 7].tolist() == [0, 0, 0]  # not touched: black outline
    assert out[0, 52, x + 25 + 7].tolist() == [255, 0, 255]  # colour 4 fill
    assert out[0, 45, x + 25 + 7].tolist() == [255, 255, 255]  # touched: white outline


def test_batteries_and_press_overlays_need_their_values():
    env = FakeVLAEnv(num_envs=1)
    raw, out = _render_pair(mw.RenderWorkingBatteriesInfoWrapper, env)
    assert not _changed(raw, out)
    env.info_extra = {
        "found_working_count": torch.tensor([1]),
        "target_working_count": torch.tensor([2]),
    }
    raw, out = _render_pair(mw.RenderWorkingBatteriesInfoWrapper, env)
    assert _changed(raw, out, 0, ((125, 160), (0, 400)))
    raw, out = _render_pair(mw.RenderPressProgressInfoWrapper, env)
    assert not _changed(raw, out)
    env.info_extra = {
        "raw_press_count": torch.tensor([2]),
        "press_count": torch.tensor([1]),
        "target_blinks": torch.tensor([3]),
    }
    raw, out = _render_pair(mw.RenderPressProgressInfoWrapper, env)
    assert _changed(raw, out, 0, ((95, 130), (0, 400)))


def test_timed_transfer_overlay_draws_near_right_edge():
    env = FakeVLAEnv(num_envs=1)
    raw, out = _render_pair(mw.RenderTimedTransferInfoWrapper, env)
    assert not _changed(raw, out)
    env.signal_step = torch.tensor([2])
    env.window_start = torch.tensor([97])
    env.window_end = torch.tensor([107])
    env.DELAY_STEPS = 100
    env.info_extra = {"cube_on_red": torch.tensor([False])}
    raw, out = _render_pair(mw.RenderTimedTransferInfoWrapper, env)
    width = RENDER_HW[1]
    assert _changed(raw, out, 0, ((0, 160), (width - 262, width)))
    assert not _changed(raw, out, 0, ((0, RENDER_HW[0]), (0, width - 265)))


def test_trace_shape_overlay_draws_minimap():
    env = FakeVLAEnv(num_envs=1)
    raw, out = _render_pair(mw.RenderTraceShapeDebugWrapper, env)
    assert not _changed(raw, out)
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    env.waypoints = torch.tensor(
        np.stack([0.1 * np.cos(t), 0.1 * np.sin(t)], -1)[None], dtype=torch.float32
    )
    env.checkpoints = env.waypoints[:, ::5][:, :12]
    env.checkpoint_visited = torch.zeros(1, 12, dtype=torch.bool)
    env.checkpoint_visited[0, :3] = True
    env.shape_type = torch.tensor([0])
    env.info_extra = {
        "action_mask": torch.tensor([True]),
        "is_contour_closed": torch.tensor([False]),
    }
    raw, out = _render_pair(mw.RenderTraceShapeDebugWrapper, env, steps=2)
    assert _changed(raw, out, 0, ((130, 290), (10, 170)))
    assert _changed(raw, out, 0, ((290, 360), (10, 200)))  # status text
    assert not _changed(raw, out, 0, ((0, 125), (0, 640)))


def test_debug_reward_overlay_lists_terms():
    env = FakeVLAEnv(num_envs=1)
    raw, out = _render_pair(mw.DebugRewardWrapper, env)
    assert not _changed(raw, out)
    env.info_extra = {"reward_dict": {"a": torch.tensor([0.5]), "b": torch.tensor([1.0])}}
    raw, out = _render_pair(mw.DebugRewardWrapper, env)
    assert _changed(raw, out, 0, ((155, 200), (0, 200)))


def test_overlay_frame_conversion_float_and_unbatched():
    env = FakeVLAEnv(num_envs=1, render_dtype="float")
    w = mw.RenderStepInfoWrapper(env)
    w.reset()
    out = w.render()
    assert out.dtype == np.uint8 and out.flags.c_contiguous
    assert out[0, 400, 400].tolist() == [100, 100, 100]
    frame = np.full((64, 64, 3), 7, np.uint8)
    arr, batched = ov.frames_to_uint8(frame)
    assert arr.shape == (1, 64, 64, 3) and not batched
    arr[0, 0, 0] = 0
    assert frame[0, 0, 0] == 7  # never draws into the caller's buffer


# ----------------------------------------------------------------------------------------
# real ManiSkill envs (CPU sim)
# ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def push_cube_env():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("mani_skill.envs")
    env = gym.make(
        "PushCube-v1",
        robot_uids="panda_wristcam",
        obs_mode="rgb",
        sensor_configs=dict(width=128, height=128),
        control_mode="pd_ee_delta_pose",
        sim_backend="cpu",
        render_mode="rgb_array",
        max_episode_steps=40,
    )
    yield env
    env.close()


def test_real_env_chain_proprio_and_spaces(push_cube_env):
    env = push_cube_env
    calls = []
    base_reset = env.unwrapped.reset
    env.unwrapped.reset = lambda *a, **k: calls.append(1) or base_reset(*a, **k)
    try:
        wrapped = _apply_config(env, mw.VLAWrapperConfig())
        assert calls == []  # constructing the chain does not reset the env
    finally:
        del env.unwrapped.reset
    assert wrapped.max_episode_steps == 40
    space = wrapped.observation_space
    assert list(space.keys()) == ["proprio", "rgb"]
    assert space["proprio"] == spaces.Box(-np.inf, np.inf, (1, 7), np.float32)
    assert space["rgb"] == spaces.Box(0, 255, (1, 128, 128, 6), np.uint8)
    obs, _ = wrapped.reset(seed=1)
    obs, *_ = wrapped.step(torch.zeros(1, 7))
    assert list(obs) == ["proprio", "rgb"]
    assert obs["proprio"].shape == (1, 7) and obs["proprio"].dtype == torch.float32
    assert obs["rgb"].shape == (1, 128, 128, 6) and obs["rgb"].dtype == torch.uint8
    assert obs["rgb"].device == torch.device(env.unwrapped.device)
    agent = env.unwrapped.agent
    tcp = agent.tcp.pose.raw_pose[0].numpy().astype(np.float64)
    qpos = agent.robot.get_qpos()[0].numpy()
    p = obs["proprio"][0].numpy()
    np.testing.assert_allclose(p[:3], tcp[:3], atol=1e-6)
    diff = (p[3:6] - _ref_rpy(tcp[3:7]) + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(diff, 0, atol=1e-4)
    assert p[6] == pytest.approx(qpos[7] + qpos[8], abs=1e-6)
    assert 0.0 < p[6] <= 0.081
    assert space.contains({k: v.numpy() for k, v in obs.items()})


def test_real_env_overlays_change_rendered_pixels(push_cube_env, monkeypatch):
    monkeypatch.delenv("MIKASA_DISABLE_REWARD_OVERLAY", raising=False)
    env = push_cube_env
    wrapped = _apply_config(
        env, mw.VLAWrapperConfig(overlays=mw.STEP_REWARD), include_overlays=True
    )
    wrapped.reset(seed=2)
    wrapped.step(torch.zeros(1, 7))
    raw = env.render().numpy()
    out = wrapped.render()
    assert out.shape == raw.shape and out.dtype == np.uint8
    assert _changed(raw, out, 0, ((0, 100), (0, 300)))
    assert not _changed(raw, out, 0, ((150, 512), (0, 512)))


def test_real_env_without_wrist_camera():
    gym = pytest.importorskip("gymnasium")
    env = gym.make(
        "PickCube-v1",
        robot_uids="panda",
        obs_mode="rgb",
        sensor_configs=dict(width=128, height=128),
        control_mode="pd_ee_delta_pose",
        sim_backend="cpu",
    )
    try:
        wrapped = _apply_config(env, mw.VLAWrapperConfig())
        assert wrapped.max_episode_steps == 50  # registered horizon of PickCube-v1
        assert wrapped.observation_space["rgb"].shape == (1, 128, 128, 3)
        obs, _ = wrapped.reset(seed=0)
        assert obs["rgb"].shape == (1, 128, 128, 3)
        assert obs["proprio"].shape == (1, 7)
    finally:
        env.close()


# ----------------------------------------------------------------------------------------
# a real MIKASA task (skipped until mikasa_envs registers it)
# ----------------------------------------------------------------------------------------


def test_real_mikasa_task_curriculum_freezes_robot():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("mikasa_envs")
    if "RememberColor3-VLA-v0" not in gym.registry:
        pytest.skip("RememberColor3-VLA-v0 is not registered yet")
    env = gym.make(
        "RememberColor3-VLA-v0",
        obs_mode="rgb",
        control_mode="pd_ee_delta_pose",
        sim_backend="cpu",
        max_episode_steps=12,
    )
    try:
        wrapped = mw.apply_mikasa_vla_wrappers(env)
        assert wrapped.max_episode_steps == 12
        assert mw.CurriculumPhaseNoopActionWrapper in _chain(wrapped)
        obs, info = wrapped.reset(seed=3)
        assert list(obs) == ["proprio", "rgb"]  # no task_cue (None), no oracle_info
        assert info["oracle_info"].shape == (1,)
        base = env.unwrapped
        frozen = int(base.cue_steps_per_env[0] + base.empty_steps_per_env[0])
        start = obs["proprio"][0].clone()
        assert start[6].item() == pytest.approx(0.08, abs=2e-3)
        # Sent actions push +x and open the gripper; while frozen the env receives zeros:
        # the arm holds and the fingers close toward 0.015 each.
        action = torch.tensor([[1.0, 0, 0, 0, 0, 0, 1.0]])
        for _ in range(frozen):
            obs, *_ = wrapped.step(action)
        held = obs["proprio"][0]
        assert torch.allclose(held[:3], start[:3], atol=5e-3)
        assert held[6].item() < 0.07
        obs, *_ = wrapped.step(action)  # first action that reaches the robot
        assert obs["proprio"][0, 0].item() > held[0].item() + 0.01
        assert obs["proprio"][0, 6].item() > held[6].item()
    finally:
        env.close()
