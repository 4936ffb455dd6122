"""Same seed, same episode as the reference: the seed-0 reset of every task the reference
could run on CPU (83 of the 90) is reproduced (``tests/data/reset_parity_seed0.json``, copied
from the specification by ``benchmarks/reset_parity.py --export-test-data``).

Default run: proprio (TCP pose, gripper opening: the robot's noisy start pose) within 1e-3
and the same instruction, in state mode. Slow run: the rendered frames of the canonical VLA
chain against the reference's (lavapipe): top camera within 6/255 mean abs error, and the
wrist camera (2x2-averaged) within 1/255, which catches a misplaced object the top camera's
6/255 lets through (TraceShapeSeq, whose button stands elsewhere on purpose, is held to
6/255 there too). Lamp tasks used a stand-in bulb in the reference: a few pixels differ.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from mikasa_wrappers import apply_mikasa_vla_state_wrappers, apply_mikasa_vla_wrappers

DATA = Path(__file__).parent / "data"
REFERENCE = json.loads((DATA / "reset_parity_seed0.json").read_text())["envs"]
FRAMES = DATA / "reset_parity_frames"
ENV_IDS = sorted(REFERENCE)
PROPRIO_TOL = 1e-3
TOP_MAE_TOL = 6.0  # mean abs error, 0-255 scale
# On 2x2-averaged 64x64 images. Measured ≤ 0.4 here (the stored averages are rounded; stand-in
# bulbs); a misplaced shape or 5 mm of cube jitter from a wrong draw order gave 1.3-1.8.
WRIST_MAE_TOL = 1.0
# Tasks with an object moved on purpose (packages/mikasa-envs/DEVIATIONS.md): the wrist camera
# sees it elsewhere; these are held to the top camera's bound there too (measured: TraceShape
# 1.66, TraceShapeSeq 4.44). The prefix covers both trace families.
MOVED_BY_DESIGN = {
    "TraceShape": "green cube, lamp and TraceShapeSeq's submit button at fixed spots, DEVIATIONS.md Fixed #26, #27",
}


def proprio_diff(ours: np.ndarray, ref: list[float]) -> np.ndarray:
    """Per-value abs difference of two 7-value proprio vectors, roll and yaw modulo 2π."""
    diff = np.abs(np.asarray(ours, np.float64) - np.asarray(ref, np.float64))
    for col in (3, 5):
        d = diff[col] % (2 * math.pi)
        diff[col] = min(d, 2 * math.pi - d)
    return diff


def pool2(image: np.ndarray) -> np.ndarray:
    """(H, W, C) image averaged over 2x2 blocks."""
    h, w, c = image.shape
    return image.reshape(h // 2, 2, w // 2, 2, c).astype(np.float64).mean(axis=(1, 3))


def _instruction(info: dict) -> str:
    text = info["language_instruction"]
    return text[0] if isinstance(text, (list, tuple)) else text


def test_reference_copy_is_complete():
    assert len(ENV_IDS) == 83
    for ref in REFERENCE.values():
        assert (FRAMES / f"{ref['frame']}.top.png").exists()
        assert (FRAMES / f"{ref['frame']}.wrist64.png").exists()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_proprio_and_instruction_match_reference(make_env, env_id):
    ref = REFERENCE[env_id]
    env = apply_mikasa_vla_state_wrappers(make_env(env_id, obs_mode="state"))
    obs, info = env.reset(seed=ref["seed"])
    diff = proprio_diff(np.asarray(obs["proprio"][0]), ref["proprio"])
    assert diff.max() < PROPRIO_TOL, f"proprio differs by {diff.round(4).tolist()}"
    assert _instruction(info) == ref["language_instruction"]


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_reset_frames_match_reference(make_env, env_id):
    from PIL import Image

    ref = REFERENCE[env_id]
    env = apply_mikasa_vla_wrappers(make_env(env_id, obs_mode="rgb"))
    obs, _ = env.reset(seed=ref["seed"])
    rgb = np.asarray(obs["rgb"][0])
    top_ref = np.asarray(Image.open(FRAMES / f"{ref['frame']}.top.png").convert("RGB"))
    wrist_ref = np.asarray(Image.open(FRAMES / f"{ref['frame']}.wrist64.png").convert("RGB"))
    top = np.abs(rgb[..., :3].astype(np.float64) - top_ref).mean()
    wrist = np.abs(pool2(rgb[..., 3:]) - wrist_ref).mean()
    assert top < TOP_MAE_TOL, f"top camera mean abs error {top:.2f}/255"
    moved = any(env_id.startswith(prefix) for prefix in MOVED_BY_DESIGN)
    wrist_tol = TOP_MAE_TOL if moved else WRIST_MAE_TOL
    assert wrist < wrist_tol, f"wrist camera mean abs error {wrist:.2f}/255 (2x2-averaged)"


def test_blink_schedule_reproduces_the_specs_measured_example(make_env):
    # blink_count_button_press.md §4 measured N = 3, P = 8, off = 4, 4, 3 (action from e = 28) on
    # an unnamed seed; with the reference's torch order (button x, y, N, P, max_blinks "on"
    # lengths, max_blinks dark times) seeds 3 and 5 give exactly that (and no other seed < 100
    # does for most other orders tried).
    env = make_env("BlinkCountButtonPressMedium-VLA-v0")
    base = env.unwrapped
    for seed in (3, 5):
        env.reset(seed=seed)
        assert int(base.target_blinks[0]) == 3
        assert base.blink_start_steps[0, :3].tolist() == [8, 15, 22]
        assert base.blink_off_schedule[0, :3].tolist() == [4, 4, 3]
        assert int(base.cue_steps_per_env[0]) == 28


def test_rotate_target_and_heading_come_from_numpy_before_the_arm_noise(make_env):
    # The reference draws the target's u, then θ0, from the numpy episode RNG right after the
    # table builder's 9 normals; the 7 arm-noise normals follow.
    env = make_env("RotateLenientPos-VLA-v0")
    base = env.unwrapped
    _, info = env.reset(seed=0)
    rng = np.random.RandomState(0)
    rng.normal(0, 0.02, (1, 9))
    u, theta0 = rng.uniform(0, 1), rng.uniform(0, 2 * math.pi)
    assert float(base.initial_rotations[0]) == pytest.approx(theta0, abs=1e-6)
    target = 0.1 + u * (math.pi / 2 - 0.1)
    assert float(base.task_cue[0]) == pytest.approx(target, abs=1e-3)
    assert _instruction(info) == "Rotate the peg by 72 degrees to match the target angle."
    qpos = base.agent.robot.get_qpos()[0, :7].numpy()
    expected = np.array([0.0, 0.0, 0.0, -2 * np.pi / 3, 0.0, 2 * np.pi / 3, np.pi / 4]) + rng.normal(0, 0.02, 7)
    np.testing.assert_allclose(qpos, expected, atol=1e-5)


def test_only_the_shell_games_lack_a_reference_reset():
    # The 7 canonical ids the reference could not run here: the shell games need the YCB mug.
    import mikasa_envs

    canonical = [i for i in mikasa_envs.registered_env_ids() if mikasa_envs.get_task(i).canonical]
    missing = sorted(set(canonical) - set(ENV_IDS))
    assert len(missing) == 7 and all(i.startswith("ShellGame") for i in missing), missing
