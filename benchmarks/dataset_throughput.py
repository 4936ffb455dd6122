"""Conversion throughput of mikasa-datasets: NPZ -> RLDS, RLDS -> LeRobot, NPZ -> LeRobot.

Run inside the conversion environment (scripts/setup_datasets_envs.sh)::

    .venv-datasets/bin/python benchmarks/dataset_throughput.py                  # synthetic
    .venv-datasets/bin/python benchmarks/dataset_throughput.py --npz DIR        # collected data

Reports frames/s (wall clock, library imports excluded), CPU seconds (all threads) and
CPU-ms per frame, the machine's load average around each run (this box is shared: a load
above the core count inflates wall time), and the video PSNR of the LeRobot output against
the NPZ frames. Targets: >= 1,000 frames/s NPZ -> RLDS, >= 300 frames/s for the
LeRobot paths on a 2-core CPU machine.

Collection throughput (oracle episodes per minute, the whole plan projected) is
``benchmarks/collect_throughput.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
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
        help="comma-separated subset to run, of npz-rlds, rlds-lerobot, npz-lerobot",
    )
    parser.add_argument("--vcodec", help="LeRobot video codec (default: the converter's)")
    parser.add_argument(
        "--workers", type=int, help="LeRobot writer processes (default: the converter's)"
    )
    parser.add_argument("--json", type=Path, help="also write the rows as JSON here")
    parser.add_argument(
        "--keep", type=Path, help="work directory to keep (default: a deleted temp dir)"
    )
    args = parser.parse_args(argv)
    paths = set(args.paths.split(","))
    unknown = sorted(paths - {"npz-rlds", "rlds-lerobot", "npz-lerobot"})
    if unknown:
        parser.error(
            f"unknown --paths {unknown}; accepted: npz-rlds, rlds-lerobot, npz-lerobot "
            "(collection: benchmarks/collect_throughput.py)"
        )

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
        if args.json:
            args.json.write_text(json.dumps(rows, indent=2) + "\n")
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
