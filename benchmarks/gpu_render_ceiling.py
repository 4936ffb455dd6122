"""GPU render-only throughput: P processes x K scenes each, rendered through camera groups.

No physics: every process renders its K scenes (both 128x128 cameras each) in one camera
group pass, back to back, for a fixed time; all processes start together at a barrier and
are timed over the same window. This is the ceiling the bench's GPU workers run into.

    python benchmarks/gpu_render_ceiling.py 1x1 1x4 1x16 16x1 16x4 16x8
    python benchmarks/gpu_render_ceiling.py 16x4:panda          # robot hidden

A spec is ``PROCESSESxSCENES[:HIDE]``; HIDE is a comma-separated list of entity-name parts
whose render bodies are hidden. Measured on an H200 (2026-11-22): 1x1 792 scenes/s, 1x16
1,353, 16x1 750, 16x4 1,102, 16x8 1,213, 16x4 without the robot 1,611.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import time
from typing import Any

ENV_ID = "RememberColor3-VLA-v0"
DURATION_S = 6.0


def worker(k: int, hide: str, barrier: Any, results: Any) -> None:
    """Build ``k`` envs, render them in one group until the window closes; report passes."""
    os.environ["MIKASA_CAMERA_GROUP"] = "0"  # the envs' own groups stay unbuilt
    import gymnasium as gym
    import mikasa_envs  # noqa: F401  (registers the envs)
    import torch
    from mikasa_envs.camera_group import CameraGroupRenderer, env_cameras, env_render_device

    torch.set_num_threads(1)
    envs = [gym.make(ENV_ID, obs_mode="rgb", sim_backend="cpu") for _ in range(k)]
    for i, env in enumerate(envs):
        env.reset(seed=i)
    views = [env_cameras(env.unwrapped) for env in envs]
    for scene, _ in views:
        for body in scene.render_system.render_bodies:
            if hide and any(part in body.entity.name for part in hide.split(",")):
                body.visibility = 0.0
    group = CameraGroupRenderer(views, env_render_device(envs[0].unwrapped))
    for _ in range(5):
        group.render_all()
    barrier.wait()
    t0, passes = time.perf_counter(), 0
    while time.perf_counter() - t0 < DURATION_S:
        group.render_all()
        passes += 1
    results.put((passes, time.perf_counter() - t0))


def main(specs: list[str]) -> int:
    """Measure every spec given on the command line."""
    ctx = mp.get_context("spawn")
    for spec in specs or ["1x1", "16x4"]:
        shape, _, hide = spec.partition(":")
        p, k = (int(x) for x in shape.split("x"))
        barrier, results = ctx.Barrier(p), ctx.Queue()
        procs = [ctx.Process(target=worker, args=(k, hide, barrier, results)) for _ in range(p)]
        for proc in procs:
            proc.start()
        got = [results.get(timeout=300) for _ in procs]
        for proc in procs:
            proc.join()
        passes, window = sum(n for n, _ in got), max(w for _, w in got)
        print(
            f"{p} processes x {k} scenes{f' (hidden: {hide})' if hide else ''}: "
            f"{passes * k / window:.0f} scenes/s, {passes / window:.0f} passes/s",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
