"""Oracle-demonstration collection throughput, and what the whole published plan costs.

Collects oracle episodes with ``mikasa-collect``'s own code (``mikasa_oracles.collect``) for
the shortest task of every task family (``--families`` picks some) and each worker count
of ``--workers``, in the simulator's environment (``--sim-python``; default ``.venv``, so
this script also runs from the conversion environment), and prints per run episodes/min
overall and after start-up (from the first finished attempt on), frames per episode, and
NPZ bytes::

    python benchmarks/collect_throughput.py --episodes 8 --workers 1,2          # 2-core CPU machine
    python benchmarks/collect_throughput.py --episodes 32 --workers 16 --project \\
        --sim-python "$(command -v python)" --json collect32.json              # machine with 16 CPU cores

``--project [EPISODES]`` projects the whole plan (EPISODES, default 250 as published, of each
of the 90 canonical tasks: ``mikasa-collect --split all``) with the most envs collecting at
once that were measured (worker processes x ``--envs-per-worker``): frames, hours and NPZ disk. Per task, frames per episode come from its family's
representative, scaled by the task's horizon (the variants of a family differ mostly in
phase lengths), and bytes from the representative's bytes per frame.

Time. A worker rebuilds its scene for every attempt (``reset(options={"reconfigure":
True})``: the files must not depend on which worker ran which seed), so an episode costs a
fixed part plus a part per frame. Runs where every worker played at least
`LONG_RUN_EPISODES_PER_WORKER` episodes time that steady state; from two or more of them
(different episode lengths) the script fits ``seconds per episode per env = a + b x
frames`` and projects every task as ``start-up + episodes x (a + b x frames per episode) /
(envs x yield)`` (envs: worker processes x envs per process), where ``yield`` is the family's share of successful attempts and
start-up (the workers' imports and first scene, paid once per task) is the median over the
runs. Short runs are dominated by start-up and under-state the steady rate several times
(on a machine with one NVIDIA GPU and 16 CPU cores 32 episodes on 16 workers ran at 1/2-1/6 of the rate 256 did); without
two long runs the projection falls back to each family's after-start-up rate and says that
it is pessimistic.

``--rows-from FILE`` (repeatable) reads rows written earlier with ``--json`` instead of
collecting, e.g. a short run of every family plus long runs of a few::

    python benchmarks/collect_throughput.py --rows-from collect32.json \\
        --rows-from collect256.json --project
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
SIM_PYTHON = REPO / ".venv" / "bin" / "python"
"""The simulator's interpreter (``--sim-python`` replaces it, e.g. on a machine whose own
Python has the packages)."""

LONG_RUN_EPISODES_PER_WORKER = 8
"""A run times the steady state when each of its worker processes played this many
episodes (with several envs per process, they share them)."""


def collect_child(
    env_ids: list[str], episodes: int, workers: int, envs: int, out: str, shared: bool
) -> None:
    """(In the simulator's environment) collect each task in turn, print each summary as one
    JSON line; with ``shared`` on one pool of workers, as ``mikasa-collect`` runs several
    tasks, else on a pool per task."""
    from mikasa_datasets.npz import task_dir
    from mikasa_oracles.collect import collect, open_pool

    pool = open_pool(workers * envs, envs) if shared and workers * envs > 1 else None
    try:
        for env_id in env_ids:
            s = collect(
                env_id,
                episodes,
                out,
                workers=workers,
                envs_per_worker=envs,
                progress=False,
                pool=pool,
            )
            files = [f for f in task_dir(Path(out), env_id).rglob("*") if f.is_file()]
            row = {
                "env_id": env_id,
                "workers": workers,
                "envs_per_worker": envs,
                "shared_pool": shared,
                "episodes": s.new_episodes,
                "frames": s.frames,
                "wall_s": round(s.wall_s, 2),
                "episodes_per_min": round(s.episodes_per_min, 1),
                "startup_s": None if s.startup_s is None else round(s.startup_s, 2),
                "steady_episodes_per_min": round(s.steady_episodes_per_min, 1),
                "success_rate": round(s.success_rate, 3),
                "bytes": sum(f.stat().st_size for f in files),
            }
            print("COLLECT " + json.dumps(row), flush=True)
    finally:
        if pool is not None:
            pool.close()


def manifest_rows(sim_python: Path) -> list[tuple[str, int, str, bool, bool]]:
    """(family, horizon, env id, registered, canonical) of every manifest task, read in the
    simulator's environment."""
    code = (
        "import json, mikasa_envs\n"
        "from mikasa_envs.manifest import list_tasks\n"
        "reg = set(mikasa_envs.registered_env_ids())\n"
        "rows = [(t.family, t.max_episode_steps, t.env_id, t.env_id in reg, t.canonical)\n"
        "        for t in list_tasks()]\n"
        "print('FAMILIES ' + json.dumps(rows))\n"
    )
    out = subprocess.run(
        [str(sim_python), "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return json.loads(next(line for line in out.splitlines() if line.startswith("FAMILIES "))[9:])


def family_representatives(rows: list) -> tuple[dict[str, tuple[int, str]], list[str]]:
    """(family -> (horizon, env id) of its shortest-horizon registered task, families
    without envs)."""
    chosen: dict[str, tuple[int, str]] = {}
    for family, horizon, env_id, registered, _canonical in rows:
        if registered and (family not in chosen or horizon < chosen[family][0]):
            chosen[family] = (horizon, env_id)
    missing = sorted({family for family, *_ in rows} - set(chosen))
    return dict(sorted(chosen.items())), missing


def collection_rows(args: argparse.Namespace, tasks: list, work: Path) -> list[dict]:
    """Collect ``--episodes`` oracle episodes per family representative (of ``--families``,
    default all) and per count of ``--workers``; one row per run."""
    workers = [int(w) for w in args.workers.split(",")]
    reps, missing = family_representatives(tasks)
    if args.families:
        only = set(args.families.split(","))
        unknown = sorted(only - set(reps))
        if unknown:
            raise SystemExit(f"unknown --families {unknown}; accepted: {', '.join(reps)}")
        reps = {f: e for f, e in reps.items() if f in only}
    print(
        f"collection: {args.episodes} episodes per run; families without envs yet: {len(missing)}"
    )
    # One child per run; with --shared-pool one child per worker count runs every family
    # on one pool, as mikasa-collect runs several tasks.
    if args.shared_pool:
        runs = [(list(reps), w) for w in workers]
    else:
        runs = [([f], w) for f in reps for w in workers]
    horizon_of = {f: h for f, (h, _) in reps.items()}
    family_of = {e: f for f, (_, e) in reps.items()}
    rows = []
    for k, (families, w) in enumerate(runs):
        out, log = work / f"collect_{k}", work / f"collect_{k}.stderr"
        proc = subprocess.Popen(
            [
                str(args.sim_python),
                __file__,
                "--_child",
                ",".join(reps[f][1] for f in families),
                str(args.episodes),
                str(w),
                str(args.envs_per_worker),
                str(out),
                str(int(args.shared_pool)),
            ],
            stdout=subprocess.PIPE,
            stderr=log.open("w"),  # a file: a full stderr pipe would stall the child
            text=True,
        )
        for line in proc.stdout:
            if not line.startswith("COLLECT "):
                continue
            row = {"path": "collect", **json.loads(line[8:])}
            row["family"] = family = family_of[row["env_id"]]
            row["horizon"] = horizon_of[family]
            print(
                f"collect {family:<30} {row['env_id']:<34} {w}x{args.envs_per_worker} env(s) "
                f"{row['episodes_per_min']:>6.1f} episodes/min, {row['steady_episodes_per_min']:>6.1f} "
                f"after start-up ({row['episodes']} ep, {row['frames']} frames, {row['wall_s']:.1f} s, "
                f"start-up {row['startup_s']} s, success {row['success_rate']:.0%})",
                flush=True,
            )
            rows.append(row)
        if proc.wait() != 0:
            raise RuntimeError(f"collection run {k} failed:\n{log.read_text()[-4000:]}")
        shutil.rmtree(out, ignore_errors=True)
    for family in missing:
        print(f"collect {family:<30} (no env yet)")
    return rows


def _seconds_per_episode(row: dict) -> float:
    """An env's wall seconds per kept episode in the run's steady state."""
    return _runners(row) * 60.0 / row["steady_episodes_per_min"]


def _runners(row: dict) -> int:
    """Envs collecting at once in a run: worker processes x envs per process."""
    return row["workers"] * row.get("envs_per_worker", 1)


def fit_episode_cost(rows: list[dict]) -> dict | None:
    """Least-squares ``seconds per kept episode per env = a + b x frames per episode``
    over the long runs (`LONG_RUN_EPISODES_PER_WORKER`); None without two long runs of
    different episode lengths."""
    long_rows = [r for r in rows if r["episodes"] >= LONG_RUN_EPISODES_PER_WORKER * r["workers"]]
    x = np.array([r["frames"] / r["episodes"] for r in long_rows])
    if len(long_rows) < 2 or np.ptp(x) == 0:
        return None
    y = np.array([_seconds_per_episode(r) for r in long_rows])
    b, a = np.polyfit(x, y, 1)
    return {
        "episode_s": round(float(a), 4),
        "frame_s": round(float(b), 5),
        "runs": [f"{r['env_id']} ({r['episodes']} ep)" for r in long_rows],
        "max_rel_error": round(float(np.max(np.abs(a + b * x - y) / y)), 3),
    }


def project_plan(rows: list[dict], tasks: list, episodes_per_task: int) -> dict:
    """The whole published plan (``episodes_per_task`` successful episodes of every canonical
    task) projected from the measured families, with the most envs collecting at once measured
    (the module docstring says how)."""
    # Frames per episode, yield and bytes from every run (the files do not depend on how
    # many envs collect them); time from the runs with the most envs at once.
    rows = [r for r in rows if r["episodes"]]
    most = max(_runners(r) for r in rows)
    timed = [r for r in rows if _runners(r) == most]
    by_family: dict[str, list[dict]] = {}
    for r in rows:
        by_family.setdefault(r["family"], []).append(r)
    model = fit_episode_cost(timed)
    startup = statistics.median(r["startup_s"] for r in timed if r["startup_s"] is not None)
    frames = seconds = size = 0.0
    parts = {"startup": 0.0, "episodes": 0.0, "frames": 0.0}  # the model's three terms, seconds
    covered, uncovered = 0, {}
    for family, horizon, env_id, _registered, canonical in tasks:
        if not canonical:
            continue
        runs = by_family.get(family)
        timed_runs = [r for r in runs or [] if _runners(r) == most]
        if not runs or not (model or timed_runs):
            uncovered.setdefault(family, []).append(env_id)
            continue
        run_frames = sum(r["frames"] for r in runs)
        per_episode = run_frames / sum(r["episodes"] for r in runs) * horizon / runs[0]["horizon"]
        task_frames = episodes_per_task * per_episode
        if model:
            attempts = sum(r["episodes"] / r["success_rate"] for r in runs) / sum(
                r["episodes"] for r in runs
            )
            parts["startup"] += startup
            parts["episodes"] += episodes_per_task * attempts * model["episode_s"] / most
            parts["frames"] += episodes_per_task * attempts * model["frame_s"] * per_episode / most
        else:
            best = max(timed_runs, key=lambda r: r["episodes"])
            seconds += task_frames / (
                best["steady_episodes_per_min"] / 60 * best["frames"] / best["episodes"]
            )
        frames += task_frames
        size += task_frames * sum(r["bytes"] for r in runs) / run_frames
        covered += 1
    plan = {
        "path": "plan",
        "runners": most,
        "episodes_per_task": episodes_per_task,
        "tasks": covered,
        "tasks_not_measured": uncovered,
        "frames": int(frames),
        "hours": round((seconds + sum(parts.values())) / 3600, 2),
        "hours_by_part": {k: round(v / 3600, 2) for k, v in parts.items()} if model else None,
        "startup_s_per_task": startup if model else None,
        "model": model,
        "disk_gb": round(size / 1e9, 1),
    }
    how = (
        f"a + b x frames per episode per env, a = {model['episode_s']:.3f} s, b = "
        f"{1000 * model['frame_s']:.2f} ms (fit on {len(model['runs'])} long runs, worst "
        f"{model['max_rel_error']:.0%} off), start-up {startup:.1f} s per task; hours of frames "
        f"{parts['frames'] / 3600:.2f}, of per-episode cost {parts['episodes'] / 3600:.2f}, of "
        f"start-up {parts['startup'] / 3600:.2f}"
        if model
        else "each family's after-start-up rate of its longest run (no two runs long enough to "
        "fit the per-episode cost: pessimistic when the runs were short)"
    )
    print(
        f"plan: {covered} canonical tasks x {episodes_per_task} episodes ~ {plan['frames'] / 1e6:.2f} M frames, "
        f"~{plan['hours']:.2f} h with {most} env(s) collecting at once, ~{plan['disk_gb']:.1f} GB of NPZ; time from {how}"
        + (
            f"; not counted: {sum(map(len, uncovered.values()))} tasks of the {len(uncovered)} "
            "families not measured"
            if uncovered
            else ""
        ),
        flush=True,
    )
    return plan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--episodes", type=int, default=8, help="episodes per run (default: %(default)s)"
    )
    parser.add_argument(
        "--workers", default="1,2", help="worker counts to collect with (default: %(default)s)"
    )
    parser.add_argument(
        "--envs-per-worker",
        type=int,
        default=1,
        help="envs per worker process, in threads rendering together (default: %(default)s)",
    )
    parser.add_argument("--families", help="comma-separated families (default: all with envs)")
    parser.add_argument(
        "--project",
        type=int,
        nargs="?",
        const=250,
        metavar="EPISODES",
        help="project the whole plan, EPISODES (default 250, the published count) per "
        "canonical task, from the measured families",
    )
    parser.add_argument(
        "--rows-from",
        type=Path,
        action="append",
        metavar="FILE",
        help="rows written earlier with --json, instead of collecting (repeatable)",
    )
    parser.add_argument(
        "--sim-python",
        default=str(SIM_PYTHON),
        help="the simulator's Python (default: %(default)s)",
    )
    parser.add_argument("--json", type=Path, help="also write the rows (and the plan) as JSON here")
    parser.add_argument(
        "--shared-pool",
        action="store_true",
        help="collect the families one after another on one pool of workers, as mikasa-collect "
        "runs several tasks (start-up: the first task's includes the processes' start)",
    )
    parser.add_argument("--_child", nargs=6, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args._child:
        env_ids, episodes, workers, envs, out, shared = args._child
        collect_child(
            env_ids.split(","), int(episodes), int(workers), int(envs), out, shared == "1"
        )
        return 0
    if not Path(args.sim_python).is_file():
        raise SystemExit(
            f"no simulator environment at {args.sim_python} (scripts/setup.sh, or --sim-python)"
        )
    tasks = manifest_rows(Path(args.sim_python))
    if args.rows_from:
        rows = [
            r
            for f in args.rows_from
            for r in json.loads(f.read_text())
            if r.get("path") == "collect"
        ]
        if not rows:
            raise SystemExit(f"no collection rows in {', '.join(map(str, args.rows_from))}")
    else:
        work = Path(tempfile.mkdtemp(prefix="mikasa-collect-bench-"))
        try:
            rows = collection_rows(args, tasks, work)
        finally:
            shutil.rmtree(work, ignore_errors=True)
    if args.project:
        rows = rows + [project_plan(rows, tasks, args.project)]
    if args.json:
        tmp = args.json.with_name(args.json.name + ".tmp")
        tmp.write_text(json.dumps(rows, indent=2) + "\n")
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
