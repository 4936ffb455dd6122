"""Env steps/s of one evaluation: one episode at a time in-process (``--workers 0``) against
B episodes in lockstep with one batched policy call per step (``--policy-batch B``).

    python benchmarks/policy_batch_throughput.py --policy lerobot:DIR [--task ID]
        [--episodes 20] [--batches 5,10] [--envs-per-worker K] [--obs-mode rgb]

Each setting is a fresh ``mikasa-bench run`` (a subprocess, so start-up is included as a
user sees it) over the same episodes; the script prints wall time, env steps and env
steps/s per setting, and writes them as JSON with ``--json PATH``. Without ``--policy`` it
times `SleepyBatchPolicy` below: a stand-in for a GPU policy whose call costs
``--policy-ms`` whatever the batch size (what makes batching pay). Where a GPU policy is
at hand (``lerobot:DIR``), pass it; LeRobot policies need the lerobot environment
(``.venv-datasets/bin/python`` here).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()


class SleepyBatchPolicy:
    """Zero actions after a fixed delay per call, one action or a batch alike."""

    def __init__(self, delay_ms: float = 20.0) -> None:
        self.delay_s = float(delay_ms) / 1000.0

    def forward(self, obs):
        time.sleep(self.delay_s)
        return np.zeros(7, dtype=np.float32)

    def forward_batch(self, observations):
        time.sleep(self.delay_s)
        return np.zeros((len(observations), 7), dtype=np.float32)


def _run(args: argparse.Namespace, out: Path, spread: list[str]) -> dict:
    """One ``mikasa-bench run``; its wall time and env steps."""
    policy = args.policy or f"{HERE}:SleepyBatchPolicy"
    argv = [sys.executable, "-m", "mikasa_bench", "run", "--task", args.task, "--policy", policy]
    argv += ["--num-episodes", str(args.episodes), "--obs-mode", args.obs_mode, "--out", str(out)]
    argv += ["--no-progress", "--no-report", *spread]
    if args.policy is None:
        argv += ["--policy-kwargs", json.dumps({"delay_ms": args.policy_ms})]
    elif args.policy_kwargs:
        argv += ["--policy-kwargs", args.policy_kwargs]
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, env={**os.environ})
    wall = time.perf_counter() - t0
    steps = sum(json.loads((out / f"{args.task}.json").read_text())["episode_lengths"])
    return {"setting": " ".join(spread), "wall_s": round(wall, 2), "env_steps": steps,
            "env_steps_per_s": round(steps / wall, 1)}  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--policy", default=None, help="a bench policy with forward_batch (default: the stand-in)"
    )
    p.add_argument("--policy-kwargs", default=None, help='JSON, e.g. \'{"device": "cuda"}\'')
    p.add_argument("--policy-ms", type=float, default=20.0, help="the stand-in's delay per call")
    p.add_argument("--task", default="RememberColor3-VLA-v0")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--batches", default="5,10", help="comma-separated B values")
    p.add_argument("--envs-per-worker", type=int, default=None)
    p.add_argument("--obs-mode", default="rgb", choices=("rgb", "state"))
    p.add_argument("--json", default=None, help="also write the figures here")
    args = p.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        settings = [["--workers", "0"]] + [
            ["--policy-batch", b] for b in args.batches.split(",") if b.strip()
        ]
        for i, spread in enumerate(settings):
            if spread[0] == "--policy-batch" and args.envs_per_worker:
                spread = [*spread, "--envs-per-worker", str(args.envs_per_worker)]
            rows.append(_run(args, Path(tmp) / f"run{i}", spread))
            r = rows[-1]
            print(f"{r['setting']:>40}: {r['env_steps']} env steps in {r['wall_s']:.1f} s = "
                  f"{r['env_steps_per_s']:.1f} env steps/s", flush=True)  # fmt: skip
    if args.json:
        Path(args.json).write_text(json.dumps({"task": args.task, "runs": rows}, indent=2))


if __name__ == "__main__":
    main()
