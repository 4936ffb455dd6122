"""One worker: the env it caches, the policies built for it, and how it plays a job's
episode (replaying the scene's earlier episodes where it must); what every executor runs in
its worker processes, threads or Ray actors.

Every worker renders where the run's config says (`BenchmarkConfig.render_device_for` its
index: a mixed pool gives the first N workers the GPU); the environment a worker needs for
that (lavapipe-only Vulkan, lavapipe threads, `worker_env_vars`) is set when the worker
starts, before Vulkan is initialised (`mikasa_bench.media.render`). With ``save_videos`` a
worker encodes each episode's mp4 and sends the bytes back with the result.
"""

from __future__ import annotations

import logging
import os
import time
import traceback
from collections.abc import Hashable
from dataclasses import replace
from typing import Any

from mikasa_bench.errors import BenchError, EpisodeInterrupted
from mikasa_bench.media.render import check_render_device, worker_environment
from mikasa_bench.media.video import EpisodeVideo
from mikasa_bench.policies.base import policy_chunk_size
from mikasa_bench.policies.loading import build_policy
from mikasa_bench.protocol import BenchmarkConfig, scene_start, starts_scene
from mikasa_bench.runners.episode import (
    EpisodeResult,
    RecordedActions,
    make_benchmark_env,
    run_episode,
)
from mikasa_bench.runners.jobs import EpisodeJob, EpisodeOutcome

__all__ = ["EpisodeWorker", "available_cores", "make_worker_env", "worker_env_vars"]

logger = logging.getLogger(__name__)


def make_worker_env(env_id: str, config: BenchmarkConfig, process_index: int) -> tuple[Any, str]:
    """The benchmark env of pool process ``process_index``, rendering on that process's
    device (`BenchmarkConfig.render_device_for`), and where it really renders."""
    device = config.render_device_for(process_index)
    env = make_benchmark_env(env_id, replace(config, render_device=device, gpu_render_workers=0))
    return env, check_render_device(env, device)


class EpisodeWorker:
    """Per-process worker state: one cached env and the policies built for it.

    ``worker_id`` is the worker's index in its pool; ``process_index`` (default: the same)
    is its process's, which decides the render device of a mixed pool
    (`BenchmarkConfig.render_device_for`).
    """

    def __init__(self, worker_id: int, process_index: int | None = None, threaded: bool = False) -> None:
        self.worker_id = worker_id
        self.process_index = worker_id if process_index is None else process_index
        self.threaded = threaded
        """Shares its process with other workers' threads (episodes keep their own RNGs)."""
        self.env: Any = None
        self.env_key: Hashable | None = None
        self.policies: dict[str, Any] = {}
        self.render: str | None = None
        self.last_played: tuple[Hashable, int] | None = None
        """(scene key, episode) of the last episode played on the env's current scene."""
        self.recorded: tuple[Hashable, dict[int, list[Any]]] | None = None
        """(scene key, episode -> its actions) of the episodes played on the env's current
        scene: `_replay_scene_history` replays them without the policy."""

    def _env_for(self, job: EpisodeJob) -> Any:
        if self.env_key != job.env_key:
            self.close()
            self.env, self.render = make_worker_env(
                job.task.env_id, job.config, self.process_index
            )
            self.env_key = job.env_key
        return self.env

    def _policy_for(self, job: EpisodeJob, env: Any) -> Any:
        key = job.policy.key()
        if key not in self.policies:
            self.policies[key] = build_policy(job.policy, env, job.task.env_id, job.task)
        return self.policies[key]

    def run(self, job: EpisodeJob) -> EpisodeOutcome:
        """Run one job; exceptions become an outcome with ``error`` set."""
        t0 = time.perf_counter()
        try:
            cached = self.env_key == job.env_key and job.policy.key() in self.policies
            env = self._env_for(job)
            policy = self._policy_for(job, env)
            replayed = self._replay_scene_history(job, env, policy)
            setup_s = 0.0 if cached and not replayed else time.perf_counter() - t0
            cpu0 = time.process_time()
            result, video, restarts = self._play_whole(job, env, policy)
            return EpisodeOutcome(
                job,
                result,
                max(result.chunk_sizes, default=policy_chunk_size(policy)),
                time.perf_counter() - t0,
                self.worker_id,
                video=video,
                render=self.render,
                setup_s=setup_s,
                cpu_s=time.process_time() - cpu0,
                restarts=restarts,
            )
        except Exception as exc:
            # The env may be mid-episode: drop it so a later job starts clean.
            self.close()
            return EpisodeOutcome(
                job,
                None,
                0,
                time.perf_counter() - t0,
                self.worker_id,
                error=f"{type(exc).__name__}: {exc}",
                traceback=traceback.format_exc(),
                user_error=isinstance(exc, BenchError),
            )

    def _play_whole(
        self, job: EpisodeJob, env: Any, policy: Any
    ) -> tuple[EpisodeResult, bytes | None, int]:
        """Play ``job``'s episode to its end: its result, video and restarts.

        An episode whose policy lost its memory of it (`EpisodeInterrupted`) is played
        again from its reset on a rewound scene, never continued, up to the policy's
        ``max_episode_restarts`` times; then the error stops the run (``--resume``
        plays the episode again)."""
        restarts = 0
        while True:
            try:
                if not job.config.save_videos:
                    return self._play(job, job.episode, env, policy), None, restarts
                with EpisodeVideo() as recorder:
                    result = self._play(job, job.episode, env, policy, frame_sink=recorder.add)
                    return result, recorder.finish(), restarts
            except EpisodeInterrupted as exc:
                allowed = int(getattr(policy, "max_episode_restarts", 0))
                if restarts >= allowed:
                    raise EpisodeInterrupted(
                        f"{exc}; the episode was restarted {restarts} time(s), the most the "
                        f"policy allows"
                    ) from None
                restarts += 1
                logger.warning(
                    "%s episode %d (seed %d): %s; playing it again from its reset "
                    "(restart %d of %d)",
                    *(job.task.env_id, job.episode, job.seed, exc, restarts, allowed),
                )
                self._replay_scene_history(job, env, policy, rewind=True)

    def _play(
        self, job: EpisodeJob, episode: int, env: Any, policy: Any, **kwargs: Any
    ) -> EpisodeResult:
        """Play episode ``episode`` of ``job``'s task (a fresh scene where `starts_scene`)
        and record its actions (`_replay_scene_history`)."""
        from mikasa_envs.render_batcher import participating

        self.last_played = None  # until it has finished
        if starts_scene(episode) or self.recorded is None or self.recorded[0] != job.scene_key:
            self.recorded = (job.scene_key, {})
        actions: list[Any] = []
        # The episode (not the env build) takes part in shared render passes when this
        # process runs several workers (mikasa_envs.render_batcher); else a no-op.
        with participating():
            result, _ = run_episode(
                env,
                policy,
                job.seed_of(episode),
                own_global_rngs=self.threaded,
                fresh_scene=starts_scene(episode),
                action_sink=actions.append,
                **kwargs,
            )
        self.recorded[1][episode] = actions
        self.last_played = (job.scene_key, episode)
        return result

    def _replay_scene_history(
        self, job: EpisodeJob, env: Any, policy: Any, rewind: bool = False
    ) -> bool:
        """Play (and discard) the episodes that precede ``job`` on its scene, unless the
        env's scene just played them (or ``rewind``: after an interrupted attempt of the
        job, whose physics must be met again as on its first attempt): the job's numbers
        then do not depend on which episodes this worker ran before (the scheduler hands
        out a scene's episodes in order to one worker, so this only replays after a
        resume, an error or an interruption). An episode this worker played on the scene
        replays its recorded actions, no policy call; others are played with ``policy``.
        Returns whether it replayed."""
        if starts_scene(job.episode):
            return False
        if not rewind and self.last_played == (job.scene_key, job.episode - 1):
            return False
        key, recorded = self.recorded or (None, {})
        recorded = dict(recorded) if key == job.scene_key else {}  # _play starts it afresh
        for episode in range(scene_start(job.episode), job.episode):
            if episode in recorded:
                replay = RecordedActions(recorded[episode])
                self._play(job, episode, env, replay, reset_policy_hook=False)
            else:
                self._play(job, episode, env, policy)
        return True

    def close(self) -> None:
        """Close the cached env and forget its policies."""
        if self.env is not None:
            try:
                self.env.close()
            except Exception:
                pass
        self.env, self.env_key, self.policies, self.last_played = None, None, {}, None
        self.recorded = None


def available_cores() -> int:
    """CPU cores this process may use (the affinity mask, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worker_env_vars(config: BenchmarkConfig, worker_id: int, n_workers: int) -> dict[str, str]:
    """Environment of pool worker ``worker_id``: its render device's Vulkan restriction
    and an equal share of the cores for lavapipe's rasteriser threads (0 = rasterise in
    the worker's own thread, measured 10-20 % faster than one helper thread when a worker
    has a single core)."""
    share = available_cores() // max(1, n_workers)
    return worker_environment(
        config.render_device_for(worker_id), lp_threads=share if share > 1 else 0
    )
