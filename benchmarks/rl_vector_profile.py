"""Where a batched step of the RL vector env spends its time, per observation mode.

``CpuVectorEnv`` (``legacy/rl``) steps ``--num-envs`` CPU sub-envs in ``--workers`` processes:
each worker steps its sub-envs one after another (simulation, the cameras in rgb modes, the
wrappers), converts the results to numpy, and pickles them through a queue; the trainer
process unpickles every worker's results and stacks them into batched tensors. This script
times each piece separately and the whole multi-process step, and prints per batched step:

* ``sub-env step``: one sub-env's ``step`` (in this process), and ``worker compute``: that
  times the sub-envs one worker holds, the floor of a batched step while the workers run in
  parallel (one core each);
* ``to numpy`` / ``pickle`` / ``unpickle``: one worker's results, as a worker converts and
  sends them and the trainer receives them, with their size;
* ``stack``: the trainer turning every sub-env's pieces into batched tensors;
* ``measured``: the whole ``CpuVectorEnv.step`` with ``--workers`` processes, and what of it
  none of the pieces explains (queues, scheduling, workers waiting for cores).

    python benchmarks/rl_vector_profile.py                                # state and rgb_joints, 2 workers
    python benchmarks/rl_vector_profile.py --workers 16 --num-envs 128 --json results/rl_profile.json

Needs the RL release (``pip install -e legacy/rl``).
"""

from __future__ import annotations

import argparse
import os
import pickle
import time
from typing import Any

import numpy as np
import torch
from ppo_throughput import random_actions, write_figures  # this directory's PPO throughput script

MODES = ("state", "rgb", "rgb_joints")


def _median_s(fn: Any, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def profile_mode(env_id: str, mode: str, num_envs: int, workers: int, steps: int) -> dict[str, Any]:
    """The figures of one observation mode (module docstring), in milliseconds and MB."""
    from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec, _stack, _to_numpy

    spec = SubEnvSpec(env_id, mode)
    per_worker = -(-num_envs // workers)  # the busiest worker's sub-envs

    # One sub-env in this process: its step, and the conversion and transport of a worker's results.
    env = spec.make()
    try:
        env.reset(seed=0)
        action = torch.as_tensor(random_actions(env.single_action_space, 1))

        def one_step() -> tuple:
            out = env.step(action)
            if bool((out[2] | out[3]).any()):
                env.reset()
            return out

        one_step()
        step_s = _median_s(one_step, steps)
        result = one_step()
        piece = (result[0], result[1], result[2], result[3], {})
        to_numpy_s = _median_s(lambda: _to_numpy(piece), steps)
        # Separate copies: pickle writes an object it has seen before as a reference.
        worker_results = [_to_numpy(piece) for _ in range(per_worker)]
        blob = pickle.dumps(("done", 0, worker_results), protocol=pickle.HIGHEST_PROTOCOL)
        pickle_s = _median_s(lambda: pickle.dumps(("done", 0, worker_results), protocol=pickle.HIGHEST_PROTOCOL), steps)
        unpickle_s = _median_s(lambda: pickle.loads(blob), steps)
        everyone = [_to_numpy(piece) for _ in range(num_envs)]
        stack_s = _median_s(lambda: _stack([r[0] for r in everyone], torch.device("cpu")), steps)
    finally:
        env.close()

    # The whole batched step with worker processes.
    with CpuVectorEnv(spec, num_envs, workers=workers) as venv:
        venv.reset(seed=0)
        actions = random_actions(venv.single_action_space, num_envs)
        venv.step(actions)
        measured_s = _median_s(lambda: venv.step(actions), steps)

    ms = 1000.0
    worker_compute = per_worker * (step_s + to_numpy_s) + pickle_s
    trainer = workers * unpickle_s + stack_s
    return {
        "mode": mode,
        "num_envs": num_envs,
        "workers": workers,
        "sub_env_step_ms": step_s * ms,
        "worker_compute_ms": worker_compute * ms,
        "to_numpy_ms_per_worker": per_worker * to_numpy_s * ms,
        "pickle_ms_per_worker": pickle_s * ms,
        "unpickle_ms_all_workers": workers * unpickle_s * ms,
        "stack_ms": stack_s * ms,
        "mb_per_worker": len(blob) / 2**20,
        "measured_ms": measured_s * ms,
        "unexplained_ms": (measured_s - worker_compute - trainer) * ms,
        "env_steps_per_s": num_envs / measured_s,
        "bound": "the workers' simulation" if worker_compute >= trainer else "the trainer process",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="RememberColor3-v0")
    parser.add_argument("--modes", default="state,rgb_joints", help=f"comma-separated, of {', '.join(MODES)}")
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="env worker processes")
    parser.add_argument("--num-envs", type=int, default=None, help="default: 8 per worker")
    parser.add_argument("--steps", type=int, default=30, help="repeats of each timing (the median counts)")
    parser.add_argument("--json", default=None, help="also write the figures here")
    args = parser.parse_args()
    modes = args.modes.split(",")
    for mode in modes:
        if mode not in MODES:
            parser.error(f"unknown mode {mode!r}; accepted values: {', '.join(MODES)}")
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    num_envs = args.num_envs or 8 * args.workers

    rows = [profile_mode(args.env_id, mode, num_envs, args.workers, args.steps) for mode in modes]
    print(f"{args.env_id}, {num_envs} envs in {args.workers} workers, {os.cpu_count()} CPU cores; "
          "milliseconds per batched step")
    print("| mode | sub-env step | worker compute | to numpy | pickle | unpickle (all) | stack | MB per worker "
          "| measured | unexplained | env steps/s | bound |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['mode']} | {r['sub_env_step_ms']:.2f} | {r['worker_compute_ms']:.1f} | "
              f"{r['to_numpy_ms_per_worker']:.2f} | {r['pickle_ms_per_worker']:.2f} | {r['unpickle_ms_all_workers']:.2f} "
              f"| {r['stack_ms']:.2f} | {r['mb_per_worker']:.2f} | {r['measured_ms']:.1f} | {r['unexplained_ms']:.1f} "
              f"| {r['env_steps_per_s']:.0f} | {r['bound']} |")
    if args.json:
        write_figures(args.json, args.env_id, rows)


if __name__ == "__main__":
    main()
