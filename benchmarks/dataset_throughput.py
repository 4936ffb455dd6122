"""Conversion throughput of mikasa-datasets: NPZ -> RLDS, RLDS -> LeRobot, NPZ -> LeRobot.

Run inside the conversion environment (scripts/setup_datasets_envs.sh)::

    .venv-datasets/bin/python benchmarks/dataset_throughput.py                  # synthetic
    .venv-datasets/bin/python benchmarks/dataset_throughput.py --npz DIR        # collected data

Reports frames/s (wall clock, library imports excluded), CPU seconds (all threads) and
CPU-ms per frame, the machine's load average around each run (this box is shared: a load
above the core count inflates wall time), and the video PSNR of the LeRobot output against
the NPZ frames. Targets (issue 4): >= 1,000 frames/s NPZ -> RLDS, >= 300 frames/s for the
LeRobot paths on the 2-core machine.

Collection (``--paths collect``, or with the others): oracle episodes per minute of
``mikasa-collect`` for one task of every task family that has envs, with 1 and 2 workers
(``--collect-workers``), run in the simulator's environment (``.venv``; this script starts
it there); families without envs yet are listed as such::

    .venv-datasets/bin/python benchmarks/dataset_throughput.py --paths collect --collect-episodes 8

Short runs are start-up bound (with 2 workers, each worker process imports the simulator
and builds its env, ~8 s; with lavapipe the first build compiles shaders): the rate
"after start-up" (from the first finished attempt on) is printed beside the overall one,
and 2 workers only pay off overall over longer runs (``--collect-episodes 40``).

``--project [EPISODES]`` adds the whole plan projected from those rates: EPISODES (default
250, the published count) successful episodes of each of the 90 canonical tasks, its frames,
hours with the largest worker count measured, and NPZ disk. On a 16-core machine::

    python benchmarks/dataset_throughput.py --paths collect --collect-episodes 32 \
        --collect-workers 16 --project --sim-python "$(command -v python)" --json collect.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _cpu() -> float:
    """CPU seconds of this process and its finished children (parallel LeRobot writers)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def machine_speed() -> float:
    """Seconds for a 10M-iteration Python loop: this shared machine's speed drifts (the
    same conversion has run 2x apart hours apart); print it beside every figure."""
    t0 = time.perf_counter()
    total = 0
    for i in range(10_000_000):
        total += i
    return round(time.perf_counter() - t0, 2)


def _timed(label: str, fn, frames_hint: int | None = None) -> dict:
    load0 = os.getloadavg()[0]
    c0, t0 = _cpu(), time.perf_counter()
    result = fn()
    wall, cpu = time.perf_counter() - t0, _cpu() - c0
    frames = result.frames if frames_hint is None else frames_hint
    row = {
        "path": label,
        "episodes": result.episodes,
        "frames": frames,
        "wall_s": round(wall, 3),
        "frames_per_s": round(frames / wall, 1),
        "cpu_s": round(cpu, 3),
        "cpu_ms_per_frame": round(1000 * cpu / frames, 2),
        "load_before": round(load0, 2),
        "load_after": round(os.getloadavg()[0], 2),
    }
    print(
        f"{label:<16} {row['episodes']:>4} ep {frames:>6} frames  {row['frames_per_s']:>8.1f} frames/s  "
        f"cpu {row['cpu_ms_per_frame']:>6.2f} ms/frame  load {row['load_before']:.1f}->{row['load_after']:.1f}",
        flush=True,
    )
    return row


REPO = Path(__file__).resolve().parent.parent
SIM_PYTHON = REPO / ".venv" / "bin" / "python"
"""The simulator's interpreter (``--sim-python`` replaces it, e.g. on a machine whose
own Python has the packages)."""


def collect_child(env_id: str, episodes: int, workers: int, out: str) -> None:
    """(In the simulator's environment) collect, print the summary as one JSON line."""
    from mikasa_oracles.collect import collect

    s = collect(env_id, episodes, out, workers=workers, progress=False)
    row = {
        "env_id": env_id,
        "workers": workers,
        "episodes": s.new_episodes,
        "frames": s.frames,
        "wall_s": round(s.wall_s, 2),
        "episodes_per_min": round(s.episodes_per_min, 1),
        "startup_s": None if s.startup_s is None else round(s.startup_s, 2),
        "steady_episodes_per_min": round(s.steady_episodes_per_min, 1),
        "success_rate": round(s.success_rate, 3),
    }
    print("COLLECT " + json.dumps(row), flush=True)


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


def collection_rows(args: argparse.Namespace, work: Path) -> list[dict]:
    """Collect ``--collect-episodes`` oracle episodes per family representative (of
    ``--collect-families``, default all) and per count of ``--collect-workers``."""
    episodes = args.collect_episodes
    workers = [int(w) for w in args.collect_workers.split(",")]
    only = set(args.collect_families.split(",")) if args.collect_families else None
    sim_python = Path(args.sim_python)
    if not sim_python.is_file():
        print(f"collection: skipped, no simulator environment at {sim_python} (scripts/setup.sh)")
        return []
    tasks = manifest_rows(sim_python)
    reps, missing = family_representatives(tasks)
    if only:
        reps = {f: e for f, e in reps.items() if f in only}
    print(f"collection: {episodes} episodes per run; families without envs yet: {len(missing)}")
    rows = []
    for family, (horizon, env_id) in reps.items():
        for w in workers:
            out = work / f"collect_{family}_{w}"
            proc = subprocess.run(
                [
                    str(sim_python),
                    __file__,
                    "--_collect-child",
                    env_id,
                    str(episodes),
                    str(w),
                    str(out),
                ],
                capture_output=True,
                text=True,
            )
            lines = [x for x in proc.stdout.splitlines() if x.startswith("COLLECT ")]
            if proc.returncode != 0 or not lines:
                raise RuntimeError(f"collection of {env_id} failed:\n{proc.stdout}\n{proc.stderr}")
            row = {"path": "collect", "family": family, **json.loads(lines[-1][8:])}
            row["horizon"] = horizon
            row["bytes"] = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
            print(
                f"collect {family:<30} {env_id:<34} {w} worker(s) {row['episodes_per_min']:>6.1f} episodes/min, "
                f"{row['steady_episodes_per_min']:>6.1f} after start-up ({row['episodes']} ep, {row['frames']} frames, "
                f"{row['wall_s']:.1f} s, start-up {row['startup_s']} s, success {row['success_rate']:.0%})",
                flush=True,
            )
            rows.append(row)
            shutil.rmtree(out, ignore_errors=True)
    for family in missing:
        print(f"collect {family:<30} (no env yet)")
    if args.project and rows:
        rows.append(project_plan(rows, tasks, args.project))
    return rows


def project_plan(rows: list[dict], tasks: list, episodes_per_task: int) -> dict:
    """The whole published plan (``episodes_per_task`` successful episodes of every canonical
    task) projected from the measured families, with the largest worker count measured.

    Per task: frames = episodes x the representative's frames per episode x (the task's
    horizon / the representative's): the variants of a family differ mostly in phase lengths,
    which scale with the horizon (an estimate; the Long variants' episodes are longer). Time
    from the representative's rate after start-up (failed attempts included), disk from its
    bytes per frame."""
    most = max(r["workers"] for r in rows)
    measured = {r["family"]: r for r in rows if r.get("workers") == most and r["episodes"]}
    frames = seconds = size = 0.0
    covered, uncovered = 0, {}
    for family, horizon, env_id, _registered, canonical in tasks:
        if not canonical:
            continue
        rep = measured.get(family)
        if rep is None:
            uncovered.setdefault(family, []).append(env_id)
            continue
        per_episode = rep["frames"] / rep["episodes"] * horizon / rep["horizon"]
        task_frames = episodes_per_task * per_episode
        frames_per_s = rep["steady_episodes_per_min"] / 60 * rep["frames"] / rep["episodes"]
        frames += task_frames
        seconds += task_frames / frames_per_s
        size += task_frames * rep["bytes"] / rep["frames"]
        covered += 1
    plan = {
        "path": "plan",
        "workers": most,
        "episodes_per_task": episodes_per_task,
        "tasks": covered,
        "tasks_not_measured": uncovered,
        "frames": int(frames),
        "hours": round(seconds / 3600, 2),
        "disk_gb": round(size / 1e9, 1),
    }
    print(
        f"plan: {covered} canonical tasks x {episodes_per_task} episodes ~ {plan['frames'] / 1e6:.2f} M frames, "
        f"~{plan['hours']:.1f} h with {most} worker(s), ~{plan['disk_gb']:.1f} GB of NPZ"
        + (f"; not counted: {sum(map(len, uncovered.values()))} tasks of the {len(uncovered)} "
           "families not measured" if uncovered else ""),
        flush=True,
    )
    return plan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--npz", type=Path, help="an NPZ task directory to convert (default: synthetic data)"
    )
    parser.add_argument(
        "--episodes", type=int, default=60, help="synthetic episodes (default: %(default)s)"
    )
    parser.add_argument(
        "--min-len", type=int, default=20, help="synthetic episode length range (default: 20..60)"
    )
    parser.add_argument("--max-len", type=int, default=60)
    parser.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="with --npz: convert its episodes this many times over (a bigger task from a few real episodes)",
    )
    parser.add_argument(
        "--paths",
        default="npz-rlds,rlds-lerobot,npz-lerobot",
        help="comma-separated subset to run, of npz-rlds, rlds-lerobot, npz-lerobot, collect",
    )
    parser.add_argument(
        "--collect-episodes", type=int, default=8, help="episodes per collection run"
    )
    parser.add_argument("--collect-workers", default="1,2", help="worker counts to collect with")
    parser.add_argument(
        "--collect-families", help="comma-separated families (default: all with envs)"
    )
    parser.add_argument(
        "--project",
        type=int,
        nargs="?",
        const=250,
        metavar="EPISODES",
        help="with collect: project the whole plan, EPISODES (default 250, the published "
        "count) per canonical task, from the measured families",
    )
    parser.add_argument(
        "--sim-python",
        default=str(SIM_PYTHON),
        help="the simulator's Python (default: %(default)s)",
    )
    parser.add_argument("--_collect-child", nargs=4, help=argparse.SUPPRESS)
    parser.add_argument("--vcodec", help="LeRobot video codec (default: the converter's)")
    parser.add_argument(
        "--workers", type=int, help="LeRobot writer processes (default: the converter's)"
    )
    parser.add_argument("--json", type=Path, help="also write the rows as JSON here")
    parser.add_argument(
        "--keep", type=Path, help="work directory to keep (default: a deleted temp dir)"
    )
    args = parser.parse_args(argv)
    if args._collect_child:
        env_id, episodes, workers, out = args._collect_child
        collect_child(env_id, int(episodes), int(workers), out)
        return 0
    paths = set(args.paths.split(","))
    if paths == {"collect"}:
        work = Path(tempfile.mkdtemp(prefix="mikasa-collect-bench-"))
        try:
            rows = collection_rows(args, work)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
        return 0

    from mikasa_datasets import lerobot as lr
    from mikasa_datasets import rlds
    from mikasa_datasets.loaders import load_episodes, write_synthetic_task

    args.vcodec = args.vcodec or lr.DEFAULT_VCODEC

    # Library start-up (TensorFlow ~5 s, torch/lerobot ~5 s) is not conversion throughput.
    rlds._builder_class()
    lr.lerobot_dataset_class()

    work = args.keep or Path(tempfile.mkdtemp(prefix="mikasa-dataset-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        if args.npz and args.repeat > 1:
            from mikasa_datasets.npz import (
                read_metadata,
                summarize_episode,
                write_episode,
                write_metadata,
            )

            episodes = load_episodes(args.npz)
            npz_task = work / "data_npz" / args.npz.name
            summaries = []
            for i in range(len(episodes) * args.repeat):
                ep = dict(episodes[i % len(episodes)])
                ep["episode_seed"] = np.array(i, dtype=np.int64)  # distinct episodes on paper
                summaries.append(
                    summarize_episode(ep, write_episode(npz_task / f"train_data_{i}.npz", ep))
                )
            write_metadata(npz_task, read_metadata(args.npz)["env_id"], summaries)
        elif args.npz:
            npz_task = args.npz
        else:
            rng = np.random.default_rng(0)
            lengths = [int(x) for x in rng.integers(args.min_len, args.max_len + 1, args.episodes)]
            npz_task = write_synthetic_task(work / "data_npz", "RememberColor3-VLA-v0", lengths)
        speed = machine_speed()
        print(
            f"source: {npz_task}  (cores: {os.cpu_count()}, vcodec: {args.vcodec}, "
            f"machine speed: 10M-iteration Python loop {speed} s)"
        )
        rows = [{"path": "machine", "cores": os.cpu_count(), "python_loop_10m_s": speed}]
        rlds_dir = None
        if paths & {"npz-rlds", "rlds-lerobot"}:
            rows.append(
                _timed(
                    "npz->rlds",
                    lambda: rlds.convert_npz_to_rlds(npz_task, work / "data_rlds", overwrite=True),
                )
            )
            rlds_dir = rows and work / "data_rlds" / npz_task.name
        if "rlds-lerobot" in paths and rlds_dir is not None:
            rows.append(
                _timed(
                    "rlds->lerobot",
                    lambda: lr.convert_rlds_to_lerobot(
                        rlds_dir,
                        work / "lerobot_from_rlds",
                        overwrite=True,
                        vcodec=args.vcodec,
                        workers=args.workers,
                    ),
                )
            )
        if "npz-lerobot" in paths:
            rows.append(
                _timed(
                    "npz->lerobot",
                    lambda: lr.convert_npz_to_lerobot(
                        npz_task,
                        work / "lerobot_from_npz",
                        overwrite=True,
                        vcodec=args.vcodec,
                        workers=args.workers,
                    ),
                )
            )
            source = load_episodes(npz_task)
            back = load_episodes(work / "lerobot_from_npz" / npz_task.name)
            values = [
                lr.psnr(a["rgb"][..., c], b["rgb"][..., c])
                for a, b in zip(source, back, strict=True)
                for c in (slice(0, 3), slice(3, 6))
            ]
            allpix = lr.psnr(
                np.concatenate([a["rgb"] for a in source]), np.concatenate([b["rgb"] for b in back])
            )
            print(
                f"video PSNR ({args.vcodec}): {allpix:.2f} dB over all frames; per camera-episode min {min(values):.2f}, mean {np.mean(values):.2f} dB"
            )
            rows.append(
                {
                    "path": "psnr",
                    "vcodec": args.vcodec,
                    "all_frames_db": round(allpix, 2),
                    "min_db": round(min(values), 2),
                    "mean_db": round(float(np.mean(values)), 2),
                }
            )
        if "collect" in paths:
            rows += collection_rows(args, work)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
