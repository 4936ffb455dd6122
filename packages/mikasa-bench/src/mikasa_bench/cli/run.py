"""The ``run`` and ``quickstart`` subcommands of ``mikasa-bench``: options to run
directories (``--resume`` included), the executor the options ask for, and the execution
with its table and report."""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mikasa_bench.cli.common import eprint, parse_policy_kwargs
from mikasa_bench.cli.parser import DEFAULT_SIM_BACKEND, QUICKSTART_POLICIES, QUICKSTART_TASKS
from mikasa_bench.errors import BenchError
from mikasa_bench.policies.loading import check_policy_supports, resolve_policy
from mikasa_bench.protocol import NUM_EPISODES_PER_TASK, OBS_MODE, START_SEED, BenchmarkConfig
from mikasa_bench.protocol.tasks import benchmark_commit, make_run_dir, resolve_tasks
from mikasa_bench.results.files import META_DIRNAME, RUN_META_FILENAME
from mikasa_bench.results.report import text_table, write_report
from mikasa_bench.results.run_data import load_run
from mikasa_bench.results.store import RunStore
from mikasa_bench.runners.executor import make_executor
from mikasa_bench.runners.lockstep import LockstepExecutor
from mikasa_bench.runners.runner import execute_runs

# Options that define a run; with --resume they come from the run directory instead.
_RUN_DEFINING = (
    "split",
    "task",
    "policy",
    "policy_kwargs",
    "num_episodes",
    "start_seed",
    "obs_mode",
    "sim_backend",
    "video",
    "render_device",
    "gpu_render_workers",
    "policy_batch",
    "out",
    "output_dir",
    "csv",
)


# ------------------------------------------------------------------------------------
# run / quickstart
# ------------------------------------------------------------------------------------


def _config(args: argparse.Namespace) -> BenchmarkConfig:
    try:
        return BenchmarkConfig(
            start_seed=START_SEED if args.start_seed is None else args.start_seed,
            n_episodes=NUM_EPISODES_PER_TASK if args.num_episodes is None else args.num_episodes,
            obs_mode=args.obs_mode or OBS_MODE,
            sim_backend=args.sim_backend or DEFAULT_SIM_BACKEND,
            save_videos=bool(args.video),
            render_device=args.render_device or "auto",
            gpu_render_workers=args.gpu_render_workers or 0,
            policy_batch=args.policy_batch or 1,
        )
    except ValueError as exc:
        raise BenchError(str(exc)) from None


def _resume_dirs(path: str) -> list[Path]:
    root = Path(path)
    if (root / META_DIRNAME / RUN_META_FILENAME).is_file():
        return [root]
    if root.is_dir():
        subs = sorted(p for p in root.iterdir() if (p / META_DIRNAME / RUN_META_FILENAME).is_file())
        if subs:
            return subs
    if not root.exists():
        raise BenchError(f"cannot resume: {root} does not exist")
    raise BenchError(
        f"cannot resume {root}: expected a run directory created by `mikasa-bench run` "
        f"(containing meta/run.json) or a directory of such runs"
    )


def _executor_from(args: argparse.Namespace) -> Any:
    """The executor the options ask for (raises on a bad combination, before anything is
    written)."""
    return make_executor(
        args.executor, args.workers, address=args.address, envs_per_worker=args.envs_per_worker
    )


def _lockstep_executor(args: argparse.Namespace, batch: int) -> Any:
    """The executor of a ``--policy-batch`` run (its envs are its own processes)."""
    given = [
        flag
        for flag, value in (
            ("--workers", getattr(args, "workers", None)),
            ("--address", getattr(args, "address", None)),
        )
        if value is not None
    ]
    if getattr(args, "executor", "local") != "local":
        given.append(f"--executor {args.executor}")
    if given:
        raise BenchError(
            f"a --policy-batch run plays its B episodes in env processes of its own (see "
            f"--envs-per-worker) with the policy in this process; do not pass {', '.join(given)}"
        )
    return LockstepExecutor(batch, getattr(args, "envs_per_worker", None))


def _execute_and_report(
    stores: list[Any],
    args: argparse.Namespace,
    report_dir: Path | None,
    report: bool = True,
    executor: Any = None,
) -> int:
    executor = executor if executor is not None else _executor_from(args)
    if any(s.config.policy_batch > 1 for s in stores):
        executor = _lockstep_executor(args, max(s.config.policy_batch for s in stores))
    dirs = ", ".join(str(s.run_dir) for s in stores)
    pending = sum(len(s.pending()) for s in stores)
    total = sum(s.config.n_episodes * len(s.tasks) for s in stores)
    desc = executor.describe()
    details = [f"{desc['workers']} workers"] if "workers" in desc else []
    if "policy_batch" in desc:
        details.append(f"{desc['policy_batch']} episodes in lockstep, one policy call per step")
    if desc.get("envs_per_worker", "auto") not in ("auto", 1):
        details.append(f"envs per worker: {desc['envs_per_worker']}")
    if "address" in desc:
        details.append(f"Ray at {desc['address']}")
    details.append(f"render {stores[0].config.render_description()}")
    eprint(
        f"running {pending} of {total} episodes with the {desc['name']} executor "
        f"({', '.join(details)}) -> {dirs}"
    )
    t0 = time.perf_counter()
    try:
        execute_runs(stores, executor, progress=not args.no_progress)
    except KeyboardInterrupt:
        eprint(
            f"\ninterrupted; finished episodes are saved. Continue with:\n"
            f"  mikasa-bench run --resume {_resume_hint(stores)}"
        )
        return 130
    except BenchError as exc:
        eprint(
            f"error: {exc}\n\nresults finished so far are kept in {dirs}; "
            f"continue with: mikasa-bench run --resume {_resume_hint(stores)}"
        )
        return 2
    wall = time.perf_counter() - t0
    runs = [load_run(s.run_dir, label=s.policy.label) for s in stores]
    print(text_table(runs))
    print(f"\nwall time {wall:.1f} s; results in {dirs}")
    if any(s.config.save_videos for s in stores):
        print("videos: " + ", ".join(str(s.run_dir / "videos") for s in stores))
    if report and report_dir is not None:
        md, html_path = write_report(runs, report_dir)
        print(f"report: {md}\n        {html_path}")
    return 0


def _resume_hint(stores: Sequence[Any]) -> str:
    if len(stores) == 1:
        return str(stores[0].run_dir)
    parents = {s.run_dir.parent for s in stores}
    return str(parents.pop()) if len(parents) == 1 else str(stores[0].run_dir)


def cmd_run(args: argparse.Namespace) -> int:
    """``mikasa-bench run``: evaluate policies on tasks (or ``--resume`` a run directory)."""
    executor = _executor_from(args)
    if args.resume:
        given = [
            f"--{k.replace('_', '-')}"
            for k in _RUN_DEFINING
            if getattr(args, k, None) not in (None, False)
        ]
        if given:
            raise BenchError(
                f"--resume takes every setting from the run directory; do not pass {', '.join(given)}"
            )
        stores = [RunStore.open(d) for d in _resume_dirs(args.resume)]
        report_dir = stores[0].run_dir if len(stores) == 1 else stores[0].run_dir.parent
        return _execute_and_report(stores, args, report_dir, not args.no_report, executor)

    if not args.split and not args.task:
        raise BenchError(
            "choose the tasks: --split {short,medium,long,all} or --task ENV_ID (or --resume DIR)"
        )
    if not args.policy:
        raise BenchError(
            "choose a policy: --policy zero | random | oracle | oracle-memoryless | module:Class | "
            "path/file.py[:Class] | ws://HOST:PORT | lerobot:DIR"
        )
    kwargs = parse_policy_kwargs(args.policy_kwargs)
    if kwargs and len(args.policy) > 1:
        raise BenchError("--policy-kwargs applies to a single --policy; run policies separately")
    config = _config(args)
    specs = [resolve_policy(name, kwargs) for name in args.policy]
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise BenchError(f"policies with the same name given twice: {labels}")
    selection = resolve_tasks(
        split=args.split, env_ids=args.task, strict=args.strict, csv_path=args.csv
    )
    for spec in specs:
        check_policy_supports(spec, [t.env_id for t in selection.tasks])

    if args.out:
        base = Path(args.out)
    else:
        label = selection.split if selection.split else "custom"
        base = make_run_dir(Path(args.output_dir or "results") / label)
    dirs = [base] if len(specs) == 1 else [base / s.label for s in specs]
    commit = benchmark_commit()
    stores = []
    for spec, d in zip(specs, dirs, strict=False):
        stores.append(
            RunStore.create(
                d,
                tasks=selection.tasks,
                policy=spec,
                config=config,
                selection=selection.to_dict(),
                commit=commit,
            )
        )
    return _execute_and_report(stores, args, base, not args.no_report, executor)


def cmd_quickstart(args: argparse.Namespace) -> int:
    """``mikasa-bench quickstart``: the oracle and zero policies on three short tasks."""
    if args.episodes < 1:
        raise BenchError(f"--episodes must be >= 1, got {args.episodes}")
    executor = _executor_from(args)
    config = BenchmarkConfig(
        n_episodes=args.episodes, obs_mode=args.obs_mode, sim_backend=DEFAULT_SIM_BACKEND
    )
    out = Path(args.out)
    selection = resolve_tasks(env_ids=list(QUICKSTART_TASKS))
    commit = benchmark_commit()
    stores = []
    for name in QUICKSTART_POLICIES:
        spec = resolve_policy(name)
        d = out / spec.label
        if d.exists() and any(d.iterdir()):
            store = RunStore.open(d)
            if store.config != config or [t.env_id for t in store.tasks] != list(QUICKSTART_TASKS):
                raise BenchError(
                    f"{d} holds a different evaluation (settings {store.config.to_dict()}); "
                    f"choose another --out"
                )
            eprint(
                f"{d}: continuing the existing quickstart run "
                f"({store.n_done_episodes} episodes already done)"
            )
        else:
            store = RunStore.create(
                d,
                tasks=selection.tasks,
                policy=spec,
                config=config,
                selection=selection.to_dict(),
                commit=commit,
            )
        stores.append(store)
    t0 = time.perf_counter()
    rc = _execute_and_report(stores, args, out, executor=executor)
    if rc == 0:
        print(f"quickstart total wall time {time.perf_counter() - t0:.1f} s")
    return rc
