"""Which GPUs a command's processes use: runs the command and samples ``nvidia-smi`` meanwhile.

A pool whose workers each see every GPU opens a CUDA context per worker on each of them
(ManiSkill's reset forks torch's RNG on all visible devices) and renders on the first only;
`mikasa_envs.workers.use_one_gpu` shows each worker one GPU, round robin. This script is how
that was checked on a machine with several NVIDIA GPUs: for each GPU it prints the most processes seen at once,
the peak memory they held and the mean utilisation, and how many processes held a context on
more than one GPU (should be 0 besides the driver process of a trainer or an in-process policy).

    python benchmarks/gpu_processes.py --json gpus.json -- \\
        python benchmarks/bench_throughput.py --workers 32 --episodes 600 --skip-serial

Containers often hide other processes' pids from ``nvidia-smi``; the per-GPU utilisation and
memory are then still shown, the process counts are not.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import defaultdict
from typing import Any


def _query(kind: str, fields: str) -> list[list[str]]:
    """Rows of ``nvidia-smi --query-<kind>=<fields>`` (empty if nvidia-smi fails)."""
    try:
        out = subprocess.run(
            ["nvidia-smi", f"--query-{kind}={fields}", "--format=csv,noheader,nounits"],
            capture_output=True,
            text=True,
            timeout=20,
        ).stdout
    except (OSError, subprocess.TimeoutExpired):
        return []
    return [[c.strip() for c in line.split(",")] for line in out.splitlines() if line.strip()]


def _number(text: str) -> float:
    """A figure of nvidia-smi's (0 where it says ``[N/A]`` or the like)."""
    try:
        return float(text)
    except ValueError:
        return 0.0


def sample_while(command: list[str], every_s: float) -> dict[str, Any]:
    """Run ``command`` and sample the GPUs every ``every_s`` seconds until it exits."""
    gpus = {uuid: int(index) for uuid, index in _query("gpu", "uuid,index")}
    util: dict[int, list[float]] = defaultdict(list)
    peak_procs: dict[int, int] = defaultdict(int)
    peak_mem: dict[int, float] = defaultdict(float)
    gpus_of_pid: dict[str, set[int]] = defaultdict(set)
    t0 = time.perf_counter()
    child = subprocess.Popen(command)
    while child.poll() is None:
        for uuid, u in _query("gpu", "uuid,utilization.gpu"):
            util[gpus.get(uuid, -1)].append(_number(u))
        procs: dict[int, list[float]] = defaultdict(list)
        for uuid, pid, mem in _query("compute-apps", "gpu_uuid,pid,used_memory"):
            procs[gpus.get(uuid, -1)].append(_number(mem))
            gpus_of_pid[pid].add(gpus.get(uuid, -1))
        for gpu, mems in procs.items():
            peak_procs[gpu] = max(peak_procs[gpu], len(mems))
            peak_mem[gpu] = max(peak_mem[gpu], sum(mems))
        time.sleep(every_s)
    return {
        "command": command,
        "returncode": child.returncode,
        "wall_s": round(time.perf_counter() - t0, 1),
        "gpus": {
            str(index): {
                "peak_processes": peak_procs.get(index, 0),
                "peak_process_memory_mib": peak_mem.get(index, 0.0),
                "mean_utilization_pct": round(sum(util[index]) / len(util[index]), 1) if util[index] else None,
                "samples": len(util[index]),
            }
            for index in sorted(gpus.values())
        },
        "processes_seen": len(gpus_of_pid),
        "processes_on_several_gpus": sum(len(g) > 1 for g in gpus_of_pid.values()),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--every", type=float, default=2.0, help="seconds between samples")
    p.add_argument("--json", default=None, metavar="PATH", help="write the figures here")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND ARGS...")
    args = p.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        p.error("give the command to watch after --")
    report = sample_while(command, args.every)
    print(f"{' '.join(command)}: exit {report['returncode']} after {report['wall_s']} s "
          f"(CUDA_VISIBLE_DEVICES={os.environ.get('CUDA_VISIBLE_DEVICES', 'unset')})")
    for index, g in report["gpus"].items():
        print(f"  GPU {index}: up to {g['peak_processes']} processes, {g['peak_process_memory_mib']:.0f} MiB "
              f"at peak, {g['mean_utilization_pct']} % busy on average ({g['samples']} samples)")
    print(f"  processes seen: {report['processes_seen']}, on several GPUs: {report['processes_on_several_gpus']}")
    if args.json:
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(report, f, indent=2)
        os.replace(tmp, args.json)
    sys.exit(report["returncode"])


if __name__ == "__main__":
    main()
