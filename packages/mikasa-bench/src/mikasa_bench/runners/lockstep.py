"""Batched evaluation (``mikasa-bench run --policy-batch B``): B episodes in lockstep, one
policy call per step for all of them.

A learned policy on a GPU answers B observations in about the time it takes for one, and
one evaluation episode at a time leaves it waiting on the simulator and the simulator on
it (a Diffusion Policy evaluated in-process ran 10-20 env steps/s on an H200). With
``policy_batch = B`` the bench runs B envs in lockstep, as lerobot-eval does with its vector
envs, and asks the policy (in this process) once per step for all of them:
``policy.forward_batch(observations)``. The envs live in env processes of up to
``envs_per_worker`` each (`executor.envs_per_process`: 4 on a GPU, stepped in threads whose
cameras render in one shared pass; 1 on the CPU).

Which episodes share a batch is fixed by the protocol, never by scheduling, so results
depend on B alone (not on the machine, a resume or timing): the scenes of a task
(`EPISODES_PER_SCENE` episodes each, `protocol.scene_start`) are taken B at a time, and
round r plays episode r of each of those scenes. A round resets its envs together (a fresh
scene for round 0), seeds the global RNGs with its first episode's seed, resets the policy
once (a LeRobot policy's action queue and observation history are per batch) and steps
until every episode has ended; an episode that ends early keeps its last observation in the
batch and its actions are dropped. A deterministic policy gives the same per-episode
results as the unbatched run wherever its batched arithmetic gives the same actions (a
network's batched convolutions may differ in the last bits, and its episodes with them); a
stochastic one draws its noise per batch (recorded in the result files' protocol as
``policy_batch``). On a resume, a group of scenes with any
episode missing is played again whole and only the missing episodes are recorded.

A policy that can be evaluated this way has ``forward_batch(observations) -> (B, *A) or
(B, K, *A)`` (a list of B observation dicts in; one action or a chunk of K per env out)
and, optionally, ``reset()`` / ``reset(seed)``; it is built once per task in this process
(a LeRobot policy: `mikasa_bench.lerobot.policy.LeRobotPolicy.forward_batch`).
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import threading
import time
import traceback
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any

import numpy as np

from mikasa_bench.errors import BenchError, PolicyOutputError
from mikasa_bench.media.render import apply_environment
from mikasa_bench.policies.base import policy_chunk_size, reset_policy
from mikasa_bench.policies.loading import build_policy
from mikasa_bench.protocol import EPISODES_PER_SCENE, BenchmarkConfig
from mikasa_bench.runners.episode import (
    EpisodeResult,
    first_value,
    normalize_action_chunk,
    seed_global_rngs,
)
from mikasa_bench.runners.executor import envs_per_process
from mikasa_bench.runners.jobs import EpisodeJob, EpisodeOutcome, Executor, render_config
from mikasa_bench.runners.worker import make_worker_env, worker_env_vars

__all__ = ["LockstepExecutor", "split_action_batch", "scene_groups"]


def scene_groups(n_episodes: int, batch: int) -> list[list[list[int]]]:
    """The rounds of every batch of a task: ``groups[g][r]`` lists the episodes played
    together in round ``r`` of group ``g`` (episode ``r`` of each of the group's scenes)."""
    scenes = [
        list(range(s, min(s + EPISODES_PER_SCENE, n_episodes)))
        for s in range(0, n_episodes, EPISODES_PER_SCENE)
    ]
    groups = []
    for g in range(0, len(scenes), batch):
        members = scenes[g : g + batch]
        rounds = [
            [scene[r] for scene in members if r < len(scene)] for r in range(EPISODES_PER_SCENE)
        ]
        groups.append([r for r in rounds if r])
    return groups


def split_action_batch(output: Any, batch: int, action_shape: Sequence[int]) -> list[list[Any]]:
    """Split ``forward_batch``'s output into each env's list of float32 torch actions.

    Accepted: ``(B, *A)`` (one action per env) or ``(B, K, *A)`` (a chunk each) as a torch
    tensor or numpy array; anything else raises `PolicyOutputError` naming the shapes.
    """
    import torch

    a = tuple(int(d) for d in action_shape)
    t = output.detach() if isinstance(output, torch.Tensor) else None
    if t is None:
        try:
            arr = np.asarray(output)
        except Exception:
            arr = np.asarray(None, dtype=object)
        shape = tuple(arr.shape)
    else:
        shape = tuple(t.shape)
    if (
        not shape
        or shape[0] != batch
        or shape[1:] not in (a, shape[1:2] + a)
        or len(shape) > len(a) + 2
    ):
        raise PolicyOutputError(
            f"policy.forward_batch returned {type(output).__name__} of shape {shape} for "
            f"{batch} observations; expected ({batch}, {', '.join(map(str, a))}) or "
            f"({batch}, K, {', '.join(map(str, a))})"
        )
    rows = t.unbind(0) if t is not None else list(arr)
    return [normalize_action_chunk(row, a) for row in rows]


# ------------------------------------------------------------------------------------
# the env processes
# ------------------------------------------------------------------------------------


def _numpy_tree(x: Any) -> Any:
    """Observations as numpy (they cross a process boundary; torch tensors would travel
    as shared-memory handles)."""
    if isinstance(x, Mapping):
        return {k: _numpy_tree(v) for k, v in x.items()}
    if hasattr(x, "detach"):
        return x.detach().cpu().numpy()
    return x


def _torch_tree(x: Any) -> Any:
    """Back to the torch tensors an env in this process would have given the policy."""
    import torch

    if isinstance(x, Mapping):
        return {k: _torch_tree(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return torch.from_numpy(x)
    return x


class _LockstepEnv:
    """One env of an env process (rebuilt when the task or settings change), reset and
    stepped on the parent's command; every reply is ``(kind, payload)``."""

    def __init__(self, process_index: int) -> None:
        self.process_index = process_index
        self.env: Any = None
        self.key: Any = None
        self.render: str | None = None

    def run(self, kind: str, payload: Any) -> tuple[str, Any]:
        import torch

        try:
            if kind == "reset":
                env_id, config, seed, fresh = payload
                if self.key != (env_id, config):
                    self.close()
                    self.env, self.render = make_worker_env(env_id, config, self.process_index)
                    self.key = (env_id, config)
                options = {"reconfigure": True} if fresh else None
                obs, _ = self.env.reset(seed=int(seed), options=options)
                shape = tuple(self.env.action_space.shape)
                return "reset", (
                    _numpy_tree(obs),
                    (int(self.env.max_episode_steps), shape, self.render),
                )
            action = torch.from_numpy(payload).unsqueeze(0)
            device = getattr(self.env.unwrapped, "device", None) or torch.device("cpu")
            obs, reward, terminated, truncated, info = self.env.step(action.to(device))
            success = isinstance(info, dict) and bool(first_value(info.get("success", False)))
            done = bool(first_value(terminated)) or bool(first_value(truncated))
            return "step", (_numpy_tree(obs), float(first_value(reward)), success, done)
        except Exception as exc:
            self.close()
            return "error", (f"{type(exc).__name__}: {exc}", traceback.format_exc())

    def close(self) -> None:
        if self.env is not None:
            try:
                self.env.close()
            except Exception:
                pass
        self.env, self.key = None, None


class _EnvSlots:
    """The envs of one env process. Several (the default on a GPU) step in threads of their
    own and render their cameras in one shared pass (`mikasa_envs.render_batcher`): the
    processes that submit work to one GPU are what limits a pool there (`executor`'s
    `GPU_ENVS_PER_WORKER`)."""

    def __init__(self, process_index: int, slots: int) -> None:
        self.envs = [_LockstepEnv(process_index) for _ in range(slots)]
        self.threads = ThreadPoolExecutor(slots) if slots > 1 else None

    def run(self, command: tuple[str, list[tuple[int, Any]]]) -> list[tuple[str, Any]]:
        """``(kind, [(slot, payload), ...])`` -> each slot's reply, in that order."""
        kind, items = command
        if self.threads is None:
            return [self.envs[slot].run(kind, payload) for slot, payload in items]
        from mikasa_envs.render_batcher import participating

        # Every thread joins the render passes before any of them renders: one pass each
        # step for all of them, not one for the first to get there.
        joined = threading.Barrier(len(items))

        def one(slot: int, payload: Any) -> tuple[str, Any]:
            with participating():
                joined.wait()
                return self.envs[slot].run(kind, payload)

        futures = [self.threads.submit(one, slot, payload) for slot, payload in items]
        return [f.result() for f in futures]

    def close(self) -> None:
        for env in self.envs:
            env.close()
        if self.threads is not None:
            self.threads.shutdown(wait=False)


def _start_env_slots(process_index: int, slots: int) -> _EnvSlots:
    from mikasa_envs.workers import quiet_worker

    quiet_worker(one_raster_thread=False)
    if slots > 1:
        from mikasa_envs.render_batcher import install_batcher

        install_batcher()
    return _EnvSlots(process_index, slots)


def _env_main(
    process_index: int, slots: int, inbox: Any, outbox: Any, env_vars: dict[str, str]
) -> None:
    """Entry point of an env process."""
    apply_environment(env_vars)  # before anything can initialise Vulkan
    from mikasa_envs.workers import serve_jobs, use_one_gpu

    use_one_gpu(process_index)  # a CUDA context on one GPU, not on each; spreads GPU rendering

    serve_jobs(process_index, inbox, outbox, partial(_start_env_slots, process_index, slots))


class _EnvPool:
    """``n`` envs in spawn-started env processes of up to ``per_process`` envs each,
    commanded together."""

    def __init__(self, n: int, per_process: int, config: BenchmarkConfig) -> None:
        ctx = mp.get_context("spawn")
        self.per_process = max(1, per_process)
        n_proc = -(-n // self.per_process)
        self.outbox = ctx.Queue()
        self.inboxes = [ctx.Queue() for _ in range(n_proc)]
        self.processes = []
        for index in range(n_proc):
            slots = min(self.per_process, n - index * self.per_process)
            env_vars = worker_env_vars(config, index, n_proc)
            self.processes.append(
                ctx.Process(
                    target=_env_main,
                    args=(index, slots, self.inboxes[index], self.outbox, env_vars),
                    daemon=True,
                    name=f"mikasa-bench-envs-{index}",
                )
            )
        for p in self.processes:
            p.start()
        self._gather(range(n_proc), "ready")

    def command(self, kind: str, payloads: Mapping[int, Any]) -> dict[int, Any]:
        """Send env ``i`` its payload for ``kind`` (reset or step); each env's reply payload.
        Raises `_EnvError` when an env failed."""
        by_process: dict[int, list[tuple[int, Any]]] = {}
        for i, payload in payloads.items():
            by_process.setdefault(i // self.per_process, []).append((i % self.per_process, payload))
        for index, items in by_process.items():
            self.inboxes[index].put((kind, items))
        replies = self._gather(by_process, "done")
        out = {}
        for index, items in by_process.items():
            for (slot, _), (got, payload) in zip(items, replies[index], strict=True):
                if got == "error":
                    raise _EnvError(index * self.per_process + slot, *payload)
                out[index * self.per_process + slot] = payload
        return out

    def _gather(self, ids: Any, kind: str) -> dict[int, Any]:
        waiting, out = set(ids), {}
        while waiting:
            try:
                got, index, payload = self.outbox.get(timeout=1.0)
            except queue.Empty:
                dead = [i for i in waiting if not self.processes[i].is_alive()]
                if dead:
                    raise BenchError(
                        f"env process {dead[0]} died (exit code {self.processes[dead[0]].exitcode}); "
                        f"finished episodes are saved — rerun with --resume to continue"
                    ) from None
                continue
            if got == "fatal":
                raise BenchError(f"env process {index} failed to start:\n{payload}")
            waiting.discard(index)
            out[index] = payload
        return out

    def close(self, graceful: bool) -> None:
        from mikasa_envs.workers import stop_processes

        if graceful:
            for box in self.inboxes:
                box.put(None)
        stop_processes(self.processes, wait_s=30 if graceful else 0)


class _EnvError(Exception):
    def __init__(self, worker: int, message: str, tb: str) -> None:
        super().__init__(message)
        self.worker, self.message, self.tb = worker, message, tb


# ------------------------------------------------------------------------------------
# the executor
# ------------------------------------------------------------------------------------


class LockstepExecutor(Executor):
    """Plays the jobs' episodes B at a time in lockstep (module docstring); B is the
    runs' ``policy_batch``."""

    name = "lockstep"

    def __init__(self, batch: int, envs_per_worker: int | None = None) -> None:
        if batch < 1:
            raise BenchError(f"--policy-batch must be >= 1, got {batch}")
        if envs_per_worker is not None and envs_per_worker < 1:
            raise BenchError(f"--envs-per-worker must be >= 1, got {envs_per_worker}")
        self.batch = int(batch)
        self.envs_per_worker = envs_per_worker
        """Envs per env process as asked (None: `envs_per_process` decides by render device)."""

    def describe(self) -> dict[str, Any]:
        """Name, envs in lockstep (the runs' ``policy_batch``) and envs per env process."""
        return {
            "name": self.name,
            "policy_batch": self.batch,
            "envs_per_worker": self.envs_per_worker or "auto",
        }

    def run(self, jobs: Sequence[EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """Yield every job's outcome, a round at a time; always stops the env processes."""
        jobs = list(jobs)
        if not jobs:
            return
        config = render_config(jobs)
        other = sorted({j.config.policy_batch for j in jobs} - {self.batch})
        if other:
            raise BenchError(
                f"runs with --policy-batch {other} given to a lockstep executor of batch "
                f"{self.batch}: run them separately"
            )
        pending: dict[tuple[int, str], dict[int, EpisodeJob]] = {}
        for j in jobs:
            pending.setdefault((j.run_index, j.task.env_id), {})[j.episode] = j
        widest = max(
            len(rounds[0])
            for group in pending.values()
            for rounds in scene_groups(next(iter(group.values())).config.n_episodes, self.batch)
        )
        pool = _EnvPool(widest, envs_per_process(config, 0, self.envs_per_worker), config)
        clean = False
        try:
            for todo in pending.values():
                yield from self._task(pool, todo)
            clean = True
        finally:
            pool.close(graceful=clean)

    def _task(self, pool: _EnvPool, todo: dict[int, EpisodeJob]) -> Iterator[EpisodeOutcome]:
        """The groups of one task of one run that hold a missing episode."""
        job = next(iter(todo.values()))
        policy = None
        for rounds in scene_groups(job.config.n_episodes, self.batch):
            if not any(e in todo for r in rounds for e in r):
                continue
            for r, episodes in enumerate(rounds):
                t0 = time.perf_counter()
                try:
                    if policy is None:
                        policy = _batch_policy(job)
                    results, render = _play_round(pool, policy, job, episodes, fresh=r == 0)
                except _EnvError as exc:
                    yield from _failed(todo, episodes, exc.message, exc.tb, False)
                    return
                except Exception as exc:
                    user = isinstance(exc, BenchError)
                    yield from _failed(
                        todo, episodes, f"{type(exc).__name__}: {exc}", traceback.format_exc(), user
                    )
                    return
                wall = time.perf_counter() - t0
                chunk = policy_chunk_size(policy)
                for e, result in zip(episodes, results, strict=True):
                    if e in todo:
                        yield EpisodeOutcome(todo[e], result, chunk, wall, 0, render=render)


def _failed(
    todo: dict[int, EpisodeJob], episodes: Sequence[int], error: str, tb: str, user: bool
) -> Iterator[EpisodeOutcome]:
    """One failed outcome (the runner stops at the first), for a missing episode of the round."""
    job = next((todo[e] for e in episodes if e in todo), next(iter(todo.values())))
    yield EpisodeOutcome(job, None, 0, 0.0, 0, error=error, traceback=tb, user_error=user)


def _batch_policy(job: EpisodeJob) -> Any:
    """The job's policy, built in this process; `BenchError` unless it has forward_batch."""
    policy = build_policy(job.policy, None, job.task.env_id, job.task)
    if not callable(getattr(policy, "forward_batch", None)):
        raise BenchError(
            f"policy {job.policy.label or job.policy.target!r} ({type(policy).__name__}) has no "
            f"forward_batch(observations) method, so it cannot be evaluated with --policy-batch; "
            f"LeRobot policies (lerobot:DIR) have one, or run without --policy-batch"
        )
    return policy


def _play_round(
    pool: _EnvPool, policy: Any, job: EpisodeJob, episodes: Sequence[int], fresh: bool
) -> tuple[list[EpisodeResult], str | None]:
    """Play ``episodes`` (one per env) together; their results and where the envs rendered."""
    seeds = [job.seed_of(e) for e in episodes]
    n = len(episodes)
    replies = pool.command(
        "reset", {i: (job.task.env_id, job.config, s, fresh) for i, s in enumerate(seeds)}
    )
    obs = [_torch_tree(replies[i][0]) for i in range(n)]
    max_steps, action_shape, render = replies[0][1]
    seed_global_rngs(seeds[0])
    reset_policy(policy, seeds[0])
    queues: list[deque[Any]] = [deque() for _ in range(n)]
    active = list(range(n))
    success, total, steps = [False] * n, [0.0] * n, [0] * n
    for _ in range(max_steps):
        if not queues[active[0]]:
            chunks = split_action_batch(policy.forward_batch(obs), n, action_shape)
            for i in active:
                queues[i] = deque(chunks[i])
        replies = pool.command(
            "step", {i: queues[i].popleft().numpy() for i in active}
        )
        for i, (o, reward, ok, _) in replies.items():
            obs[i] = _torch_tree(o)
            total[i] += reward
            steps[i] += 1
            success[i] = success[i] or ok
        active = [i for i in active if not replies[i][3]]
        if not active:
            break
    results = [EpisodeResult(success[i], total[i], steps[i], seeds[i]) for i in range(n)]
    return results, render
