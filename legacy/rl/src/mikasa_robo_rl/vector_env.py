"""Many CPU-simulated RL envs behind one ``ManiSkillVectorEnv``-like object.

The release's PPO trainers step 1,024 GPU-simulated envs as one batch. GPU PhysX is not
available everywhere, so :class:`CpuVectorEnv` runs ``num_envs`` single CPU envs in worker
processes (``mikasa_envs.workers``, the process loop the bench and the collectors use) and
presents them as one batch: ``reset`` / ``step`` take and return batched torch tensors.

Each sub-env is ``gym.make(<id>, num_envs=1, sim_backend="cpu")`` with the RL wrapper chain
(a VLA id: the canonical VLA chain, ``mikasa_robo_rl.wrappers.apply_vla_rl_wrappers``),
wrapped in ManiSkill's own ``ManiSkillVectorEnv`` (``ignore_terminations``,
``record_metrics``: ``episode`` = ``success_once`` / ``return`` / ``episode_len`` / ...);
this module resets finished sub-envs with seeds of their own (``final_observation``,
``final_info``, ``_final_info`` as ManiSkillVectorEnv's auto-reset reports them), ships the
pieces between processes and stacks them. A worker process holds
``num_envs / workers`` sub-envs and steps them one after another, or each in a thread of its
own with their cameras rendered in one GPU pass (``render_together``); observations travel
pickled through queues, or through shared memory (``shared_memory``).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from mani_skill.utils.gym_utils import find_max_episode_steps_value

__all__ = ["CpuVectorEnv", "SubEnvSpec", "default_vector_workers"]


def default_vector_workers(num_envs: int) -> int:
    """One worker process per CPU core, at most one per sub-env."""
    return max(1, min(num_envs, os.cpu_count() or 1))


@dataclass(frozen=True)
class SubEnvSpec:
    """How a worker builds each of its sub-envs (picklable: it crosses to the workers)."""

    env_id: str
    mode: str = "state"
    """An RL observation mode (``mikasa_robo_rl.wrappers.OBS_MODES``)."""
    reward_mode: str = "normalized_dense"
    control_mode: str | None = None
    """None: the id's own (``mikasa_robo_rl.wrappers.default_control_mode``)."""
    noop_steps: int = 1
    reconfiguration_freq: int | None = None
    ignore_terminations: bool = True
    render_mode: str | None = None
    make_kwargs: dict[str, Any] = field(default_factory=dict)
    video_dir: str | None = None
    """record sub-env 0's episodes here (ManiSkill's ``RecordEpisode``; needs ``render_mode``)"""
    save_trajectory: bool = False
    """with ``video_dir``: also save sub-env 0's trajectories (``trajectory.h5`` / ``.json``)"""
    max_steps_per_video: int | None = None

    def make(self, index: int = 0) -> gym.Env:
        """Sub-env ``index``: `make_single` in ManiSkill's ``ManiSkillVectorEnv`` (a batch of
        one, torch tensors, episode metrics)."""
        from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

        env = self.make_single(index)
        try:
            return ManiSkillVectorEnv(
                env, 1, auto_reset=False, ignore_terminations=self.ignore_terminations, record_metrics=True
            )
        except BaseException:
            env.close()
            raise

    def make_single(self, index: int = 0) -> gym.Env:
        """Sub-env ``index`` unbatched by a vector wrapper: ``gym.make`` on the CPU sim, the RL
        chain (the VLA chain for a VLA id), ``RecordEpisode`` for sub-env 0 when
        ``video_dir`` is set."""
        from mikasa_robo_rl.manifest import trainable_horizon
        from mikasa_robo_rl.wrappers import (
            apply_rl_wrappers,
            apply_vla_rl_wrappers,
            default_control_mode,
            env_info,
            env_obs_mode,
            is_vla_env_id,
        )

        trainable_horizon(self.env_id)  # an unknown id fails here, naming close RL and VLA ids
        vla = is_vla_env_id(self.env_id)
        if vla and self.noop_steps != 1:
            raise ValueError(f"noop_steps applies to the RL ids only; {self.env_id} is a VLA id (use 1)")
        if not vla:
            env_info(self.env_id, self.noop_steps)
        # The trainers' normalized_dense is upstream's, dense / its divisor, unclipped.
        # The envs clip theirs to [0, 1] (their published contract), and clipped, every
        # exploring step whose smoothness penalty outweighs the rest is worth exactly 0:
        # PPO gets no signal (docs/lab-notes/rl-ppo-runs/results/unclipped_reward.md,
        # "The clipped reward trap").
        upstream_normalized = self.reward_mode == "normalized_dense"
        env = gym.make(
            self.env_id,
            num_envs=1,
            obs_mode=env_obs_mode(self.mode),
            control_mode=self.control_mode or default_control_mode(self.env_id),
            reward_mode="dense" if upstream_normalized else self.reward_mode,
            render_mode=self.render_mode,
            reconfiguration_freq=self.reconfiguration_freq,
            sim_backend="cpu",
            **self.make_kwargs,
        )
        try:
            if vla:
                env = apply_vla_rl_wrappers(env, self.mode)
            else:
                env = apply_rl_wrappers(env, self.mode, noop_steps=self.noop_steps)
            if upstream_normalized:
                env = gym.wrappers.TransformReward(
                    env, partial(torch.div, other=float(env.unwrapped.normalized_dense_divisor))
                )
            if self.video_dir is not None and index == 0:
                from mani_skill.utils.wrappers.record import RecordEpisode

                if self.render_mode is None:
                    raise ValueError("recording videos needs a render_mode (e.g. 'rgb_array' or 'all')")
                env = RecordEpisode(env, self.video_dir, save_trajectory=self.save_trajectory,
                                    trajectory_name="trajectory", max_steps_per_video=self.max_steps_per_video,
                                    video_fps=30, avoid_overwriting_video=True)
            return env
        except BaseException:
            env.close()
            raise


def _to_numpy(tree: Any) -> Any:
    """Tensors (nested in dicts) as numpy arrays, for the trip between processes."""
    if isinstance(tree, Mapping):
        return {k: _to_numpy(v) for k, v in tree.items()}
    if isinstance(tree, tuple):
        return tuple(_to_numpy(v) for v in tree)
    if torch.is_tensor(tree):
        return tree.detach().cpu().numpy()
    return tree


def _leaves(tree: Any, path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """The leaves of a (nested) dict observation, or of its ``spaces.Dict``, with their key
    paths."""
    if isinstance(tree, Mapping):
        return [leaf for k, v in tree.items() for leaf in _leaves(v, (*path, k))]
    return [(path, tree)]


class SharedObservations:
    """Every sub-env's observation in shared memory: leaf ``path`` -> ``(num_envs, *shape)``.

    The trainer creates the blocks (``layout``: path -> (shape of one sub-env's leaf without
    its batch of 1, dtype)); a worker attaches by their ``names`` and writes its sub-envs'
    rows, so image arrays never go through a pipe; the trainer reads the batch once.
    """

    def __init__(self, layout: dict[tuple[str, ...], tuple[tuple[int, ...], str]], num_envs: int,
                 names: dict[tuple[str, ...], str] | None = None) -> None:
        from multiprocessing.shared_memory import SharedMemory

        self.layout, self.owner = layout, names is None
        self.blocks: dict[tuple[str, ...], Any] = {}
        self.arrays: dict[tuple[str, ...], np.ndarray] = {}
        for path, (shape, dtype) in layout.items():
            size = max(1, int(np.prod((num_envs, *shape))) * np.dtype(dtype).itemsize)
            block = SharedMemory(create=True, size=size) if names is None else SharedMemory(name=names[path])
            self.blocks[path] = block
            self.arrays[path] = np.ndarray((num_envs, *shape), dtype=dtype, buffer=block.buf)

    @property
    def names(self) -> dict[tuple[str, ...], str]:
        return {path: block.name for path, block in self.blocks.items()}

    def write(self, index: int, obs: Any) -> None:
        """Sub-env ``index``'s observation (numpy, batch of 1) into its rows."""
        for path, value in _leaves(obs):
            self.arrays[path][index] = value[0]

    def read(self, device: torch.device) -> Any:
        """The whole batch as a tensor tree on ``device``, copied out of the shared blocks."""
        out: dict[str, Any] = {}
        for path, array in self.arrays.items():
            tensor = torch.from_numpy(array)
            tensor = tensor.clone() if device.type == "cpu" else tensor.to(device)
            if not path:  # the observation is one array, not a dict
                return tensor
            node = out
            for key in path[:-1]:
                node = node.setdefault(key, {})
            node[path[-1]] = tensor
        return out

    def close(self) -> None:
        self.arrays = {}
        for block in self.blocks.values():
            block.close()
            if self.owner:
                block.unlink()
        self.blocks = {}


class _SubEnvs:
    """A worker's state: its sub-envs; jobs ``("reset", seeds)`` and ``("step", actions)``.

    A finished sub-env resets itself, as ManiSkillVectorEnv's auto-reset does, but with a
    seed drawn from its own generator (seeded by its last seeded reset): an unseeded reset
    takes its scene from the process's global torch RNG, so the episodes after the first
    would depend on how the sub-envs are spread over processes.
    """

    def __init__(self, spec: SubEnvSpec, count: int, first_index: int = 0, shared: Any = None,
                 render_together: bool = False) -> None:
        self.threads: ThreadPoolExecutor | None = None
        if render_together and count > 1:
            from mikasa_envs.render_batcher import install_batcher

            install_batcher()
            self.threads = ThreadPoolExecutor(count, thread_name_prefix="mikasa-rl-sub-env")
        self.envs = [spec.make(first_index + i) for i in range(count)]
        self.seeders = [np.random.RandomState() for _ in range(count)]
        self.first_index = first_index
        # (layout, num_envs, names): observations go into the trainer's shared blocks
        self.shared = None if shared is None else SharedObservations(*shared)

    def _send(self, i: int, obs: Any) -> Any:
        """Sub-env ``i``'s observation for the trainer: written to shared memory (None goes
        back), or as numpy arrays."""
        if self.shared is None:
            return _to_numpy(obs)
        self.shared.write(self.first_index + i, _to_numpy(obs))
        return None

    def _reset(self, i: int, seed: int | None) -> tuple[Any, Any]:
        if seed is None:
            seed = int(self.seeders[i].randint(2**31))
        else:
            self.seeders[i] = np.random.RandomState(seed)
        return self.envs[i].reset(seed=seed)

    def _reset_one(self, i: int, seed: int | None) -> tuple[Any, Any]:
        obs, info = self._reset(i, seed)
        return self._send(i, obs), _to_numpy(info)

    def _step_one(self, i: int, action: np.ndarray) -> tuple[Any, ...]:
        obs, reward, terminated, truncated, info = self.envs[i].step(torch.as_tensor(action[None]))
        # Only what the trainers read crosses back: final observation and metrics.
        kept = {}
        if bool((terminated | truncated).any()):
            kept = {"final_observation": obs, "final_info": {"episode": info["episode"]},
                    "_final_info": terminated | truncated}
            obs, _ = self._reset(i, None)
        return (self._send(i, obs), *_to_numpy((reward, terminated, truncated, kept)))

    def _each(self, fn: Callable[[int, Any], Any], payload: list[Any]) -> list[Any]:
        """``fn(i, payload[i])`` for every sub-env: one after another, or with ``threads``
        each in its own thread, rendering together (``mikasa_envs.render_batcher``)."""
        if self.threads is None:
            return [fn(i, p) for i, p in enumerate(payload)]
        from mikasa_envs.render_batcher import participating

        def run_one(i: int) -> Any:
            with participating():
                return fn(i, payload[i])

        return list(self.threads.map(run_one, range(len(payload))))

    def run(self, job: tuple[str, Any]) -> list[Any]:
        kind, payload = job
        if kind == "reset":
            return self._each(self._reset_one, payload)
        if kind == "step":
            return self._each(self._step_one, payload)
        raise ValueError(f"unknown job {kind!r}")

    def close(self) -> None:
        for env in self.envs:
            env.close()
        if self.threads is not None:
            self.threads.shutdown()
        if self.shared is not None:
            self.shared.close()


def _start_sub_envs(spec: SubEnvSpec, count: int, first_index: int, shared: Any = None,
                    render_together: bool = False) -> _SubEnvs:
    from mikasa_envs.workers import quiet_worker

    quiet_worker()
    import mikasa_robo_rl  # noqa: F401  (registers the RL ids in the spawned interpreter)

    return _SubEnvs(spec, count, first_index, shared, render_together)


def _worker_main(worker_id: int, spec: SubEnvSpec, count: int, first_index: int, inbox: Any, outbox: Any,
                 shared: Any = None, render_together: bool = False) -> None:
    from mikasa_envs.workers import serve_jobs, use_one_gpu

    use_one_gpu(worker_id)  # a CUDA context on one GPU, not on each (its docstring says why)
    serve_jobs(worker_id, inbox, outbox, partial(_start_sub_envs, spec, count, first_index, shared, render_together))


def _stack(parts: list[Any], device: torch.device) -> Any:
    """Per-sub-env numpy pieces (each with a leading batch of 1) as one batched tensor tree."""
    first = parts[0]
    if isinstance(first, Mapping):
        return {k: _stack([p[k] for p in parts], device) for k in first}
    return torch.from_numpy(np.concatenate([np.asarray(p) for p in parts], axis=0)).to(device)


def _replace_rows(batch: Any, rows: dict[int, Any]) -> Any:
    """A copy of a batched tensor tree with row i replaced by ``rows[i]`` (numpy, batch of 1)."""
    if isinstance(batch, Mapping):
        return {k: _replace_rows(v, {i: row[k] for i, row in rows.items()}) for k, v in batch.items()}
    out = batch.clone()
    for i, row in rows.items():
        out[i] = torch.from_numpy(np.asarray(row[0])).to(out.device)
    return out


class CpuVectorEnv:
    """``num_envs`` CPU sub-envs in ``workers`` processes, as one batched env.

    Follows ``ManiSkillVectorEnv``: ``reset(seed=s)`` seeds sub-env i with the seed
    ManiSkill gives env i of a batch reset with ``seed=s``; ``step(actions)`` takes a
    ``(num_envs, action_dim)`` tensor and returns batched tensors on ``device``; a finished
    sub-env resets itself and ``info`` then holds ``final_observation``, ``final_info``
    (with ``episode`` metrics) and the mask ``_final_info``. ``single_observation_space`` /
    ``single_action_space`` are a sub-env's. ``workers=0`` runs the sub-envs in this
    process (tests, debugging). ``shared_memory=True``: the workers write observations into
    `SharedObservations` instead of pickling them through the queues (the rest, rewards,
    flags and a finished episode's final observation, still goes through them).
    """

    def __init__(
        self, spec: SubEnvSpec, num_envs: int, workers: int | None = None, device: str | torch.device = "cpu",
        shared_memory: bool = False, render_together: bool = False,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.spec, self.num_envs, self.device = spec, int(num_envs), torch.device(device)
        workers = default_vector_workers(num_envs) if workers is None else int(workers)
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        # Spaces, and a clear error for a bad id or mode before any fork (no recording).
        probe = replace(spec, video_dir=None).make()
        self.single_observation_space = probe.single_observation_space
        self.single_action_space = probe.single_action_space
        self.max_episode_steps = find_max_episode_steps_value(probe)
        self._shared: SharedObservations | None = None
        if shared_memory and workers > 0:
            # The wrapper chain's observation space says each leaf's shape and dtype.
            leaves = _leaves(self.single_observation_space)
            layout = {path: (tuple(space.shape), space.dtype.str) for path, space in leaves}
            self._shared = SharedObservations(layout, self.num_envs)
        probe.close()
        self._inline: _SubEnvs | None = None
        self._processes: list[Any] = []
        if workers == 0:
            self._inline = _SubEnvs(spec, num_envs)
            self._counts = [num_envs]
            return
        workers = min(workers, num_envs)
        self._counts = [num_envs // workers + (w < num_envs % workers) for w in range(workers)]
        shared = None if self._shared is None else (self._shared.layout, self.num_envs, self._shared.names)
        ctx = mp.get_context("spawn")
        self._outbox = ctx.Queue()
        self._inboxes = [ctx.Queue() for _ in range(workers)]
        self._processes = [
            ctx.Process(target=_worker_main,
                        args=(w, spec, n, sum(self._counts[:w]), inbox, self._outbox, shared, render_together),
                        daemon=True, name=f"mikasa-rl-env-{w}")
            for w, (n, inbox) in enumerate(zip(self._counts, self._inboxes, strict=True))
        ]
        for p in self._processes:
            p.start()
        ready = 0
        while ready < workers:
            kind, wid, payload = self._receive()
            if kind == "fatal":
                self.close()
                raise RuntimeError(f"env worker {wid} failed to start:\n{payload}")
            ready += kind == "ready"

    # ------------------------------------------------------------------ plumbing
    def _receive(self) -> tuple[str, int, Any]:
        while True:
            try:
                return self._outbox.get(timeout=1.0)
            except queue.Empty:
                dead = [p for p in self._processes if not p.is_alive()]
                if dead:
                    raise RuntimeError(f"env worker {dead[0].name} died (exit code {dead[0].exitcode})") from None

    def _run_all(self, kind: str, payloads: list[Any]) -> list[Any]:
        """Job ``kind`` on every sub-env (payload i for sub-env i); results in sub-env order."""
        chunks, start = [], 0
        for n in self._counts:
            chunks.append(payloads[start : start + n])
            start += n
        if self._inline is not None:
            return self._inline.run((kind, chunks[0]))
        for inbox, chunk in zip(self._inboxes, chunks, strict=True):
            inbox.put((kind, chunk))
        results: dict[int, list[Any]] = {}
        while len(results) < len(self._inboxes):
            tag, wid, payload = self._receive()
            if tag == "done":
                results[wid] = payload
        return [r for w in range(len(self._inboxes)) for r in results[w]]

    # ------------------------------------------------------------------ the env API
    def reset(self, seed: int | None = None) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """Reset every sub-env (seeded as ManiSkill seeds a batch, if ``seed`` is given)."""
        from mikasa_robo_rl.collect import episode_seed

        seeds = [None if seed is None else episode_seed(seed, i, self.num_envs) for i in range(self.num_envs)]
        results = self._run_all("reset", seeds)
        return self._observations(results), {}

    def _observations(self, results: list[Any]) -> Any:
        """The batch of observations: from the shared blocks, or stacked from the results."""
        if self._shared is not None:
            return self._shared.read(self.device)
        return _stack([r[0] for r in results], self.device)

    def step(
        self, actions: torch.Tensor | np.ndarray
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        """One step of every sub-env with ``actions`` ``(num_envs, action_dim)``."""
        actions = np.asarray(actions.detach().cpu() if torch.is_tensor(actions) else actions, dtype=np.float32)
        if actions.shape != (self.num_envs, *self.single_action_space.shape):
            raise ValueError(
                f"actions have shape {actions.shape}; expected {(self.num_envs, *self.single_action_space.shape)}"
            )
        if not np.isfinite(actions).all():
            raise ValueError("actions contain NaN or inf")
        results = self._run_all("step", list(actions))
        obs = self._observations(results)
        reward, terminated, truncated = (_stack([r[k] for r in results], self.device) for k in (1, 2, 3))
        info: dict[str, Any] = {}
        finished = [("_final_info" in r[4]) and bool(np.asarray(r[4]["_final_info"]).any()) for r in results]
        if any(finished):
            # Sub-envs that did not finish contribute their current observation (masked out
            # by ``_final_info``), as ManiSkillVectorEnv's batch does.
            info["final_observation"] = _replace_rows(
                obs, {i: r[4]["final_observation"] for i, (r, f) in enumerate(zip(results, finished, strict=True)) if f}
            )
            # Metrics exist only for finished sub-envs; the others get zeros (masked out).
            template = next(r[4]["final_info"]["episode"] for r, f in zip(results, finished, strict=True) if f)
            blank = {k: np.zeros_like(v) for k, v in template.items()}
            info["final_info"] = {
                "episode": _stack(
                    [r[4]["final_info"]["episode"] if f else blank for r, f in zip(results, finished, strict=True)],
                    self.device,
                )
            }
            info["_final_info"] = torch.tensor(finished, device=self.device)
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Stop the workers (or close the in-process sub-envs)."""
        if self._inline is not None:
            self._inline.close()
            self._inline = None
        if self._processes:
            from mikasa_envs.workers import stop_processes

            for inbox in self._inboxes:
                inbox.put(None)
            stop_processes(self._processes, wait_s=3)
            self._processes = []
        if self._shared is not None:
            self._shared.close()
            self._shared = None

    def __enter__(self) -> CpuVectorEnv:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
