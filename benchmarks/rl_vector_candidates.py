"""Candidate vector envs for the RL trainers, side by side: env steps/s of the same sub-envs.

The RL trainers step many CPU-simulated sub-envs as one batch. Three ways to spread them
over processes, each stepped with random actions and timed over ``--steps`` batched steps
after ``--warmup`` (the batch as torch tensors in the trainer, as the trainers use it):

* ``pickle-queues``: the release's ``CpuVectorEnv`` (``legacy/rl``): ``--workers``
  processes, each holding ``num_envs / workers`` sub-envs it steps one after another;
  results converted to numpy and pickled through a queue, stacked by the trainer.
* ``shared-queues``: the same with ``shared_memory=True``: the workers write observations
  into shared memory, only rewards, flags and finished episodes' final observations go
  through the queues; several sub-envs per worker, as before.
* ``shared-threads``: the same, each worker stepping its sub-envs in threads of their own
  and rendering their cameras in one GPU pass per step (``render_together=True``; with CPU
  rendering the threads only overlap what releases the GIL).
* ``gymnasium-shm``: Gymnasium's ``AsyncVectorEnv`` with ``shared_memory=True`` over
  ManiSkill's ``CPUGymWrapper``: one process per sub-env, observations written by the
  workers into shared memory (no pickling of image arrays); the trainer wraps the shared
  batch as a tensor (``copy=False``) and copies it once, to the device.
* ``gymnasium-pipes``: the same with ``shared_memory=False`` (observations pickled through
  pipes), to see what the shared memory alone is worth.

Gymnasium's design holds one sub-env per process, so its candidates always start
``--num-envs`` processes; the others start ``--workers``. Every candidate builds the
same sub-env (``SubEnvSpec.make_single``: the RL wrapper chain on the CPU sim) and resets it
with the same seeds; what differs is how the batch travels.

    python benchmarks/rl_vector_candidates.py                                  # 8 envs, state and rgb_joints
    python benchmarks/rl_vector_candidates.py --num-envs 16 --workers 16 --json results/rl_candidates.json

Needs the RL release (``pip install -e legacy/rl``).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from ppo_throughput import random_actions, write_figures  # this directory's PPO throughput script

CANDIDATES = ("pickle-queues", "shared-queues", "shared-threads", "gymnasium-shm", "gymnasium-pipes")


def make_cpu_gym_env(spec: Any, index: int) -> gym.Env:
    """Sub-env ``index`` of ``spec`` as a plain Gymnasium env (numpy, unbatched): ManiSkill's
    ``CPUGymWrapper`` over the RL chain. Top-level, so that spawned workers can unpickle it."""
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper
    from mikasa_envs.workers import quiet_worker

    quiet_worker()
    import mikasa_robo_rl  # noqa: F401  (registers the RL ids in the spawned interpreter)

    chain = spec.make_single(index)
    env = CPUGymWrapper(chain, ignore_terminations=spec.ignore_terminations, record_metrics=True)
    # CPUGymWrapper takes its spaces from the unwrapped env; the chain's observation
    # wrappers reshape the observation (and say so in their single_observation_space),
    # and Gymnasium's shared memory is laid out from the space.
    env.observation_space = chain.get_wrapper_attr("single_observation_space")
    return env


def _as_tensors(tree: Any, device: torch.device) -> Any:
    """A numpy batch (nested in dicts) as tensors on ``device``, without an extra copy on the
    CPU (``torch.from_numpy`` shares the buffer)."""
    if isinstance(tree, dict):
        return {k: _as_tensors(v, device) for k, v in tree.items()}
    return torch.from_numpy(np.asarray(tree)).to(device)


class GymnasiumBatch:
    """Gymnasium's ``AsyncVectorEnv`` over the sub-envs, stepped with torch tensors."""

    def __init__(self, spec: Any, num_envs: int, shared_memory: bool, device: torch.device) -> None:
        fns: list[Callable[[], gym.Env]] = [partial(make_cpu_gym_env, spec, i) for i in range(num_envs)]
        self.env = gym.vector.AsyncVectorEnv(
            fns,
            shared_memory=shared_memory,
            copy=False,  # the trainer copies once, into its tensors
            context="spawn",
            autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
        )
        self.device = device
        self.single_action_space = self.env.single_action_space

    def reset(self, seed: int) -> Any:
        from mikasa_robo_rl.collect import episode_seed  # the seeds CpuVectorEnv gives

        n = self.env.num_envs
        obs, _ = self.env.reset(seed=[episode_seed(seed, i, n) for i in range(n)])
        return _as_tensors(obs, self.device)

    def step(self, actions: np.ndarray) -> Any:
        obs, reward, terminated, truncated, _ = self.env.step(actions)
        return _as_tensors(obs, self.device), torch.as_tensor(reward, device=self.device)

    def close(self) -> None:
        self.env.close()


class QueuesBatch:
    """The release's ``CpuVectorEnv``."""

    def __init__(self, spec: Any, num_envs: int, workers: int, device: torch.device, shared_memory: bool,
                 render_together: bool) -> None:
        from mikasa_robo_rl.vector_env import CpuVectorEnv

        self.env = CpuVectorEnv(spec, num_envs, workers=workers, device=device, shared_memory=shared_memory,
                                render_together=render_together)
        self.single_action_space = self.env.single_action_space

    def reset(self, seed: int) -> Any:
        return self.env.reset(seed=seed)[0]

    def step(self, actions: np.ndarray) -> Any:
        obs, reward, *_ = self.env.step(actions)
        return obs, reward

    def close(self) -> None:
        self.env.close()


def measure(candidate: str, env_id: str, mode: str, num_envs: int, workers: int, steps: int, warmup: int) -> dict:
    """Env steps/s of one candidate in one observation mode, with the start-up time."""
    from mikasa_robo_rl.vector_env import SubEnvSpec

    spec, device = SubEnvSpec(env_id, mode), torch.device("cpu")
    t0 = time.perf_counter()
    if not candidate.startswith("gymnasium"):
        batch: Any = QueuesBatch(spec, num_envs, workers, device, candidate != "pickle-queues",
                                 candidate == "shared-threads")
    else:
        batch = GymnasiumBatch(spec, num_envs, candidate == "gymnasium-shm", device)
    try:
        batch.reset(seed=0)
        start_s = time.perf_counter() - t0
        rng = np.random.default_rng(0)
        for i in range(warmup + steps):
            if i == warmup:
                t0 = time.perf_counter()
            batch.step(random_actions(batch.single_action_space, num_envs, rng))
        elapsed = time.perf_counter() - t0
    finally:
        batch.close()
    processes = num_envs if candidate.startswith("gymnasium") else min(workers, num_envs)
    return {
        "candidate": candidate,
        "mode": mode,
        "num_envs": num_envs,
        "processes": processes,
        "env_steps_per_s": round(num_envs * steps / elapsed, 1),
        "batched_step_ms": round(1000 * elapsed / steps, 2),
        "start_s": round(start_s, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="RememberColor3-v0")
    parser.add_argument("--modes", default="state,rgb_joints", help="comma-separated RL observation modes")
    parser.add_argument("--candidates", default=",".join(CANDIDATES), help=f"comma-separated, of {', '.join(CANDIDATES)}")
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes of the CpuVectorEnv candidates (Gymnasium's start one per env)")
    parser.add_argument("--steps", type=int, default=100, help="timed batched steps")
    parser.add_argument("--warmup", type=int, default=10, help="untimed batched steps first")
    parser.add_argument("--json", default=None, help="also write the figures here")
    args = parser.parse_args()
    candidates = [c.strip() for c in args.candidates.split(",") if c.strip()]
    unknown = sorted(set(candidates) - set(CANDIDATES))
    if unknown:
        parser.error(f"unknown candidate(s) {unknown}; choose from {', '.join(CANDIDATES)}")
    if args.num_envs < 1 or args.workers < 1 or args.steps < 1:
        parser.error("--num-envs, --workers and --steps must be >= 1")

    rows = []
    print(f"{args.env_id}, {args.num_envs} envs, {os.cpu_count()} CPU cores")
    print(f"{'candidate':<16} {'mode':<11} {'processes':>9} {'env steps/s':>12} {'step ms':>8} {'start s':>8}")
    for mode in [m.strip() for m in args.modes.split(",") if m.strip()]:
        for candidate in candidates:
            row = measure(candidate, args.env_id, mode, args.num_envs, args.workers, args.steps, args.warmup)
            rows.append(row)
            print(f"{candidate:<16} {mode:<11} {row['processes']:>9} {row['env_steps_per_s']:>12} "
                  f"{row['batched_step_ms']:>8} {row['start_s']:>8}", flush=True)
    if args.json:
        write_figures(args.json, args.env_id, rows)


if __name__ == "__main__":
    main()
