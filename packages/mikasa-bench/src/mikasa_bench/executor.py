"""Executors: where episodes run.

The unit of work is one episode (`EpisodeJob`). An `Executor` takes a list of jobs and
yields an `EpisodeOutcome` per job in completion order; the runner puts results back in
seed order, so the numbers never depend on the executor or the worker count.

* `LocalExecutor` (default): a pool of spawn-started worker processes (SAPIEN is not
  fork-safe once imported). Each worker owns at most one CPU-simulated env; it builds the
  env for a task once and reuses it for every episode (and policy) of that task it gets.
  Jobs are handed out one at a time, preferring the task the worker already has an env
  for, so each worker moves through the task list in order.
* `InlineExecutor`: the same worker logic in the calling process (``--workers 0``;
  debugging, tests with fake envs).
* `mikasa_bench.ray_executor.RayExecutor` (``--executor ray``): Ray actors running the same
  worker logic, spread over a cluster.

Every worker renders where the run's config says (`BenchmarkConfig.render_device_for` its
index: a mixed pool gives the first N workers the GPU); the environment a worker needs for
that (lavapipe-only Vulkan, lavapipe threads) is set when the worker starts, before
Vulkan is initialised (`mikasa_bench.media.render`). With ``save_videos`` a worker encodes each
episode's mp4 and sends the bytes back with the result: the runner writes the file before
it journals the episode, so a recorded episode always has its video, also with Ray
workers on other machines.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import queue
import time
import traceback
from abc import ABC, abstractmethod
from collections import OrderedDict, deque
from collections.abc import Hashable, Iterator, Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

from mikasa_bench.media.render import apply_environment, check_render_device, worker_environment
from mikasa_bench.policies.base import policy_chunk_size
from mikasa_bench.policies.loading import build_policy
from mikasa_bench.policies.spec import PolicySpec

from .episode import EpisodeResult, RecordedActions, make_benchmark_env, run_episode
from .errors import BenchError, EpisodeInterrupted
from .protocol import BenchmarkConfig, scene_start, starts_scene
from .tasks import BenchmarkTask

__all__ = [
    "EpisodeJob",
    "EpisodeOutcome",
    "Executor",
    "InlineExecutor",
    "LocalExecutor",
    "EXECUTORS",
    "make_executor",
    "make_worker_env",
    "available_cores",
    "render_config",
]

logger = logging.getLogger(__name__)


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


def make_worker_env(env_id: str, config: BenchmarkConfig, process_index: int) -> tuple[Any, str]:
    """The benchmark env of pool process ``process_index``, rendering on that process's
    device (`BenchmarkConfig.render_device_for`), and where it really renders."""
    device = config.render_device_for(process_index)
    env = make_benchmark_env(env_id, replace(config, render_device=device, gpu_render_workers=0))
    return env, check_render_device(env, device)


class _EpisodeWorker:
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
                from mikasa_bench.media.video import EpisodeVideo

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


def worker_env_vars(config: BenchmarkConfig, worker_id: int, n_workers: int) -> dict[str, str]:
    """Environment of pool worker ``worker_id``: its render device's Vulkan restriction
    and an equal share of the cores for lavapipe's rasteriser threads (0 = rasterise in
    the worker's own thread, measured 10-20 % faster than one helper thread when a worker
    has a single core)."""
    share = available_cores() // max(1, n_workers)
    return worker_environment(
        config.render_device_for(worker_id), lp_threads=share if share > 1 else 0
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


class InlineExecutor(Executor):
    """Runs every job in the calling process, in order."""

    name = "inline"

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Yield outcomes one by one; the env cache lives for this call."""
        if jobs:
            # Best effort: effective only if this process has not initialised Vulkan yet
            # (the render check of the first env says so if it had).
            device = render_config(jobs).render_device_for(0)
            apply_environment(worker_environment(device))
        worker = _EpisodeWorker(0)
        try:
            for job in jobs:
                yield worker.run(job)
        finally:
            worker.close()


def _start_worker(process_index: int, threaded: bool, worker_id: int) -> _EpisodeWorker:
    from mikasa_envs.workers import quiet_worker

    # Rendering workers keep Mesa's threads: the bench's render path was measured with them.
    quiet_worker(one_raster_thread=False)
    return _EpisodeWorker(worker_id, process_index, threaded)


def _worker_main(
    process_index: int, worker_ids: list[int], inboxes: list[Any], outbox: Any, env_vars: dict[str, str]
) -> None:
    """Entry point of a `LocalExecutor` worker process (one or more workers, a thread each)."""
    # Before anything can initialise Vulkan: the render device's driver restriction.
    apply_environment(env_vars)
    # imported lazily: mikasa_envs loads ManiSkill
    from mikasa_envs.workers import serve_job_slots, use_one_gpu

    use_one_gpu(process_index)  # a CUDA context on one GPU, not on each; spreads GPU rendering
    start = partial(_start_worker, process_index, len(worker_ids) > 1)
    serve_job_slots(worker_ids, inboxes, outbox, start)


class _Scheduler:
    """Hands out jobs scene by scene and task by task.

    A worker gets the episodes of one scene (`EpisodeJob.scene_key`: 5 consecutive
    episodes of a task) in order and alone, so they play on one scene as the protocol
    fixes; then the next unclaimed scene of the same task, keeping its env. A worker that
    needs a new env joins the task with the fewest workers on it (then the one with the
    most env steps left, so long-horizon tasks start early and do not trail the run), so
    workers spread over tasks instead of all building every task's env in turn: measured
    on the GPU machine, an env build costs 2-5 s while 16 workers build at once, as much as
    ~40 short episodes. Which worker runs an episode never changes its
    result (the workers replay a scene's earlier episodes if they must)."""

    def __init__(self, jobs: Sequence[EpisodeJob]) -> None:
        self.unclaimed: OrderedDict[Hashable, OrderedDict[Hashable, deque[EpisodeJob]]] = OrderedDict()
        """Env key -> scene key -> the scene's jobs, for scenes no worker has started."""
        for job in jobs:
            scenes = self.unclaimed.setdefault(job.env_key, OrderedDict())
            scenes.setdefault(job.scene_key, deque()).append(job)
        self.claimed: dict[Hashable, deque[EpisodeJob]] = {}
        """Scene key -> jobs left of a scene a worker is playing."""
        self.steps_left: dict[Hashable, int] = {
            key: sum(j.task.max_episode_steps for q in scenes.values() for j in q)
            for key, scenes in self.unclaimed.items()
        }
        """Env key -> env steps of its unclaimed scenes (kept as scenes are claimed)."""
        self.holders: dict[Hashable, int] = {}
        """Env key -> workers whose last job was of that key."""

    def next_for(self, last: EpisodeJob | None) -> EpisodeJob | None:
        """The next job for a worker whose last job was ``last`` (None: a new worker)."""
        scene = self.claimed.get(last.scene_key) if last is not None else None
        if not scene:
            key = last.env_key if last is not None else None
            if key not in self.unclaimed:
                if not self.unclaimed:
                    return None
                # A new env: the least-served task (order of the run as the last tie-break).
                order = {k: i for i, k in enumerate(self.unclaimed)}
                new = min(
                    self.unclaimed, key=lambda k: (self.holders.get(k, 0), -self.steps_left[k], order[k])
                )
                if key is not None and self.holders.get(key):
                    self.holders[key] -= 1
                self.holders[new] = self.holders.get(new, 0) + 1
                key = new
            scenes = self.unclaimed[key]
            scene_key, scene = scenes.popitem(last=False)
            self.steps_left[key] -= sum(j.task.max_episode_steps for j in scene)
            if not scenes:
                del self.unclaimed[key], self.steps_left[key]
            self.claimed[scene_key] = scene
        job = scene.popleft()
        if not scene:
            del self.claimed[job.scene_key]
        return job


@dataclass
class _Handle:
    process: Any
    inbox: Any
    job: EpisodeJob | None = None
    last: EpisodeJob | None = None


GPU_ENVS_PER_WORKER = 4
"""Default envs per GPU-rendering worker process. Measured on an H200 (16 processes): the
GPU's graphics units are the limit, ~0.35 ms per 128x128 camera however many processes
submit; a pass of 4 scenes instead of 1 rendered ~1.5x the scenes per second."""


def gpu_visible() -> bool:
    """Whether an NVIDIA GPU is visible to this process (decides ``auto`` rendering's
    default envs per worker; the workers check where they really render)."""
    if os.environ.get("CUDA_VISIBLE_DEVICES", None) in ("", "-1"):
        return False
    return os.path.exists("/dev/nvidiactl")


def envs_per_process(config: BenchmarkConfig, process_index: int, envs_per_worker: int | None) -> int:
    """Envs (threads) of pool process ``process_index``: ``envs_per_worker`` if given, else
    `GPU_ENVS_PER_WORKER` for a process rendering on the GPU and 1 for one rendering on the
    CPU (lavapipe gains nothing from sharing passes, and threads share one core)."""
    if envs_per_worker is not None:
        return envs_per_worker
    device = config.render_device_for(process_index)
    on_gpu = device == "gpu" or (device == "auto" and gpu_visible())
    return GPU_ENVS_PER_WORKER if on_gpu else 1


class LocalExecutor(Executor):
    """A pool of ``workers`` spawn-started processes on this machine, each running one or
    more envs (`envs_per_process`: one thread each; on a GPU their cameras render in shared
    passes, `mikasa_envs.render_batcher`)."""

    name = "local"

    def __init__(self, workers: int | None = None, envs_per_worker: int | None = None) -> None:
        n = workers if workers is not None else available_cores()
        if n < 1:
            raise BenchError(f"--workers must be >= 1 for the local executor, got {n}")
        if envs_per_worker is not None and envs_per_worker < 1:
            raise BenchError(f"--envs-per-worker must be >= 1, got {envs_per_worker}")
        self.workers = int(n)
        self.envs_per_worker = envs_per_worker
        """Envs per process as asked (None: `envs_per_process` decides per process)."""
        self.envs: list[int] = []
        """Envs of each process of the last `run`."""
        self.startup_s: float | None = None
        """Seconds until every worker had imported the simulator (set by `run`)."""

    def describe(self) -> dict[str, Any]:
        """Name, process count and envs per process (``"auto"``: by render device)."""
        return {
            "name": self.name,
            "workers": self.workers,
            "envs_per_worker": self.envs_per_worker or "auto",
        }

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Start the pool, feed it, yield outcomes; always stops the workers."""
        jobs = list(jobs)
        if not jobs:
            return
        ctx = mp.get_context("spawn")
        outbox = ctx.Queue()
        handles: list[_Handle] = []
        scheduler = _Scheduler(jobs)
        clean = False
        config = render_config(jobs)
        n = min(self.workers, len(jobs))
        self.envs = [envs_per_process(config, index, self.envs_per_worker) for index in range(n)]
        t_start = time.perf_counter()
        not_ready = sum(self.envs)
        try:
            for index, k in enumerate(self.envs):
                ids = list(range(len(handles), len(handles) + k))
                inboxes = [ctx.Queue() for _ in ids]
                p = ctx.Process(
                    target=_worker_main,
                    args=(index, ids, inboxes, outbox, worker_env_vars(config, index, n)),
                    daemon=True,
                    name=f"mikasa-bench-worker-{index}",
                )
                p.start()
                handles.extend(_Handle(p, inbox) for inbox in inboxes)
            for h in handles:
                self._assign(h, scheduler)
            remaining = len(jobs)
            while remaining:
                try:
                    kind, wid, payload = outbox.get(timeout=1.0)
                except queue.Empty:
                    self._check_alive(handles)
                    continue
                if kind == "fatal":
                    raise BenchError(f"worker {wid} failed to start:\n{payload}")
                if kind == "ready":
                    not_ready -= 1
                    if not not_ready:
                        self.startup_s = time.perf_counter() - t_start
                    continue
                h = handles[wid]
                h.job, h.last = None, payload.job
                remaining -= 1
                self._assign(h, scheduler)
                yield payload
            clean = True
        finally:
            self._shutdown(handles, graceful=clean)

    @staticmethod
    def _assign(h: _Handle, scheduler: _Scheduler) -> None:
        job = scheduler.next_for(h.last)
        if job is not None:
            h.job = job
            h.inbox.put(job)

    @staticmethod
    def _check_alive(handles: Sequence[_Handle]) -> None:
        for wid, h in enumerate(handles):
            if h.job is not None and not h.process.is_alive():
                j = h.job
                raise BenchError(
                    f"worker {wid} died (exit code {h.process.exitcode}) while running "
                    f"{j.task.env_id} episode {j.episode} (seed {j.seed}); finished episodes "
                    f"are saved — rerun with --resume to continue"
                )

    @staticmethod
    def _shutdown(handles: Sequence[_Handle], graceful: bool) -> None:
        if graceful:
            for h in handles:
                try:
                    h.inbox.put(None)
                except Exception:
                    pass
        # Error / interrupt (or a worker that did not exit): stop now; the episodes they
        # were running are not recorded and will be rerun by --resume.
        from mikasa_envs.workers import stop_processes

        processes = list({id(h.process): h.process for h in handles}.values())
        stop_processes(processes, wait_s=30 if graceful else 0)


def _ray_executor(workers: int | None = None, address: str | None = None) -> Executor:
    # Imported lazily: ray is an optional extra (mikasa-bench[ray]).
    from .ray_executor import RayExecutor

    return RayExecutor(workers=workers, address=address)


EXECUTORS: dict[str, Any] = {
    "local": LocalExecutor,
    "inline": InlineExecutor,
    "ray": _ray_executor,
}
"""Executor name -> class or factory."""


def make_executor(
    name: str = "local",
    workers: int | None = None,
    *,
    address: str | None = None,
    envs_per_worker: int | None = None,
) -> Executor:
    """Build an executor by name (``workers == 0`` selects `InlineExecutor`; ``address``
    is the Ray cluster to join, default: ``RAY_ADDRESS`` or a new local instance;
    ``envs_per_worker`` is the local pool's envs per process, default by render device)."""
    if name not in EXECUTORS:
        raise BenchError(f"unknown executor {name!r}; expected one of {', '.join(EXECUTORS)}")
    if address is not None and name != "ray":
        raise BenchError("--address is only used by --executor ray")
    if envs_per_worker is not None and (name != "local" or workers == 0):
        raise BenchError("--envs-per-worker is only used by the local executor with --workers >= 1")
    if name == "ray":
        if workers == 0:
            raise BenchError("--workers 0 (run in this process) cannot be used with Ray")
        return _ray_executor(workers, address)
    if name == "inline" or workers == 0:
        return InlineExecutor()
    return LocalExecutor(workers, envs_per_worker)
