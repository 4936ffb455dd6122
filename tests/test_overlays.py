"""Tests of the render overlays of mikasa-wrappers on the fake env of ``wrappers_fakes``."""

from __future__ import annotations

import mikasa_wrappers as mw
import numpy as np
import pytest
import torch
from mikasa_wrappers import overlays as ov
from wrappers_fakes import RENDER_HW, FakeVLAEnv, _changed

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
