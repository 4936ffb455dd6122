"""``mikasa-collect``: demonstration datasets from the scripted oracles (datasets spec §2-§5).

Rolls out a task's oracle through the canonical VLA wrapper chain (``obs_mode="rgb"``,
``pd_ee_delta_pose``, ``normalized_dense``, CPU simulation), keeps the successful
episodes and writes them as NPZ files through :mod:`mikasa_datasets.npz`::

    <out>/data_npz/<dataset_name>/train_data_<i>.npz   i = 0..N-1
    <out>/data_npz/<dataset_name>/metadata.json

Seeds and determinism
    Attempt ``k`` resets the env with seed ``start_seed + k`` (default start seed 0, as
    the upstream PPO collector: training seeds stay far below the benchmark's
    4242424242+). Failed attempts are skipped, so episode ``i`` is the ``i``-th successful
    attempt in seed order. An episode depends only on its seed (every attempt starts on a
    freshly built scene, as PhysX keeps contact caches across plain resets; the oracle is
    reset and the global RNGs seeded per attempt), so the same command writes
    byte-identical files, and any number of workers writes the same files as one.

Parallelism
    ``--workers W`` (W >= 2) starts W spawn-started processes (SAPIEN is not fork-safe),
    each with one env; with ``--executor ray``, W actors of a Ray cluster
    (:mod:`mikasa_oracles.collect_pools`). Seeds are handed out in order; a finished successful attempt is
    staged in ``data_npz/_batched/<dataset_name>/seed_<s>.npz`` and renamed to its final
    ``train_data_<i>.npz`` only once every smaller seed has finished, so indices follow
    seed order whatever the completion order. No more attempts are in flight than
    episodes still missing, so none is wasted at the end. ``W == 1`` runs in-process.

Resume
    Final files appear by atomic rename only, and ``metadata.json`` is rewritten after
    every new episode. Re-running the same command keeps ``train_data_0..n-1`` (checked),
    continues at the seed after the last kept episode and removes stale temporary and
    staged files. One collector per task directory at a time (an advisory lock).

Modules
    This one plans and commits a task's collection (:func:`collect`); one attempt (the
    per-worker episode loop) is :mod:`mikasa_oracles.collect_attempts`, the task
    directory's lock and resume checks :mod:`mikasa_oracles.collect_resume`, the pools
    :mod:`mikasa_oracles.collect_pools`, their shared errors
    :mod:`mikasa_oracles.collect_errors` and the command line
    :mod:`mikasa_oracles.collect_cli` (``mikasa-collect``, ``python -m
    mikasa_oracles.collect_cli``). Imports run one way: cli -> collect -> pools, resume,
    attempts -> errors.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mikasa_oracles.collect_attempts import (  # noqa: F401  (re-exported)
    CONTROL_MODE,
    REWARD_MODE,
    SIM_BACKEND,
    STAGED_PREFIX,
    AttemptResult,
    make_collection_env,
    seed_global_rngs,
)
from mikasa_oracles.collect_errors import CollectError, CollectionFailed
from mikasa_oracles.collect_pools import InlinePool, ProcessPool, RayPool
from mikasa_oracles.collect_resume import clean_staging, existing_episodes, locked_directory

__all__ = [
    "AttemptResult",
    "CollectError",
    "CollectionFailed",
    "CollectionSummary",
    "DEFAULT_MIN_EPISODE_LENGTH",
    "DEFAULT_NUM_EPISODES",
    "DEFAULT_OUT",
    "DEFAULT_START_SEED",
    "InlinePool",
    "ProcessPool",
    "RayPool",
    "collect",
    "default_max_attempts",
    "locked_directory",
    "resolve_task",
    "seed_global_rngs",
]

DEFAULT_NUM_EPISODES = 250
"""Episodes per task in the released data (spec §4)."""
SPLITS = ("short", "medium", "long", "all")
"""``--split`` values: the manifest's horizon splits, or all 90 canonical tasks."""
DEFAULT_OUT = "data_mikasa_robo"
"""Dataset root (spec §2)."""
DEFAULT_START_SEED = 0
"""Seed of attempt 0, as the upstream PPO collector (spec §5.1.3)."""
DEFAULT_MIN_EPISODE_LENGTH = 10
"""Successes shorter than this are discarded (upstream ``MIN_EPISODE_LENGTH_TO_SAVE``)."""
MAX_SEED = 2**32 - 1
"""ManiSkill seeds its episode RNG with ``numpy.random.RandomState``: seeds < 2**32."""


EXECUTORS = ("local", "ray")
"""``--executor`` values: local processes, or the actors of a Ray cluster."""

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
_TRUTHY = {"1", "true", "yes", "y", "on"}


# --------------------------------------------------------------------------- task checks
def resolve_task(env_id: str) -> Any:
    """The manifest row of ``env_id`` after checking that it can be collected.

    Raises :class:`CollectError` for an unknown id (with close matches from the manifest),
    a task whose family has no oracle, or a task not registered in this installation.
    """
    from mikasa_envs.manifest import UnknownEnvIdError, get_task

    from mikasa_oracles import ORACLES

    try:
        spec = get_task(env_id)
    except UnknownEnvIdError as exc:
        raise CollectError(str(exc)) from None
    if spec.family not in ORACLES:
        raise CollectError(
            f"no oracle for {env_id!r} (family {spec.family!r}); mikasa-collect supports the "
            f"families {', '.join(sorted(ORACLES))}"
        )
    import mikasa_envs  # registers the envs (imports the simulator)

    if env_id not in mikasa_envs.registered_env_ids():
        raise CollectError(
            f"{env_id!r} is in the manifest but not implemented in this installation"
        )
    return spec


def default_max_attempts(missing: int) -> int:
    """Attempt budget of one run when ``--max-attempts`` is not given: 10 per missing
    episode, at least 100 (an oracle far below 10 % success is broken, not unlucky)."""
    return max(100, 10 * missing)


# --------------------------------------------------------------------------- the collection
@dataclass
class CollectionSummary:
    """What one ``collect`` call did."""

    env_id: str
    dataset_dir: Path
    num_episodes: int
    existing_episodes: int
    new_episodes: int = 0
    attempts: int = 0
    successes: int = 0
    frames: int = 0
    wall_s: float = 0.0
    workers: int = 1
    seeds: tuple[int, int] | None = None
    reasons: dict[str, int] = field(default_factory=dict)
    startup_s: float | None = None
    """Wall time until the first attempt finished: worker start-up, env build, one episode."""

    @property
    def success_rate(self) -> float:
        """Successful attempts / attempts of this run (NaN if none)."""
        return self.successes / self.attempts if self.attempts else float("nan")

    @property
    def episodes_per_min(self) -> float:
        """New episodes per minute of wall time of this run."""
        return 60.0 * self.new_episodes / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def steady_episodes_per_min(self) -> float:
        """New episodes per minute after the first attempt finished (start-up excluded;
        NaN with fewer than two new episodes)."""
        if self.startup_s is None or self.new_episodes < 2 or self.wall_s <= self.startup_s:
            return float("nan")
        return 60.0 * (self.new_episodes - 1) / (self.wall_s - self.startup_s)

    def format(self) -> str:
        """Multi-line human-readable summary."""
        seeds = f" (seeds {self.seeds[0]}-{self.seeds[1]})" if self.seeds else ""
        rate = f"{100 * self.success_rate:.1f}%" if self.attempts else "n/a"
        others = {k: v for k, v in sorted(self.reasons.items()) if k != "saved"}
        rejected = (
            (", rejected: " + ", ".join(f"{k} {v}" for k, v in others.items())) if others else ""
        )
        return "\n".join(
            [
                f"{self.env_id}: {self.new_episodes} new episode(s), "
                f"{self.existing_episodes + self.new_episodes}/{self.num_episodes} in {self.dataset_dir}",
                f"  attempts: {self.attempts}{seeds}, successes: {self.successes}, success rate: {rate}{rejected}",
                f"  frames: {self.frames}, wall time: {self.wall_s:.1f} s, "
                f"{self.episodes_per_min:.1f} episodes/min with {self.workers} worker(s)",
            ]
        )


def open_pool(
    runners: int, envs_per_worker: int = 1, runner_args: tuple[Any, ...] | None = None
) -> InlinePool | ProcessPool:
    """A local pool of ``runners`` attempt runners, ``envs_per_worker`` to a process (in this
    process when ``runners`` is 1). Its runners are built for each job's task, so
    :func:`collect` can share it across tasks (``runner_args``: the first task's)."""
    if runners == 1:
        return InlinePool(runner_args)
    return ProcessPool(runner_args, -(-runners // envs_per_worker), envs_per_worker=envs_per_worker)


def collect(
    env_id: str,
    num_episodes: int,
    out: str | os.PathLike[str] = DEFAULT_OUT,
    *,
    workers: int = 1,
    envs_per_worker: int = 1,
    start_seed: int = DEFAULT_START_SEED,
    max_attempts: int | None = None,
    min_episode_length: int = DEFAULT_MIN_EPISODE_LENGTH,
    progress: bool = True,
    log_attempts: bool = False,
    executor: str = "local",
    ray_address: str | None = None,
    pool: Any = None,
) -> CollectionSummary:
    """Collect ``num_episodes`` successful oracle episodes of ``env_id`` under ``out``.

    Resumes what is already in ``<out>/data_npz/<dataset_name>/``. ``max_attempts`` bounds
    the attempts of this call (default :func:`default_max_attempts`). ``executor`` "local"
    runs ``workers`` local processes (in-process for 1), "ray" as many Ray actors
    (``ray_address``, ``$RAY_ADDRESS`` or a local Ray instance); the files are the same.
    ``envs_per_worker`` (local processes only) runs that many envs per process, in threads
    that render together (on a GPU: fewer render passes); the files are the same. ``pool``
    (from :func:`open_pool`) runs the attempts instead of a pool of this call's own, and is
    left open for the next task (the caller closes it, and replaces it after an exception:
    attempts may still be in flight). Raises
    :class:`CollectError` for bad input and :class:`CollectionFailed` if the budget runs
    out or a worker crashes; saved episodes stay valid in both cases.
    """
    from mikasa_datasets.npz import batched_dir as staging_dir_of
    from mikasa_datasets.npz import (
        episode_file_name,
        read_episode_summary,
        remove_stale_temp_files,
        task_dir,
        write_metadata,
    )

    for name, value, low in (
        ("num_episodes", num_episodes, 1),
        ("workers", workers, 1),
        ("envs_per_worker", envs_per_worker, 1),
        ("min_episode_length", min_episode_length, 1),
    ):
        if int(value) < low:
            raise CollectError(f"{name} must be >= {low}, got {value}")
    if executor not in EXECUTORS:
        raise CollectError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if envs_per_worker > 1 and executor != "local":
        raise CollectError(f"envs_per_worker > 1 needs the local executor, got {executor!r}")
    if max_attempts is not None and max_attempts < 1:
        raise CollectError(f"max_attempts must be >= 1, got {max_attempts}")
    if not 0 <= start_seed <= MAX_SEED:
        raise CollectError(f"start_seed must be in [0, {MAX_SEED}], got {start_seed}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CollectError(f"--out {out} exists and is not a directory")
    spec = resolve_task(env_id)

    t0 = time.perf_counter()
    directory = task_dir(out, env_id)
    staging = staging_dir_of(out, env_id)
    directory.mkdir(parents=True, exist_ok=True)
    summary = CollectionSummary(env_id, directory, num_episodes, 0, workers=workers)
    with locked_directory(directory):
        # A run killed mid-write leaves temporary files (never final names) and staged
        # attempts; both are redone deterministically.
        remove_stale_temp_files(directory)
        clean_staging(staging)
        committed = existing_episodes(directory, env_id, start_seed)
        summary.existing_episodes = len(committed)
        if len(committed) > num_episodes:
            raise CollectError(
                f"{directory} already holds {len(committed)} episodes, more than the "
                f"{num_episodes} requested; raise --num-episodes or use another --out"
            )

        def save_metadata() -> None:
            write_metadata(
                directory, env_id, committed, batched_source_dir=staging, unbatched_dir=directory
            )

        if committed:
            save_metadata()  # repairs a stale file (e.g. after deleting the last episode)
        if len(committed) == num_episodes:
            summary.wall_s = time.perf_counter() - t0
            return summary

        missing = num_episodes - len(committed)
        budget = max_attempts if max_attempts is not None else default_max_attempts(missing)
        first_seed = max(start_seed, committed[-1].episode_seed + 1) if committed else start_seed
        if first_seed > MAX_SEED:
            raise CollectError(f"no seeds left: the next seed {first_seed} exceeds {MAX_SEED}")
        staging.mkdir(parents=True, exist_ok=True)
        runner_args = (env_id, str(staging), min_episode_length, spec.language_instruction)
        own_pool = pool is None
        if own_pool:
            # Runners in all (processes x envs each), never more than the missing episodes.
            n_runners = min(workers * envs_per_worker, missing)
            if executor == "ray":
                pool = RayPool(runner_args, n_runners, address=ray_address)
            else:
                pool = open_pool(n_runners, min(envs_per_worker, n_runners), runner_args)
        n_runners = pool.slots
        log_attempts = (
            log_attempts or os.environ.get("MIKASA_LOG_EPISODE_LENGTHS", "").lower() in _TRUTHY
        )

        from tqdm.auto import tqdm

        bar = tqdm(
            total=num_episodes,
            initial=len(committed),
            desc=env_id,
            unit="ep",
            disable=not progress,
            dynamic_ncols=True,
        )
        pending: dict[int, AttemptResult] = {}
        in_flight: set[int] = set()
        next_seed = commit_seed = first_seed
        ok = False
        try:
            while len(committed) < num_episodes:
                # Never more attempts in flight than episodes could still be missing.
                staged_ok = sum(r.saved for r in pending.values())
                while (
                    len(in_flight) < n_runners
                    and summary.attempts < budget
                    and next_seed <= MAX_SEED
                    and len(committed) + len(in_flight) + staged_ok < num_episodes
                ):
                    pool.submit(next_seed, runner_args)
                    in_flight.add(next_seed)
                    next_seed += 1
                    summary.attempts += 1
                if not in_flight:
                    break  # budget spent
                result = pool.get()
                if summary.startup_s is None:
                    summary.startup_s = time.perf_counter() - t0
                in_flight.discard(result.seed)
                if result.error is not None:
                    raise CollectionFailed(
                        f"attempt with seed {result.seed} crashed:\n{result.error}"
                    )
                pending[result.seed] = result
                summary.reasons[result.reason] = summary.reasons.get(result.reason, 0) + 1
                summary.successes += result.saved
                if log_attempts:
                    bar.write(
                        f"[EPISODE] env={env_id} attempt={result.seed - first_seed} seed={result.seed} "
                        f"length={result.length} success={int(result.reason in ('saved', 'too_short'))} "
                        f"saved={int(result.saved)} reason={result.reason}"
                    )
                # Commit in seed order: an episode's index never depends on timing.
                while commit_seed in pending:
                    r = pending.pop(commit_seed)
                    commit_seed += 1
                    if not r.saved:
                        continue
                    final = directory / episode_file_name(len(committed))
                    os.replace(r.staged, final)
                    committed.append(read_episode_summary(final))
                    summary.new_episodes += 1
                    summary.frames += r.length
                    save_metadata()
                    bar.update(1)
                bar.set_postfix(
                    attempts=summary.attempts, success=f"{summary.successes}/{summary.attempts}"
                )
            ok = True
        finally:
            bar.close()
            if own_pool:
                pool.close(graceful=ok)
            clean_staging(staging)
            summary.wall_s = time.perf_counter() - t0
            if summary.attempts:
                summary.seeds = (first_seed, next_seed - 1)
        if len(committed) < num_episodes:
            raise CollectionFailed(
                f"only {len(committed)}/{num_episodes} episodes after {summary.attempts} attempts "
                f"(seeds {first_seed}-{next_seed - 1}, {summary.successes} kept); raise "
                f"--max-attempts and rerun to continue\n{summary.format()}"
            )
    return summary
