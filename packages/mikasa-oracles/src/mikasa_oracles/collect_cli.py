"""The ``mikasa-collect`` command line (the collection itself: :mod:`mikasa_oracles.collect`).

    mikasa-collect --env-id RememberColor3-VLA-v0 --num-episodes 250 --workers 2
    mikasa-collect --split all --workers 16 [--executor ray --ray-address auto]

Several tasks are checked first, then collected one after another; a task whose collection
fails does not stop the others. Exit status: 0 ok, 1 a collection failed, 2 bad input, 130
interrupted.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from typing import Any

from mikasa_oracles.collect import (
    DEFAULT_MIN_EPISODE_LENGTH,
    DEFAULT_NUM_EPISODES,
    DEFAULT_OUT,
    DEFAULT_START_SEED,
    EXECUTORS,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    SPLITS,
    CollectError,
    CollectionFailed,
    CollectionSummary,
    collect,
    open_pool,
    resolve_task,
)

__all__ = ["build_parser", "main", "selected_env_ids"]


def _int_at_least(low: int) -> Any:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be >= {low}, got {value}")
        return value

    parse.__name__ = f"integer >= {low}"
    return parse


def build_parser() -> argparse.ArgumentParser:
    """The ``mikasa-collect`` argument parser."""
    p = argparse.ArgumentParser(
        prog="mikasa-collect",
        description=(
            "Collect successful oracle demonstrations of a MIKASA-Robo-VLA task as NPZ episodes "
            "(<out>/data_npz/<dataset_name>/train_data_<i>.npz + metadata.json). Observations are "
            "rgb (two 128x128 cameras) + 7-D proprio, actions pd_ee_delta_pose, rewards "
            "normalized_dense. Re-running the same command resumes an interrupted collection."
        ),
    )
    tasks = p.add_mutually_exclusive_group(required=True)
    tasks.add_argument(
        "--env-id",
        action="append",
        default=None,
        help="task id, e.g. RememberColor3-VLA-v0 (repeatable: the tasks are collected one after another)",
    )
    tasks.add_argument(
        "--split",
        choices=SPLITS,
        default=None,
        help="every canonical task of a split (all: the 90 of the published dataset)",
    )
    p.add_argument(
        "--num-episodes",
        "--num-train-data",
        type=_int_at_least(1),
        default=DEFAULT_NUM_EPISODES,
        help=f"successful episodes wanted in total (default {DEFAULT_NUM_EPISODES})",
    )
    p.add_argument(
        "--out",
        "--path-to-save-data",
        default=DEFAULT_OUT,
        help=f"dataset root (default {DEFAULT_OUT})",
    )
    p.add_argument(
        "--workers",
        type=_int_at_least(1),
        default=1,
        help="parallel workers: local processes, or Ray actors with --executor ray (default 1)",
    )
    p.add_argument(
        "--envs-per-worker",
        type=_int_at_least(1),
        default=1,
        help="envs per local worker process, run in threads that render together (on a GPU: "
        "fewer render passes; the same files) (default 1)",
    )
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="where the workers run: local processes (default) or a Ray cluster (same files)",
    )
    p.add_argument(
        "--ray-address",
        default=None,
        help="Ray cluster to join with --executor ray (default: $RAY_ADDRESS, else a local Ray)",
    )
    p.add_argument(
        "--start-seed",
        "--seed",
        type=_int_at_least(0),
        default=DEFAULT_START_SEED,
        help=f"seed of attempt 0; attempt k uses start_seed + k (default {DEFAULT_START_SEED})",
    )
    p.add_argument(
        "--max-attempts",
        type=_int_at_least(1),
        default=None,
        help="attempts allowed in this run (default: 10 per missing episode, at least 100)",
    )
    p.add_argument(
        "--min-episode-length",
        type=_int_at_least(1),
        default=DEFAULT_MIN_EPISODE_LENGTH,
        help=f"discard successes shorter than this (default {DEFAULT_MIN_EPISODE_LENGTH}, as upstream)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--log-attempts",
        action="store_true",
        help="print one line per attempt (also on with MIKASA_LOG_EPISODE_LENGTHS=1)",
    )
    return p


def selected_env_ids(env_ids: Sequence[str] | None, split: str | None) -> list[str]:
    """The tasks of ``--env-id`` (in the given order, no repeats) or of ``--split`` (manifest
    order), each checked with :func:`resolve_task` before anything is collected."""
    if split is not None:
        from mikasa_envs.manifest import list_tasks

        env_ids = [t.env_id for t in list_tasks(split=None if split == "all" else split)]
    env_ids = list(env_ids or [])
    repeated = sorted({e for e in env_ids if env_ids.count(e) > 1})
    if repeated:
        raise CollectError(f"--env-id given more than once: {', '.join(repeated)}")
    for env_id in env_ids:
        resolve_task(env_id)
    return env_ids


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok, 1 failed, 2 bad input, 130 Ctrl-C).

    Several tasks are collected one after another, each into its own dataset directory; a
    task whose collection fails does not stop the others (exit status 1 at the end)."""
    parser = build_parser()
    args = parser.parse_args(argv)  # exits with status 2 on malformed arguments
    logging.getLogger("mani_skill").setLevel(logging.ERROR)
    try:
        env_ids = selected_env_ids(args.env_id, args.split)
    except CollectError as exc:
        print(f"mikasa-collect: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    failed: list[str] = []
    summaries: list[CollectionSummary] = []
    # Several tasks on local workers share one pool: its processes start once, not per task.
    runners = args.workers * args.envs_per_worker
    share = len(env_ids) > 1 and args.executor == "local" and runners > 1

    def new_pool() -> Any:
        return open_pool(runners, args.envs_per_worker) if share else None

    pool = new_pool()
    try:
        for k, env_id in enumerate(env_ids, 1):
            if len(env_ids) > 1:
                print(f"[{k}/{len(env_ids)}] {env_id}", file=sys.stderr, flush=True)
            try:
                summary = collect(
                    env_id,
                    args.num_episodes,
                    args.out,
                    workers=args.workers,
                    envs_per_worker=args.envs_per_worker,
                    start_seed=args.start_seed,
                    max_attempts=args.max_attempts,
                    min_episode_length=args.min_episode_length,
                    progress=not args.no_progress,
                    log_attempts=args.log_attempts,
                    executor=args.executor,
                    ray_address=args.ray_address,
                    pool=pool,
                )
            except CollectError as exc:
                print(f"mikasa-collect: error: {exc}", file=sys.stderr)
                return EXIT_USAGE
            except CollectionFailed as exc:
                print(f"mikasa-collect: collection failed: {exc}", file=sys.stderr)
                failed.append(env_id)
                if pool is not None:  # a worker may have died or left attempts in flight
                    pool.close(graceful=False)
                    pool = new_pool()
                continue
            except KeyboardInterrupt:
                print(
                    "mikasa-collect: interrupted; the episodes saved so far are kept — rerun the "
                    "same command to continue",
                    file=sys.stderr,
                )
                return EXIT_INTERRUPTED
            summaries.append(summary)
            print(summary.format(), flush=True)
    finally:
        if pool is not None:
            pool.close()
    if len(env_ids) > 1:
        new = sum(s.new_episodes for s in summaries)
        frames = sum(s.frames for s in summaries)
        wall = sum(s.wall_s for s in summaries)
        print(
            f"{len(summaries)}/{len(env_ids)} task(s) complete: {new} new episode(s), {frames} frames "
            f"in {wall:.1f} s" + (f"; failed: {', '.join(failed)}" if failed else "")
        )
    return EXIT_FAILED if failed else EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
