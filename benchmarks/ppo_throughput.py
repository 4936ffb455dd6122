"""PPO training throughput on CPU-simulated envs: env steps/s and where the time goes.

For each observation mode: (1) the batched CPU env alone (``CpuVectorEnv``, random
actions): env steps/s of simulation (+ rendering in rgb modes) and the transport between
processes; (2) the PPO-MLP trainer (``legacy/rl/baselines/ppo/ppo_memtasks.py``) for a few
iterations: its SPS and the share of each iteration spent rolling out (simulation,
rendering, policy inference) and updating the networks.

    python benchmarks/ppo_throughput.py                                   # state and rgb_joints
    python benchmarks/ppo_throughput.py --num-envs 64 --workers 16 --modes state
    python benchmarks/ppo_throughput.py --json results/ppo_throughput.json

Prints a table; ``--json`` writes the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TRAINER = ROOT / "legacy/rl/baselines/ppo/ppo_memtasks.py"
MODE_FLAGS = {
    "state": ["--include-state"],
    "rgb": ["--include-rgb"],
    "rgb_joints": ["--include-rgb", "--include-joints"],
}


def random_actions(space: Any, n: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """``n`` actions drawn uniformly from a Box ``space``, float32 ``(n, *shape)``."""
    low, high = np.asarray(space.low, np.float32), np.asarray(space.high, np.float32)
    rng = np.random.default_rng() if rng is None else rng
    return (low + (high - low) * rng.random((n, *low.shape))).astype(np.float32)


def env_only(env_id: str, mode: str, num_envs: int, workers: int, steps: int, options: dict) -> dict:
    """Steps/s of the batched env alone with random actions (after one warm-up step);
    ``options``: ``CpuVectorEnv``'s ``shared_memory`` / ``render_together``."""
    from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec

    t0 = time.perf_counter()
    with CpuVectorEnv(SubEnvSpec(env_id, mode), num_envs, workers=workers, **options) as env:
        startup = time.perf_counter() - t0
        env.reset(seed=0)
        env.step(random_actions(env.single_action_space, num_envs))
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(random_actions(env.single_action_space, num_envs))
        wall = time.perf_counter() - t0
    return dict(env_steps_per_s=num_envs * steps / wall, startup_s=startup)


def trainer(env_id: str, mode: str, num_envs: int, workers: int, iterations: int, num_steps: int,
            options: dict) -> dict:
    """Run the trainer for ``iterations`` and read its per-iteration figures."""
    cmd = [sys.executable, str(TRAINER), "--env-id", env_id, *MODE_FLAGS[mode], "--num-envs", str(num_envs),
           "--num-steps", str(num_steps), "--total-timesteps", str(iterations * num_envs * num_steps),
           "--num-minibatches", "8", "--num-eval-envs", "1", "--num-eval-steps", "1", "--eval-freq", "1000000",
           "--num-workers", str(workers), "--no-capture-video", "--no-save-model",
           *[f"--env-{key.replace('_', '-')}" for key, on in options.items() if on]]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=os.environ.get("TMPDIR", "/tmp"))
    if out.returncode != 0:
        raise RuntimeError(f"trainer failed:\n{out.stderr[-3000:]}")
    rows = re.findall(r"SPS (\d+), rollout ([\d.]+) s, update ([\d.]+) s", out.stdout)
    last = rows[1:] or rows  # the first iteration includes start-up
    rollout = sum(float(r[1]) for r in last)
    update = sum(float(r[2]) for r in last)
    return dict(
        sps=int(rows[-1][0]),
        steady_sps=num_envs * num_steps * len(last) / (rollout + update),
        rollout_share=rollout / (rollout + update),
        update_share=update / (rollout + update),
    )


def write_figures(path: str, env_id: str, rows: list[dict]) -> None:
    """``rows`` with the env id and this machine's CPU count as JSON at ``path`` (written to a
    temporary file, then renamed)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(dict(env_id=env_id, cpu_count=os.cpu_count(), rows=rows), indent=2))
    tmp.replace(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="RememberColor3-v0")
    parser.add_argument("--modes", default="state,rgb_joints", help=f"comma-separated, of {', '.join(MODE_FLAGS)}")
    parser.add_argument("--num-envs", type=int, default=None, help="default: 8 per worker")
    parser.add_argument("--workers", type=int, default=os.cpu_count(), help="env worker processes")
    parser.add_argument("--env-steps", type=int, default=60, help="batched steps timed for the env alone")
    parser.add_argument("--iterations", type=int, default=3, help="trainer iterations (the first is not counted)")
    parser.add_argument("--num-steps", type=int, default=60, help="trainer rollout length")
    parser.add_argument("--shared-memory", action="store_true",
                        help="env workers write observations into shared memory (CpuVectorEnv's shared_memory)")
    parser.add_argument("--render-together", action="store_true",
                        help="each env worker renders its envs in one GPU pass (CpuVectorEnv's render_together)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    options = dict(shared_memory=args.shared_memory, render_together=args.render_together)
    modes = args.modes.split(",")
    for mode in modes:
        if mode not in MODE_FLAGS:
            parser.error(f"unknown mode {mode!r}; accepted values: {', '.join(MODE_FLAGS)}")
    num_envs = args.num_envs or 8 * args.workers

    rows = []
    for mode in modes:
        alone = env_only(args.env_id, mode, num_envs, args.workers, args.env_steps, options)
        train = trainer(args.env_id, mode, num_envs, args.workers, args.iterations, args.num_steps, options)
        rows.append(dict(mode=mode, num_envs=num_envs, workers=args.workers, **options, **alone, **train))
        print(f"{mode:11s} envs {num_envs:4d} workers {args.workers:3d} | env alone {alone['env_steps_per_s']:7.0f} st/s "
              f"| training {train['steady_sps']:7.0f} st/s (rollout {100 * train['rollout_share']:.0f} %, "
              f"update {100 * train['update_share']:.0f} %)", flush=True)
    if args.json:
        write_figures(args.json, args.env_id, rows)


if __name__ == "__main__":
    main()
