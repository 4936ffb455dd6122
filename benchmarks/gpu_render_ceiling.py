"""GPU render-only throughput: P processes x K scenes each, rendered through camera groups.

No physics: every process renders its K scenes (both 128x128 cameras each) in one camera
group pass, back to back, for a fixed time; all processes start together at a barrier and
are timed over the same window. This is the ceiling the bench's GPU workers run into.

    python benchmarks/gpu_render_ceiling.py 1x1 1x4 1x16 16x1 16x4 16x8
    python benchmarks/gpu_render_ceiling.py 16x4:panda          # robot hidden
    python benchmarks/gpu_render_ceiling.py 16x4@1 16x4@4       # at most 1 / 4 passes at once

    python benchmarks/gpu_render_ceiling.py 1x16/64 1x16/256     # cameras of 64x64, 256x256
    python benchmarks/gpu_render_ceiling.py 1x16+24               # 24 small boxes added

A spec is ``PROCESSESxSCENES[+BOXES][@CONCURRENT][/SIZE][:HIDE]``; BOXES adds that many
small boxes (12 triangles each, one draw each) in view of both cameras; CONCURRENT caps how many
processes render at the same time (a shared semaphore around each pass; default: no cap);
SIZE sets both cameras to SIZExSIZE (default: the env's 128x128); HIDE is a
comma-separated list of entity-name parts whose render bodies are hidden.

Measured on an H200 (2026-11-22): 1x1 792 scenes/s, 1x16 1,353, 16x1 750, 16x4 1,102, 16x8
1,213, 16x4 without the robot 1,611. On an H100 (same day): 1x1 1,090, 1x4 1,950, 1x16
2,300-2,400, 4x4 1,898, 8x4 1,812, 16x4 1,755-1,785; capping concurrent passes changes
little (16x4@1 1,810, @2 1,883, @4 1,828); camera size little (1x16/64 2,598, /256 1,762);
24 extra boxes (24 more draws) nothing (2,397); hiding the robot (24 draws, 53k vertices)
2.5x (5,900-6,100), hiding everything 8,606. So the GPU's cost is the robot's geometry, not
draws, pixels or process count; a cheaper vertex shader (no per-vertex matrix inverse)
measured the same. Pixel-identical rendering cannot go much past ~2,300 scenes/s there.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import time
from typing import Any

ENV_ID = "RememberColor3-VLA-v0"
DURATION_S = 6.0


def add_boxes(scene: Any, n: int) -> None:
    """``n`` small static grey boxes in a row above the table, one render body each."""
    import sapien

    material = sapien.render.RenderMaterial(base_color=[0.5, 0.5, 0.5, 1.0])
    for i in range(n):
        body = sapien.render.RenderBodyComponent()
        body.attach(sapien.render.RenderShapeBox([0.01, 0.01, 0.01], material))
        entity = sapien.Entity()
        entity.name = f"probe_box_{i}"
        entity.add_component(body)
        entity.set_pose(sapien.Pose([-0.1 + 0.3 * (i % 8) / 8, -0.15 + 0.1 * (i // 8), 0.05]))
        scene.add_entity(entity)


def worker(k: int, boxes: int, size: int, hide: str, slots: Any, barrier: Any, results: Any) -> None:
    """Build ``k`` envs, render them in one group until the window closes; report passes."""
    os.environ["MIKASA_CAMERA_GROUP"] = "0"  # the envs' own groups stay unbuilt
    import gymnasium as gym
    import mikasa_envs  # noqa: F401  (registers the envs)
    import torch
    from mikasa_envs.camera_group import CameraGroupRenderer, env_cameras, env_render_device

    torch.set_num_threads(1)
    extra = {"sensor_configs": {"width": size, "height": size}} if size else {}
    envs = [gym.make(ENV_ID, obs_mode="rgb", sim_backend="cpu", **extra) for _ in range(k)]
    for i, env in enumerate(envs):
        env.reset(seed=i)
    views = [env_cameras(env.unwrapped) for env in envs]
    for scene, _ in views:
        add_boxes(scene, boxes)
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
        if slots is None:
            group.render_all()
        else:
            with slots:
                group.render_all()
        passes += 1
    results.put((passes, time.perf_counter() - t0))


def main(specs: list[str]) -> int:
    """Measure every spec given on the command line."""
    ctx = mp.get_context("spawn")
    for spec in specs or ["1x1", "16x4"]:
        shape, _, hide = spec.partition(":")
        shape, _, size = shape.partition("/")
        shape, _, cap = shape.partition("@")
        shape, _, boxes = shape.partition("+")
        p, k = (int(x) for x in shape.split("x"))
        slots = ctx.BoundedSemaphore(int(cap)) if cap else None
        barrier, results = ctx.Barrier(p), ctx.Queue()
        procs = [ctx.Process(target=worker, args=(k, int(boxes or 0), int(size or 0), hide, slots, barrier, results)) for _ in range(p)]
        for proc in procs:
            proc.start()
        got = [results.get(timeout=300) for _ in procs]
        for proc in procs:
            proc.join()
        passes, window = sum(n for n, _ in got), max(w for _, w in got)
        print(
            f"{p} processes x {k} scenes{f' + {boxes} boxes' if boxes else ''}"
            f"{f', {cap} at once' if cap else ''}"
            f"{f', {size}x{size}' if size else ''}"
            f"{f' (hidden: {hide})' if hide else ''}: "
            f"{passes * k / window:.0f} scenes/s, {passes / window:.0f} passes/s",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
