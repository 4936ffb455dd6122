"""``mikasa-rl-collect``: the datasets of the RL release (legacy_rl.md §6.1-6.2).

Rolls out an oracle on an RL task (``obs_mode="rgb"``, ``pd_joint_delta_pos``,
``normalized_dense``, CPU sim, the RL chain in ``rgb_joints`` mode, ``ManiSkillVectorEnv``
with ``ignore_terminations=True``) and writes every step up to the horizon ``T`` of every
episode (no success filter), one NPZ per episode (``mikasa_datasets.npz.RL_SCHEMA``)::

    <path>/MIKASA-Robo/unbatched/<env_id>/train_data_<n>.npz   n = 0 .. N-1
    <path>/MIKASA-Robo/summary_<env_id>.json                   settings and results

``rgb`` uint8 (T,128,128,6) and ``joints`` float32 (T,25) are the observation before step
t; ``action`` float32 (T,8) is clipped to [-1, 1] (what the controller executes);
``reward`` float32, ``success`` and ``done`` int64 (``terminated | truncated`` with
terminations ignored: 1 at the timeout step only) come after step t.

Policy: the scripted oracle (``mikasa_robo_rl.oracles.make_rl_oracle``), or with
``--ckpt-dir`` every ``<ckpt-dir>/oracle_checkpoints/ppo_memtasks/state/normalized_dense/
<env_id>/**/final_success_ckpt.pt`` (``AgentStateOnly``, mean action) acting on a
``state`` env stepped in lockstep with the rgb env (same seed and actions; CPU physics is
deterministic, rewards and successes are checked equal every step). Upstream wrote every
checkpoint's run into the same numbering, so later checkpoints overwrote earlier ones;
here checkpoint ``k`` (in path order) owns ``n = k*N .. k*N + N-1``.

Seeds: upstream reset batches of ``--batch-size`` GPU envs with seed ``b``. Episode
``n = b*batch_size + i`` (per checkpoint) resets one CPU env with the episode seed that
ManiSkill 3.0.1 gives env ``i`` of such a batch (``BaseEnv._set_episode_rng``): ``b`` for
``i = 0``, else ``RandomState(b).randint(2**31, size=batch_size - 1)[i - 1]``. The seeds
match upstream; the scenes cannot (a GPU batch draws its torch randomness from one stream).

Determinism and resume: every reset reconfigures the scene (after a plain reset CPU
PhysX keeps state, and ShellGameTouch/TakeItBack episodes then depend on the episodes the
env ran before) and the global RNGs get the episode seed, so a file depends only on
``(env_id, n, batch_size, policy)``: byte-identical for any ``--workers`` and any rerun
(``np.savez`` writes fixed zip timestamps). Episodes are the jobs of ``--workers``
spawn-started processes (the pool of ``mikasa_oracles.collect``). Files appear by atomic
rename only; a rerun skips finished files and deletes stale temporary ones. One collector
per directory at a time (advisory lock).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_robo_rl.manifest import UnknownEnvIdError, get_rl_task

try:  # the collect extra: the NPZ writer (mikasa-datasets); the VLA collector's pool, lock and errors
    from mikasa_datasets.npz import (
        EpisodeFormatError,
        episode_file_name,
        episode_index,
        list_episode_files,
        read_rl_episode_headers,
        remove_stale_temp_files,
        write_rl_episode,
    )
    from mikasa_oracles.collect import (
        CollectError,
        CollectionFailed,
        InlinePool,
        ProcessPool,
        locked_directory,
        seed_global_rngs,
    )
except ImportError:  # a base install: this module still imports (the old paths re-export it)
    ProcessPool = None

    class CollectError(ValueError):  # type: ignore[no-redef]
        """Bad input: exit 2."""

    class CollectionFailed(RuntimeError):  # type: ignore[no-redef]
        """The collection could not finish: exit 1."""


__all__ = [
    "DEFAULT_BATCH_SIZE", "DEFAULT_ENV_ID", "DEFAULT_NUM_TRAIN_DATA", "DEFAULT_PATH",
    "CollectError", "CollectionFailed", "EpisodeResult", "build_parser", "collect", "default_workers",
    "episode_seed", "main", "make_rl_collection_env", "summary_path", "unbatched_dir",
]

DEFAULT_ENV_ID = "ShellGameTouch-v0"
DEFAULT_PATH = "data_mikasa_robo"
DEFAULT_NUM_TRAIN_DATA = 1000
DEFAULT_BATCH_SIZE = 250
PROG = "mikasa-rl-collect"
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
_NEEDS_EXTRA = ('mikasa-rl-collect needs mikasa-oracles and mikasa-datasets (the collect extra): '
                'pip install "mikasa-robo-rl[collect]"')


@cache
def _batch_seeds(batch: int, batch_size: int) -> tuple[int, ...]:
    extra = np.random.RandomState(batch).randint(2**31, size=(batch_size - 1,))
    return (batch, *(int(s) for s in extra))


def episode_seed(batch: int, index: int, batch_size: int) -> int:
    """The episode seed of env ``index`` when ManiSkill 3.0.1 resets ``batch_size`` envs
    with ``seed=batch`` (``BaseEnv._set_episode_rng``)."""
    if not 0 <= index < batch_size:
        raise ValueError(f"index {index} is outside a batch of {batch_size}")
    return _batch_seeds(int(batch), int(batch_size))[index]


def default_workers() -> int:
    """Half the CPUs: an rgb env process keeps about two cores busy (physics plus CPU
    rendering), so one worker per core only adds start-up cost (measured on 2 cores)."""
    return max(1, (os.cpu_count() or 1) // 2)


def unbatched_dir(path: str | os.PathLike[str], env_id: str) -> Path:
    """``<path>/MIKASA-Robo/unbatched/<env_id>``: where the episode files go."""
    return Path(path) / "MIKASA-Robo" / "unbatched" / env_id


def summary_path(path: str | os.PathLike[str], env_id: str) -> Path:
    """``<path>/MIKASA-Robo/summary_<env_id>.json``."""
    return Path(path) / "MIKASA-Robo" / f"summary_{env_id}.json"


def make_rl_collection_env(env_id: str, mode: str = "rgb_joints") -> tuple[Any, Any]:
    """``(wrapped, vector_env)``: ``gym.make`` with the dataset's settings, the RL chain in
    ``mode``, then ``ManiSkillVectorEnv(ignore_terminations=True, record_metrics=True)``."""
    import gymnasium as gym
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    from mikasa_robo_rl.oracles import RL_CONTROL_MODE
    from mikasa_robo_rl.wrappers import apply_rl_wrappers, env_obs_mode

    env = gym.make(env_id, num_envs=1, obs_mode=env_obs_mode(mode), control_mode=RL_CONTROL_MODE,
                   reward_mode="normalized_dense", sim_backend="cpu")
    try:
        wrapped = apply_rl_wrappers(env, mode)
        return wrapped, ManiSkillVectorEnv(
            wrapped, 1, auto_reset=False, ignore_terminations=True, record_metrics=True
        )
    except BaseException:
        env.close()
        raise


def _checkpoints(ckpt_dir: str | os.PathLike[str], env_id: str) -> list[Path]:
    """The checkpoints to replay; usage errors (none, unloadable, wrong sizes) come here,
    before any worker starts."""
    from mikasa_robo_rl.agents import find_checkpoints, flatten_state_obs, load_agent

    try:
        found = find_checkpoints(ckpt_dir, env_id)
        agents = [load_agent(ckpt) for ckpt in found]
    except ValueError as exc:
        raise CollectError(str(exc)) from None
    venv = make_rl_collection_env(env_id, "state")[1]
    try:
        dims = (int(flatten_state_obs(venv.reset(seed=0)[0]).shape[1]), 8)
    finally:
        venv.close()
    for ckpt, agent in zip(found, agents, strict=True):
        if (agent.obs_dim, agent.action_dim) != dims:
            raise CollectError(f"{ckpt}: the agent maps {agent.obs_dim} -> {agent.action_dim}, "
                               f"{env_id} needs {dims[0]} -> {dims[1]}")
    return found


@dataclass(frozen=True)
class EpisodeResult:
    """One episode: index ``n``, seed, success at some step, return; or the error."""

    index: int
    seed: int = -1
    success_once: bool = False
    reward_sum: float = 0.0
    frames: int = 0
    error: str | None = None


def _first(x: Any) -> Any:
    """Element 0 of a (1, ...) tensor or array, as a numpy scalar."""
    return np.asarray(x.cpu() if hasattr(x, "cpu") else x).reshape(-1)[0]


class _EpisodeRunner:
    """Runs episodes of one task in one process: owns its env(s) and policy."""

    def __init__(self, env_id: str, directory: str, num_train_data: int, batch_size: int,
                 checkpoints: tuple[str, ...]) -> None:
        self.env_id, self.directory, self.checkpoints = env_id, Path(directory), checkpoints
        self.num_train_data, self.batch_size = num_train_data, batch_size
        self.horizon = get_rl_task(env_id).max_episode_steps
        self.venv: Any = None
        self.state_venv: Any = None
        self.oracle: Any = None
        self.agents: dict[int, Any] = {}

    def _ensure_envs(self) -> None:
        if self.venv is not None:
            return
        import torch

        torch.set_num_threads(1)  # the same float results in every process
        wrapped, self.venv = make_rl_collection_env(self.env_id, "rgb_joints")
        if self.checkpoints:
            self.state_venv = make_rl_collection_env(self.env_id, "state")[1]
        else:
            from mikasa_robo_rl.oracles import make_rl_oracle

            self.oracle = make_rl_oracle(wrapped)

    def run(self, n: int) -> EpisodeResult:
        """Roll out episode ``n`` and write its file; errors become ``error``."""
        try:
            return self._run(n)
        except Exception:
            self.close()  # maybe mid-episode or broken: rebuild for the next one
            return EpisodeResult(n, error=traceback.format_exc())

    def _policy(self, k: int) -> Any:
        """The act function of checkpoint ``k`` (obs of the state env -> raw action)."""
        import torch

        from mikasa_robo_rl.agents import flatten_state_obs, load_agent

        if k not in self.agents:
            self.agents[k] = load_agent(self.checkpoints[k])
        agent = self.agents[k]

        def act(state_obs: Any) -> Any:
            with torch.no_grad():
                return agent.get_action(flatten_state_obs(state_obs), deterministic=True)[0]

        return act

    def _run(self, n: int) -> EpisodeResult:
        self._ensure_envs()
        k, m = divmod(n, self.num_train_data)
        seed = episode_seed(m // self.batch_size, m % self.batch_size, self.batch_size)
        seed_global_rngs(seed)
        reset = {"seed": seed, "options": {"reconfigure": True}}
        obs, _ = self.venv.reset(**reset)
        if self.checkpoints:
            act, state_obs = self._policy(k), self.state_venv.reset(**reset)[0]
        else:
            self.oracle.reset()
        T = self.horizon
        ep = {"rgb": np.empty((T, 128, 128, 6), np.uint8), "joints": np.empty((T, 25), np.float32),
              "action": np.empty((T, 8), np.float32), "reward": np.empty(T, np.float32),
              "success": np.empty(T, np.int64), "done": np.empty(T, np.int64)}
        info: dict[str, Any] = {}
        for t in range(T):
            ep["rgb"][t] = obs["rgb"][0].cpu().numpy()
            ep["joints"][t] = obs["proprio"][0].cpu().numpy()
            raw = act(state_obs) if self.checkpoints else self.oracle.forward(obs)
            action = np.clip(np.asarray(raw, dtype=np.float32).reshape(-1), -1.0, 1.0)
            obs, reward, terminated, truncated, info = self.venv.step(action[None])
            ep["action"][t], ep["reward"][t] = action, _first(reward)
            ep["success"][t] = int(_first(info["success"]))
            ep["done"][t] = int(_first(terminated) or _first(truncated))
            if self.checkpoints:
                state_obs, s_reward, _, _, s_info = self.state_venv.step(action[None])
                if (_first(s_reward), int(_first(s_info["success"]))) != (
                    ep["reward"][t], ep["success"][t]):
                    raise RuntimeError(f"state and rgb envs diverged at step {t} (seed {seed})")
        write_rl_episode(self.directory / episode_file_name(n), ep)
        success_once = bool(_first(info["episode"]["success_once"]))
        return EpisodeResult(n, seed, success_once, float(ep["reward"].sum(dtype=np.float64)), T)

    def close(self) -> None:
        """Close the envs (the next episode builds fresh ones)."""
        for venv in (self.venv, self.state_venv):
            if venv is not None:
                try:
                    venv.close()
                except Exception:
                    pass
        self.venv = self.state_venv = self.oracle = None


def _write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _episodes_to_do(directory: Path, total: int, settings: dict[str, Any], summary: Path) -> list[int]:
    """Resume: check what ``directory`` holds (under the lock); the indices still missing."""
    remove_stale_temp_files(directory)  # a killed run's half-written files
    existing = list_episode_files(directory)
    if existing and episode_index(existing[-1]) >= total:
        raise CollectError(
            f"{directory} holds {existing[-1].name}, beyond the {total} episodes requested; "
            "raise --num-train-data or use another --path-to-save-data"
        )
    try:
        old = json.loads(summary.read_text(encoding="utf-8"))["settings"]
    except (OSError, ValueError, KeyError, TypeError):
        old = None
    # Seeds depend on the batch size; numbering on the policy (and N, per checkpoint).
    fixed = ["batch_size", "policy"] + (["num_train_data"] if settings["checkpoints"] else [])
    if existing and isinstance(old, dict) and any(old.get(k) != settings[k] for k in fixed):
        raise CollectError(
            f"{directory} was collected with {', '.join(f'{k}={old.get(k)!r}' for k in fixed)}; "
            "use the same settings or another --path-to-save-data"
        )
    for f in existing:
        try:
            read_rl_episode_headers(f)
        except EpisodeFormatError as exc:
            raise CollectError(f"cannot resume: {exc}; delete that file and rerun") from None
    return [n for n in range(total) if not (directory / episode_file_name(n)).exists()]


def collect(
    env_id: str = DEFAULT_ENV_ID,
    path: str | os.PathLike[str] = DEFAULT_PATH,
    num_train_data: int = DEFAULT_NUM_TRAIN_DATA,
    *,
    ckpt_dir: str | os.PathLike[str] | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    workers: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Collect ``num_train_data`` episodes of ``env_id`` (per checkpoint with ``ckpt_dir``)
    under ``path``, resuming what is there; returns the summary also written to
    :func:`summary_path`. Raises :class:`CollectError` for bad input and
    :class:`CollectionFailed` if an episode or a worker fails (finished files are kept)."""
    if ProcessPool is None:
        raise ImportError(_NEEDS_EXTRA)
    try:
        task = get_rl_task(env_id)
    except UnknownEnvIdError as exc:
        raise CollectError(str(exc)) from None
    if min(num_train_data, batch_size, 1 if workers is None else workers) < 1:
        raise CollectError("num_train_data, batch_size and workers must be >= 1")
    if num_train_data % batch_size:
        raise CollectError(
            f"--num-train-data {num_train_data} is not a multiple of --batch-size {batch_size}"
        )
    checkpoints = _checkpoints(ckpt_dir, env_id) if ckpt_dir is not None else []
    total = num_train_data * max(1, len(checkpoints))
    directory, summary_file = unbatched_dir(path, env_id), summary_path(path, env_id)
    settings = {"env_id": env_id, "num_train_data": num_train_data, "batch_size": batch_size,
                "policy": "checkpoints" if checkpoints else "scripted oracle",
                "checkpoints": [str(c) for c in checkpoints]}
    t0 = time.perf_counter()
    directory.mkdir(parents=True, exist_ok=True)
    with locked_directory(directory):
        todo = _episodes_to_do(directory, total, settings, summary_file)
        _write_json(summary_file, {"settings": settings, "complete": False})
        n_workers = max(1, min(workers or default_workers(), len(todo)))
        args = (env_id, str(directory), num_train_data, batch_size, tuple(map(str, checkpoints)))
        pool: Any = None
        if len(todo) and n_workers == 1:
            pool = InlinePool(args, _EpisodeRunner)
        elif todo:
            pool = ProcessPool(args, n_workers, _EpisodeRunner, job_attr="index", name=PROG)
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=total - len(todo), desc=env_id, unit="ep",
                   disable=not progress, dynamic_ncols=True)
        jobs, in_flight, first_s, ok = iter(todo), 0, None, False

        def submit_next() -> bool:
            n = next(jobs, None)
            if n is not None:
                pool.submit(n)
            return n is not None

        try:
            while in_flight < n_workers and submit_next():
                in_flight += 1
            while in_flight:
                result = pool.get()
                in_flight -= 1
                if result.error is not None:
                    raise CollectionFailed(f"episode {result.index} failed:\n{result.error}")
                first_s = first_s or time.perf_counter() - t0
                bar.update(1)
                in_flight += submit_next()
            ok = True
        finally:
            bar.close()
            if isinstance(pool, ProcessPool):
                pool.close(graceful=ok)
            elif pool is not None:
                pool.close()
        wall = time.perf_counter() - t0
        success = []  # (at some step, at the last step) per episode file
        for f in sorted(directory.glob("train_data_*.npz")):
            with np.load(f) as z:
                success.append((bool(z["success"].any()), bool(z["success"][-1])))
        rates = np.mean(success, axis=0).tolist() if success else [None, None]
        summary = {
            "settings": settings, "complete": True, "data_dir": str(directory),
            "episodes": len(success), "episode_length": task.max_episode_steps,
            "success_rate": rates[0], "success_at_end_rate": rates[1],
            "new_episodes": len(todo), "workers": n_workers if todo else 0,
            "wall_s": round(wall, 3), "first_episode_s": round(first_s or 0.0, 3),
            "frames_per_s": round(len(todo) * task.max_episode_steps / wall, 3),
            "episodes_per_min": round(60 * len(todo) / wall, 3),
        }
        _write_json(summary_file, summary)
    return summary


def build_parser() -> argparse.ArgumentParser:
    """The ``mikasa-rl-collect`` argument parser (the old underscore spellings too)."""
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Collect the RL release's datasets: <path>/MIKASA-Robo/unbatched/<env_id>/"
        "train_data_<n>.npz (rgb, joints, action, reward, success, done; every step up to the "
        "timeout, every episode). Rerunning the same command resumes.",
    )
    add = p.add_argument
    add("--env-id", "--env_id", default=DEFAULT_ENV_ID, help=f"RL env id (default {DEFAULT_ENV_ID})")
    add("--path-to-save-data", "--path_to_save_data", default=DEFAULT_PATH,
        help=f"dataset root (default {DEFAULT_PATH})")
    add("--ckpt-dir", "--ckpt_dir", default=None,
        help="replay the PPO state checkpoints <ckpt-dir>/oracle_checkpoints/ppo_memtasks/state/"
        "normalized_dense/<env_id>/**/final_success_ckpt.pt (or the shipped <ckpt-dir>/<env_id>/final_ckpt.pt: "
        "legacy/rl/baselines/checkpoints) instead of the scripted oracle")
    add("--num-train-data", "--num_train_data", type=int,
        default=DEFAULT_NUM_TRAIN_DATA,
        help=f"episodes (per checkpoint), a multiple of --batch-size (default {DEFAULT_NUM_TRAIN_DATA})")
    add("--batch-size", "--batch_size", type=int, default=DEFAULT_BATCH_SIZE,
        help=f"episodes per seed batch, upstream's GPU batch (default {DEFAULT_BATCH_SIZE})")
    add("--workers", type=int, default=None,
        help="worker processes (default: half the CPUs, at most the episodes to do)")
    add("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok, 1 failed, 2 bad input, 130 Ctrl-C)."""
    args = build_parser().parse_args(argv)  # exits with status 2 on malformed arguments
    if ProcessPool is None:
        print(f"{PROG}: error: {_NEEDS_EXTRA}", file=sys.stderr)
        return EXIT_USAGE
    import logging

    logging.getLogger("mani_skill").setLevel(logging.ERROR)
    try:
        s = collect(args.env_id, args.path_to_save_data, args.num_train_data,
                    ckpt_dir=args.ckpt_dir, batch_size=args.batch_size, workers=args.workers,
                    progress=not args.no_progress)
    except CollectError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except CollectionFailed as exc:
        print(f"{PROG}: collection failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; finished episodes are kept, rerun to continue", file=sys.stderr)
        return EXIT_INTERRUPTED
    rate = "n/a" if s["success_rate"] is None else f"{s['success_rate']:.3f}"
    print(f"{args.env_id}: {s['episodes']} episodes in {s['data_dir']} ({s['new_episodes']} new), "
          f"success rate {rate}, {s['wall_s']:.1f} s, {s['episodes_per_min']:.1f} episodes/min, "
          f"{s['frames_per_s']:.1f} frames/s")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
