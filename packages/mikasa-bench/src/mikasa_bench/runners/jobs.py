"""Episode jobs and the executor interface.

The unit of work is one episode (`EpisodeJob`). An `Executor` takes a list of jobs and
yields an `EpisodeOutcome` per job in completion order; the runner puts results back in
seed order, so the numbers never depend on the executor or the worker count.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Hashable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.policies.spec import PolicySpec
from mikasa_bench.protocol import BenchmarkConfig, scene_start
from mikasa_bench.protocol.tasks import BenchmarkTask
from mikasa_bench.runners.episode import EpisodeResult

__all__ = ["EpisodeJob", "EpisodeOutcome", "Executor", "render_config"]


@dataclass(frozen=True)
class EpisodeJob:
    """One episode to run: which run it belongs to, task, episode index and seed, protocol
    settings and the policy description."""

    run_index: int
    task: BenchmarkTask
    episode: int
    seed: int
    config: BenchmarkConfig
    policy: PolicySpec

    @property
    def env_key(self) -> Hashable:
        """Jobs with equal keys can share one env instance."""
        return (self.task.env_id, self.config)

    @property
    def scene_key(self) -> Hashable:
        """Jobs with equal keys play on one scene, in episode order (`protocol.scene_start`)."""
        return (self.run_index, self.env_key, scene_start(self.episode))

    def seed_of(self, episode: int) -> int:
        """The seed of episode ``episode`` of this job's task."""
        return self.seed - self.episode + episode


@dataclass
class EpisodeOutcome:
    """What a worker sends back for a job: the result, or an error description."""

    job: EpisodeJob
    result: EpisodeResult | None
    action_chunk_size: int
    wall_s: float
    worker: int
    error: str | None = None
    traceback: str | None = None
    user_error: bool = False
    video: bytes | None = None
    """The episode's mp4 (``config.save_videos``), written by the runner."""
    render: str | None = None
    """Where the worker rendered, e.g. ``"cpu: llvmpipe (LLVM 15.0.6, 256 bits)"``."""
    setup_s: float = 0.0
    """Part of ``wall_s`` spent building the env and policy and replaying the scene's earlier
    episodes (0 when nothing had to be built or replayed)."""
    cpu_s: float = 0.0
    """CPU time of the worker process (all its threads, e.g. lavapipe's) over the
    episode, env build excluded: what an episode costs, whatever else runs on the host."""
    restarts: int = 0
    """How often the episode was played again from its reset because the policy lost its
    memory of it (`EpisodeInterrupted`, e.g. a policy server's connection dropped)."""

    def describe_failure(self) -> str:
        """A message naming the task, episode, seed and policy of a failed job."""
        j = self.job
        return (
            f"policy {j.policy.label or j.policy.target!r} failed on {j.task.env_id} "
            f"episode {j.episode} (seed {j.seed}): {self.error}"
        )


class Executor(ABC):
    """Runs episode jobs and yields their outcomes in completion order.

    `run` is a generator: closing it early (the runner does so on an error or Ctrl-C)
    must stop all work promptly.
    """

    name: str = "executor"

    @abstractmethod
    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Yield one `EpisodeOutcome` per job."""

    def describe(self) -> dict[str, Any]:
        """JSON-ready description recorded with the run (never affects results)."""
        return {"name": self.name}


def render_config(jobs: Sequence[EpisodeJob]) -> BenchmarkConfig:
    """The config whose render settings every worker of a pool follows.

    A worker process can render on one device only (Vulkan is set up once per process),
    so all jobs handed to one pool must agree on ``render_device``/``gpu_render_workers``.
    """
    settings = {(j.config.render_device, j.config.gpu_render_workers) for j in jobs}
    if len(settings) > 1:
        raise BenchError(
            "the runs given to one executor use different render devices "
            f"({sorted(settings)}); run them separately"
        )
    return jobs[0].config
