"""The ``mikasa-bench`` command line: list, run, quickstart, report, compare, serve.

Exit codes: 0 success; 1 ``compare`` found a significant regression; 2 a usage or
input error (the message says what was expected); 130 interrupted (results so far are
kept; ``run --resume DIR`` continues).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .errors import BenchError
from .gallery import add_gallery_parser, run_gallery
from .protocol import (
    CONTROL_MODE,
    NUM_EPISODES_PER_TASK,
    OBS_MODE,
    RENDER_DEVICES,
    REWARD_MODE,
    START_SEED,
    SUPPORTED_OBS_MODES,
    SUPPORTED_SPLITS,
    BenchmarkConfig,
)
from .validity import add_validity_parser, run_validity

__all__ = ["main", "build_parser", "QUICKSTART_TASKS", "QUICKSTART_POLICIES"]

QUICKSTART_TASKS: tuple[str, ...] = (
    "RememberColor3-VLA-v0",
    "FindImposterColor3-VLA-v0",
    "RememberShape3-VLA-v0",
)
QUICKSTART_POLICIES: tuple[str, ...] = ("oracle", "zero")
QUICKSTART_EPISODES = 2
QUICKSTART_WORKERS = 2
DEFAULT_SIM_BACKEND = "cpu"  # the local executor's workers each simulate one env on the CPU

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


def _eprint(*args: Any) -> None:
    print(*args, file=sys.stderr)


# ------------------------------------------------------------------------------------
# parser
# ------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of all subcommands."""
    p = argparse.ArgumentParser(
        prog="mikasa-bench",
        description="Evaluate policies on MIKASA-Robo-VLA with the canonical protocol.",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    ls = sub.add_parser("list", help="list the benchmark tasks (registered or not)")
    ls.add_argument("--split", choices=SUPPORTED_SPLITS, default="all")
    ls.add_argument("--memory-type", default=None, help="only this memory type (e.g. Object)")
    ls.add_argument("--registered-only", action="store_true", help="hide unregistered ids")

    run = sub.add_parser(
        "run",
        help="evaluate a policy on a split or on given tasks",
        description="Evaluate one or more policies. Canonical defaults: 50 episodes per task, "
        f"seeds {START_SEED}+i, obs {OBS_MODE}, control {CONTROL_MODE}, reward {REWARD_MODE}.",
    )
    sel = run.add_mutually_exclusive_group()
    sel.add_argument("--split", default=None, help=f"one of {', '.join(SUPPORTED_SPLITS)}")
    sel.add_argument(
        "--task", action="append", default=None, metavar="ENV_ID", help="an env id (repeatable)"
    )
    sel.add_argument(
        "--resume",
        default=None,
        metavar="DIR",
        help="continue an interrupted run directory (or a directory of runs)",
    )
    run.add_argument(
        "--policy",
        action="append",
        default=None,
        metavar="POLICY",
        help="zero | random | oracle | oracle-memoryless | module:Class | path/file.py[:Class] | ws://HOST:PORT "
        "(a policy server) | lerobot:DIR (a LeRobot pretrained_model directory; repeatable: "
        "each policy gets its own run directory)",
    )
    run.add_argument(
        "--policy-kwargs",
        default=None,
        metavar="JSON",
        help="keyword arguments for the policy, e.g. '{\"seed\": 1}'",
    )
    run.add_argument(
        "--num-episodes",
        type=int,
        default=None,
        help=f"episodes per task (canonical {NUM_EPISODES_PER_TASK})",
    )
    run.add_argument(
        "--start-seed", type=int, default=None, help=f"seed of episode 0 (canonical {START_SEED})"
    )
    run.add_argument(
        "--obs-mode",
        choices=SUPPORTED_OBS_MODES,
        default=None,
        help="rgb (canonical) or state (fast, NON-canonical, recorded as such)",
    )
    run.add_argument(
        "--sim-backend", default=None, help=f"ManiSkill sim backend (default {DEFAULT_SIM_BACKEND})"
    )
    run.add_argument(
        "--video",
        action="store_true",
        default=None,
        help="record every episode as videos/<env_id>/episode_<i>.mp4 (scene view with the "
        "task's overlays beside the top and wrist cameras); results are unchanged",
    )
    run.add_argument(
        "--render-device",
        choices=RENDER_DEVICES,
        default=None,
        help="where workers render: auto (GPU if any, else CPU; default), cpu (lavapipe, "
        "also on a GPU machine) or gpu",
    )
    run.add_argument(
        "--gpu-render-workers",
        type=int,
        default=None,
        metavar="N",
        help="mixed pool, with --render-device cpu: the first N workers render on the GPU, "
        "the others on the CPU",
    )
    run.add_argument(
        "--policy-batch",
        type=int,
        default=None,
        metavar="B",
        help="play B episodes in lockstep with one policy call per step for all, the policy in "
        "this process and the envs in processes of --envs-per-worker each: for learned "
        "policies on a GPU (lerobot:DIR, or a class with forward_batch); replaces --workers; a "
        "stochastic policy's results depend on B",
    )
    out = run.add_mutually_exclusive_group()
    out.add_argument("--out", default=None, metavar="DIR", help="exact run directory")
    out.add_argument(
        "--output-dir",
        default=None,
        metavar="BASE",
        help="base directory; the run goes to BASE/<split>/<timestamp> (default results)",
    )
    run.add_argument("--csv", default=None, metavar="PATH", help="task manifest override")
    _add_exec_args(run, default_workers=None)
    run.add_argument(
        "--strict",
        action="store_true",
        help="error (instead of skipping) on unregistered tasks of a split",
    )
    run.add_argument("--no-report", action="store_true", help="skip the Markdown/HTML report")

    qs = sub.add_parser(
        "quickstart",
        help="oracle and zero policies on 3 short tasks, 2 episodes each; table + report",
    )
    qs.add_argument("--out", default="results/quickstart", metavar="DIR")
    qs.add_argument("--episodes", type=int, default=QUICKSTART_EPISODES)
    qs.add_argument("--obs-mode", choices=SUPPORTED_OBS_MODES, default=OBS_MODE)
    _add_exec_args(qs, default_workers=QUICKSTART_WORKERS)

    rep = sub.add_parser("report", help="write report.md and report.html for result dirs")
    rep.add_argument(
        "dirs", nargs="+", metavar="DIR", help="result dirs, or shipped sets (reference:NAME)"
    )
    rep.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="where to write (default: the run dir, or the runs' common parent)",
    )
    rep.add_argument("--title", default=None)

    add_validity_parser(sub)
    add_gallery_parser(sub)
    cmp_ = sub.add_parser(
        "compare",
        help="per-task deltas of B against A; exit 1 if B is significantly worse on any task",
    )
    cmp_.add_argument(
        "dir_a", metavar="DIR_A", help="baseline: a result dir, or a shipped reference:NAME"
    )
    cmp_.add_argument("dir_b", metavar="DIR_B", help="candidate: a result dir (or reference:NAME)")
    cmp_.add_argument("--alpha", type=float, default=0.05, help="significance level (0.05)")

    srv = sub.add_parser(
        "serve",
        help="serve a policy over a websocket (openpi's protocol) for run --policy ws://HOST:PORT",
        description="Serve a policy to `mikasa-bench run --policy ws://HOST:PORT`: msgpack over "
        "a websocket, one policy instance per connection (pip install 'mikasa-bench[remote]').",
    )
    srv.add_argument(
        "--policy",
        required=True,
        metavar="POLICY",
        help="zero | random | module:Class | path/file.py[:Class] | lerobot:DIR (not oracle or "
        "oracle-memoryless: they read the env's state)",
    )
    srv.add_argument(
        "--policy-kwargs", default=None, metavar="JSON", help="keyword arguments for the policy"
    )
    srv.add_argument("--port", type=int, default=8000, help="port to listen on (default 8000)")
    srv.add_argument(
        "--host", default="0.0.0.0", help="address to listen on (default 0.0.0.0: every one)"
    )
    return p


def _add_exec_args(p: argparse.ArgumentParser, default_workers: int | None) -> None:
    p.add_argument(
        "--workers",
        type=int,
        default=default_workers,
        help="worker processes (default: CPU count; 0 = run in this process)",
    )
    p.add_argument(
        "--executor",
        default="local",
        choices=("local", "ray"),
        help="local: worker processes on this machine (default); ray: Ray actors spread "
        "over a cluster (pip install 'mikasa-bench[ray]')",
    )
    p.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="Ray cluster to join (default: $RAY_ADDRESS, else start Ray locally); "
        "with --executor ray, --workers defaults to the cluster's CPU count",
    )
    p.add_argument(
        "--envs-per-worker",
        type=int,
        default=None,
        metavar="K",
        help="envs each local worker process runs, one thread each; their cameras render in "
        "shared GPU passes (default: 4 for a worker rendering on the GPU, 1 on the CPU)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


# ------------------------------------------------------------------------------------
# list
# ------------------------------------------------------------------------------------


def _cmd_list(args: argparse.Namespace) -> int:
    from mikasa_oracles import has_oracle

    from .report import _format_rows
    from .tasks import registered_env_ids, select_benchmark_tasks

    tasks = select_benchmark_tasks(split=args.split)
    if args.memory_type:
        known = sorted({t.memory_type for t in tasks})
        if args.memory_type not in known:
            raise BenchError(
                f"unknown memory type {args.memory_type!r}; expected one of {', '.join(known)}"
            )
        tasks = [t for t in tasks if t.memory_type == args.memory_type]
    registered = registered_env_ids()
    rows = []
    for t in tasks:
        reg = t.env_id in registered
        if args.registered_only and not reg:
            continue
        rows.append(
            [
                t.env_id,
                t.split.title(),
                t.memory_type,
                str(t.max_episode_steps),
                "yes" if reg else "no",
                "yes" if has_oracle(t.env_id) else "no",
            ]
        )
    print(
        _format_rows(
            ["Env id", "Split", "Memory type", "Max steps", "Registered", "Oracle"], rows, right={3}
        )
    )
    n_reg = sum(r[4] == "yes" for r in rows)
    print(f"\n{len(rows)} task(s), {n_reg} registered")
    return 0


# ------------------------------------------------------------------------------------
# run / quickstart
# ------------------------------------------------------------------------------------


def _parse_kwargs(text: str | None) -> dict[str, Any]:
    if not text:
        return {}
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BenchError(
            f"--policy-kwargs must be a JSON object, e.g. '{{\"seed\": 1}}' ({exc})"
        ) from None
    if not isinstance(value, dict):
        raise BenchError("--policy-kwargs must be a JSON object, e.g. '{\"seed\": 1}'")
    return value


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
    from .results import META_DIRNAME, RUN_META_FILENAME

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
    from .executor import make_executor

    return make_executor(
        args.executor, args.workers, address=args.address, envs_per_worker=args.envs_per_worker
    )


def _lockstep_executor(args: argparse.Namespace, batch: int) -> Any:
    """The executor of a ``--policy-batch`` run (its envs are its own processes)."""
    from .lockstep import LockstepExecutor

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
    from .report import text_table, write_report
    from .results import load_run
    from .runner import execute_runs

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
    _eprint(
        f"running {pending} of {total} episodes with the {desc['name']} executor "
        f"({', '.join(details)}) -> {dirs}"
    )
    t0 = time.perf_counter()
    try:
        execute_runs(stores, executor, progress=not args.no_progress)
    except KeyboardInterrupt:
        _eprint(
            f"\ninterrupted; finished episodes are saved. Continue with:\n"
            f"  mikasa-bench run --resume {_resume_hint(stores)}"
        )
        return 130
    except BenchError as exc:
        _eprint(
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


def _cmd_run(args: argparse.Namespace) -> int:
    from .policies import check_policy_supports, resolve_policy
    from .results import RunStore
    from .tasks import benchmark_commit, make_run_dir, resolve_tasks

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
    kwargs = _parse_kwargs(args.policy_kwargs)
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


def _cmd_quickstart(args: argparse.Namespace) -> int:
    from .policies import resolve_policy
    from .results import RunStore
    from .tasks import benchmark_commit, resolve_tasks

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
            _eprint(
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


# ------------------------------------------------------------------------------------
# report / compare
# ------------------------------------------------------------------------------------


def _cmd_report(args: argparse.Namespace) -> int:
    from .reference import is_reference
    from .report import text_table, write_report
    from .results import load_run

    if not args.out and any(is_reference(d) for d in args.dirs):
        raise BenchError("reference result sets are read-only: give --out DIR for the report")
    runs = [load_run(d) for d in args.dirs]
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):
        # Same policy in several dirs: tell them apart by directory name.
        for r in runs:
            r.label = f"{r.label} ({r.run_dir.name})"
    if args.out:
        out = Path(args.out)
    elif len(runs) == 1:
        out = runs[0].run_dir
    else:
        out = Path(os.path.commonpath([str(r.run_dir.resolve()) for r in runs]))
    print(text_table(runs))
    md, html_path = write_report(runs, out, title=args.title)
    print(f"\nreport: {md}\n        {html_path}")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from .compare import compare_runs, format_comparison
    from .results import load_run

    a, b = load_run(args.dir_a), load_run(args.dir_b)
    if a.label == b.label:
        a.label, b.label = f"A: {a.label}", f"B: {b.label}"
    try:
        comp = compare_runs(a, b, alpha=args.alpha)
    except ValueError as exc:
        raise BenchError(str(exc)) from None
    print(format_comparison(comp))
    return 1 if comp.regressions else 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import logging

    from .policies import resolve_policy
    from .remote import PolicyServer

    spec = resolve_policy(args.policy, _parse_kwargs(args.policy_kwargs))
    server = PolicyServer(spec, host=args.host, port=args.port)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("websockets").setLevel(logging.WARNING)

    def ready(s: PolicyServer) -> None:
        _eprint(
            f"serving policy {spec.label or spec.target!r} on {args.host}:{s.port}; "
            f"evaluate it with: mikasa-bench run --policy ws://HOST:{s.port} ... (Ctrl-C stops)"
        )

    try:
        server.serve_forever(on_ready=ready)
    except KeyboardInterrupt:
        _eprint("stopped")
    return 0


_COMMANDS = {
    "list": _cmd_list,
    "run": _cmd_run,
    "quickstart": _cmd_quickstart,
    "report": _cmd_report,
    "compare": _cmd_compare,
    "serve": _cmd_serve,
    "validity": run_validity,
    "gallery": run_gallery,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mikasa-bench`` script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return _COMMANDS[args.command](args)
    except BenchError as exc:
        _eprint(f"error: {exc}")
        return 2
    except KeyboardInterrupt:
        _eprint("interrupted")
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
