"""Tests of the canonical VLA chain of mikasa-wrappers (configuration table, errors, the
whole chain).

Most tests use the fake env of ``wrappers_fakes``; a few run ManiSkill's own PushCube-v1 /
PickCube-v1 (CPU sim, rgb mode) through the chain. PushCube is used for proprio values
because, like the MIKASA tasks, its rgb-mode ``extra`` holds only ``tcp_pose``. The single
wrappers are tested in ``test_obs_action_wrappers.py``, the overlays in ``test_overlays.py``.
"""

from __future__ import annotations

import mikasa_wrappers as mw
import numpy as np
import pytest
import torch
from gymnasium import spaces
from mikasa_wrappers import overlays as ov
from mikasa_wrappers.apply_wrappers import _apply_config
from wrappers_fakes import CAM, FakeVLAEnv, _changed, _ref_rpy

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
        "color_memory",
        "shape_memory",
        "shape_color_memory",
        "shell_game",
        "intercept",
        "rotate",
        "memory_capacity",
        "batteries_checker",
        "blink_count",
        "trace_shape",
        "timed_transfer",
        "step_reward",
        "none",
    }
    for name, chain in mw.OVERLAY_CHAINS.items():
        assert chain == (getattr(mw, name.upper()) if name != "none" else ()), name


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
    assert not any(issubclass(c, ov.RenderOverlayWrapper) for c in _chain(wrapped))


def test_chain_without_wrist_camera_has_three_channels():
    env = FakeVLAEnv(num_envs=2, cameras=("base_camera",))
    wrapped = mw.apply_mikasa_vla_wrappers(env)
    assert wrapped.observation_space["rgb"].shape == (2, CAM, CAM, 3)
    obs, _ = wrapped.reset()
    assert obs["rgb"].shape == (2, CAM, CAM, 3)


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
