"""Reset parity with the reference: the seed-0 reset observation, task by task.

For every task in the reference file (``reference_resets_seed0.json`` of the specification:
the reference's ``reset(seed=0)`` observation after the canonical VLA wrapper chain, without
overlays), make the env with ``obs_mode="rgb"``, wrap it with ``apply_mikasa_vla_wrappers``,
reset it with the same seed and compare:

* ``proprio``: max abs difference over the 7 values (roll and yaw modulo 2π);
* ``top`` / ``wrist``: mean abs pixel error (0-255 scale) of the top camera (columns 0-127
  of the reference PNG) and the wrist camera (columns 128-255);
* ``instr``: whether the language instruction is the same string.

A task passes when proprio < 1e-3, top < 6 and the instruction is the same (the wrist
camera is reported: it shows a misplaced object better; lamp tasks ran with a stand-in bulb
in the reference, so pixels near it differ). Exit status 1 if any task does not pass.
``--state`` skips rendering (proprio and instruction only, from the state-mode chain).

    python benchmarks/reset_parity.py                                   # all 83 tasks
    python benchmarks/reset_parity.py --env-ids TakeItBack-VLA-v0,RotateLenientPos-VLA-v0
    python benchmarks/reset_parity.py --state --json results/reset_parity.json
    python benchmarks/reset_parity.py --export-test-data   # refresh tests/data (see below)

``--export-test-data`` copies what ``tests/test_reset_parity.py`` needs from the reference
file into ``tests/data/``: ``reset_parity_seed0.json`` (per task: proprio, instruction, frame
name) and ``reset_parity_frames/`` with one pair of PNGs per distinct reference frame: the
top camera at full size (``<name>.top.png``) and the wrist camera averaged over 2x2 blocks
(``<name>.wrist64.png``, 64x64), about 1.1 MB for the 83 tasks.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_REFERENCE = REPO_ROOT / ".." / "shared" / "spec" / "parity" / "reference_resets_seed0.json"
PROPRIO_TOL = 1e-3
TOP_MAE_TOL = 6.0  # mean abs error on the 0-255 scale
ANGLE_COLUMNS = (3, 5)  # roll, yaw: compared modulo 2π


def proprio_diff(ours: np.ndarray, ref: np.ndarray) -> float:
    """Max abs difference of two 7-value proprio vectors, roll and yaw modulo 2π."""
    diff = np.abs(np.asarray(ours, np.float64) - np.asarray(ref, np.float64))
    for col in ANGLE_COLUMNS:
        d = diff[col] % (2 * math.pi)
        diff[col] = min(d, 2 * math.pi - d)
    return float(diff.max())


def frame_errors(ours: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(top, wrist) mean abs pixel error on the 0-255 scale of two (128, 256, 3) frames."""
    d = np.abs(ours.astype(np.int16) - ref.astype(np.int16))
    return float(d[:, :128].mean()), float(d[:, 128:].mean())


def instruction_of(info: dict) -> str:
    """The env's instruction (Rotate reports one string per env)."""
    text = info["language_instruction"]
    return text[0] if isinstance(text, (list, tuple)) else text


def reset_observation(env_id: str, seed: int, render: bool) -> dict:
    """proprio, instruction and (with ``render``) the (128, 256, 3) frame at reset(seed)."""
    import gymnasium as gym
    import mikasa_envs  # noqa: F401
    from mikasa_wrappers import apply_mikasa_vla_state_wrappers, apply_mikasa_vla_wrappers

    obs_mode = "rgb" if render else "state"
    env = gym.make(env_id, obs_mode=obs_mode, control_mode="pd_ee_delta_pose", sim_backend="cpu")
    try:
        wrap = apply_mikasa_vla_wrappers if render else apply_mikasa_vla_state_wrappers
        env = wrap(env)
        obs, info = env.reset(seed=seed)
        out = dict(
            proprio=np.asarray(obs["proprio"][0], dtype=np.float64),
            language_instruction=instruction_of(info),
        )
        if render:
            rgb = np.asarray(obs["rgb"][0])  # (128, 128, 6): top camera, then wrist
            out["frame"] = np.concatenate([rgb[..., :3], rgb[..., 3:]], axis=1)
        return out
    finally:
        env.close()


def compare(env_id: str, ref: dict, frames_dir: Path, render: bool) -> dict:
    """One row of the table."""
    t0 = time.perf_counter()
    ours = reset_observation(env_id, int(ref["seed"]), render)
    row = dict(
        env_id=env_id,
        proprio_max_abs=proprio_diff(ours["proprio"], ref["proprio"]),
        instruction_match=ours["language_instruction"] == ref["language_instruction"],
        proprio=ours["proprio"].round(6).tolist(),
        language_instruction=ours["language_instruction"],
    )
    if render:
        from PIL import Image

        ref_frame = np.asarray(Image.open(frames_dir / ref["frame"]).convert("RGB"))
        row["top_mae"], row["wrist_mae"] = frame_errors(ours["frame"], ref_frame)
    row["ok"] = (
        row["proprio_max_abs"] < PROPRIO_TOL
        and row["instruction_match"]
        and (not render or row["top_mae"] < TOP_MAE_TOL)
    )
    row["seconds"] = time.perf_counter() - t0
    return row


TEST_DATA_DIR = REPO_ROOT / "tests" / "data"
TEST_DATA_JSON = "reset_parity_seed0.json"
TEST_FRAMES_DIR = "reset_parity_frames"


def pool2(image: np.ndarray) -> np.ndarray:
    """(H, W, C) image averaged over 2x2 blocks, as float (H/2, W/2, C)."""
    h, w, c = image.shape
    return image.reshape(h // 2, 2, w // 2, 2, c).astype(np.float64).mean(axis=(1, 3))


def export_test_data(ref_path: Path, out_dir: Path = TEST_DATA_DIR) -> None:
    """Write the test copy of the reference (module docstring); frames deduplicated by content."""
    import hashlib

    from PIL import Image

    reference = json.loads(ref_path.read_text())
    frames_dir = out_dir / TEST_FRAMES_DIR
    frames_dir.mkdir(parents=True, exist_ok=True)
    for old in frames_dir.glob("*.png"):
        old.unlink()
    names: dict[str, str] = {}
    envs = {}
    for env_id, ref in sorted(reference["envs"].items()):
        frame = np.asarray(Image.open(ref_path.parent / ref["frame"]).convert("RGB"))
        digest = hashlib.sha1(frame.tobytes()).hexdigest()
        if digest not in names:
            names[digest] = env_id
            Image.fromarray(frame[:, :128]).save(frames_dir / f"{env_id}.top.png", optimize=True)
            wrist = np.round(pool2(frame[:, 128:])).astype(np.uint8)
            Image.fromarray(wrist).save(frames_dir / f"{env_id}.wrist64.png", optimize=True)
        envs[env_id] = dict(
            seed=int(ref["seed"]),
            proprio=ref["proprio"],
            language_instruction=ref["language_instruction"],
            frame=names[digest],
        )
    what = (
        "Copied from the specification's parity/reference_resets_seed0.json by "
        "benchmarks/reset_parity.py --export-test-data. " + reference["what"] + " Here each distinct "
        f"frame is stored once in {TEST_FRAMES_DIR}/: <frame>.top.png (top camera, 128x128) and "
        "<frame>.wrist64.png (wrist camera averaged over 2x2 blocks, rounded, 64x64)."
    )
    rows = ",\n".join(f"  {json.dumps(env_id)}: {json.dumps(row)}" for env_id, row in envs.items())
    (out_dir / TEST_DATA_JSON).write_text(f'{{\n "what": {json.dumps(what)},\n "envs": {{\n{rows}\n }}\n}}\n')
    size = sum(p.stat().st_size for p in frames_dir.glob("*.png"))
    print(f"wrote {out_dir / TEST_DATA_JSON} ({len(envs)} tasks) and {len(names)} frame pairs ({size / 1e6:.2f} MB)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("reference", nargs="?", default=str(DEFAULT_REFERENCE),
                        help="reference_resets_seed0.json (frames are read from its folder)")
    parser.add_argument("--env-ids", default=None, help="comma-separated ids (default: every id of the file)")
    parser.add_argument("--state", action="store_true", help="no rendering: proprio and instruction only")
    parser.add_argument("--json", default=None, help="write the rows to this JSON file")
    parser.add_argument("--export-test-data", action="store_true",
                        help="copy the reference into tests/data for tests/test_reset_parity.py and exit")
    args = parser.parse_args()
    if args.export_test_data:
        export_test_data(Path(args.reference).resolve())
        return

    import logging

    import torch
    from mani_skill import logger

    torch.set_num_threads(1)
    logger.setLevel(logging.ERROR)  # not the "no CUDA, render on cpu" warning per env
    ref_path = Path(args.reference).resolve()
    reference = json.loads(ref_path.read_text())["envs"]
    env_ids = args.env_ids.split(",") if args.env_ids else sorted(reference)
    render = not args.state
    rows = []
    t_start = time.perf_counter()
    header = f"{'env_id':42s} {'proprio':>9s} {'top':>6s} {'wrist':>6s} instr  ok"
    print(header)
    for env_id in env_ids:
        if env_id not in reference:
            print(f"{env_id:42s} not in the reference file", file=sys.stderr)
            continue
        row = compare(env_id, reference[env_id], ref_path.parent, render)
        rows.append(row)
        top = f"{row['top_mae']:6.2f}" if render else "     -"
        wrist = f"{row['wrist_mae']:6.2f}" if render else "     -"
        print(f"{env_id:42s} {row['proprio_max_abs']:9.2e} {top} {wrist} {'yes' if row['instruction_match'] else 'NO ':5s}"
              f" {'ok' if row['ok'] else 'FAIL'}", flush=True)
    failed = [r["env_id"] for r in rows if not r["ok"]]
    print(f"\n{len(rows) - len(failed)}/{len(rows)} match (proprio < {PROPRIO_TOL:g}"
          f"{f', top < {TOP_MAE_TOL:g}/255' if render else ''}, same instruction) "
          f"in {time.perf_counter() - t_start:.0f} s")
    if failed:
        print("not matching: " + ", ".join(failed))
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(dict(reference=str(ref_path), render=render, rows=rows), indent=2))
    if failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
