"""Shared fakes and builders of the mikasa-bench tests that need no simulator
(``test_bench.py``, ``test_bench_results.py``): the spec's key lists, a fake env, a
chunking policy, and builders of tasks, task results, result dirs and run stores."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from mikasa_bench.policies import PolicySpec
from mikasa_bench.protocol import BenchmarkConfig
from mikasa_bench.protocol.tasks import BenchmarkTask
from mikasa_bench.results.store import RunStore
from mikasa_bench.results.summary import (
    build_summary,
    build_task_result,
    write_benchmark_results,
)
from mikasa_bench.runners.episode import EpisodeResult

SPEC_TASK_KEYS = [
    "env_id",
    "split",
    "memory_type",
    "start_seed",
    "n_episodes",
    "successes",
    "returns",
    "sr",
    "mean_return",
    "benchmark_commit",
    "control_mode",
    "obs_mode",
    "wrapper_chain",
    "action_chunk_size",
    "model",
    "episode_lengths",
    "episode_seeds",
]
SPEC_SUMMARY_KEYS = [
    "split",
    "sr_split",
    "sr_per_memory_type",
    "tasks",
    "per_task_sr",
    "per_task_mean_return",
]


# --------------------------------------------------------------------------------------
# fakes
# --------------------------------------------------------------------------------------


class FakeEnv(gym.Env):
    """A batched (num_envs=1) torch env: obs carries the step count; success only at
    ``success_step``; truncates after ``horizon`` steps. Records every executed action."""

    def __init__(self, horizon: int = 3, success_step: int | None = None) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (7,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1, 1), np.float32)
        self.max_episode_steps = horizon
        self.success_step = success_step
        self.device = torch.device("cpu")
        self.actions: list[torch.Tensor] = []
        self.resets: list[int] = []
        self.t = 0

    def reset(self, *, seed=None, options=None):
        self.resets.append(seed)
        self.t = 0
        return {"t": torch.zeros(1, 1)}, {}

    def step(self, action):
        assert action.shape == (1, 7) and action.dtype == torch.float32
        self.actions.append(action.clone())
        self.t += 1
        success = torch.tensor([self.t == self.success_step])
        done = torch.tensor([self.t >= self.max_episode_steps])
        return (
            {"t": torch.full((1, 1), self.t)},
            torch.tensor([0.5]),
            torch.tensor([False]),
            done,
            {"success": success},
        )


class CountingChunkPolicy:
    """Returns chunks of 5 actions whose first entry is the chunk number (1, 2, ...)."""

    chunk_size = 5

    def __init__(self) -> None:
        self.calls = 0
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def forward(self, obs):
        self.calls += 1
        chunk = torch.zeros(self.chunk_size, 7)
        chunk[:, 0] = self.calls
        chunk[:, 1] = torch.arange(self.chunk_size)
        return chunk


def _task(env_id="RememberColor3-VLA-v0", split="short", memory="Object"):
    return BenchmarkTask(env_id, split, memory, 25, "", "PPO")


def _result(task, successes, *, returns=None, lengths=None, start_seed=100, label="p"):
    n = len(successes)
    config = BenchmarkConfig(start_seed=start_seed, n_episodes=n, sim_backend="cpu")
    returns = returns or [float(i) for i in range(n)]
    lengths = lengths or [25] * n
    eps = [
        EpisodeResult(s, r, ln, start_seed + i)
        for i, (s, r, ln) in enumerate(zip(successes, returns, lengths, strict=False))
    ]
    return build_task_result(task, config, eps, model={"name": label, "config": {}})


def _write_run(path: Path, results, label="p"):
    summary = build_summary(results, model={"name": label, "config": {}})
    write_benchmark_results(path, results, summary)
    return path


def _store(tmp_path, n=3, tasks=None, policy="zero"):
    tasks = tasks or [_task(), _task("FindImposterColor3-VLA-v0", memory="Negative")]
    config = BenchmarkConfig(n_episodes=n, start_seed=1000, obs_mode="state", sim_backend="cpu")
    return RunStore.create(
        tmp_path / "run",
        tasks=tasks,
        policy=PolicySpec(policy, label=policy),
        config=config,
        selection={"env_ids": [t.env_id for t in tasks]},
        commit=None,
    )
