"""GPU check: the camera-group path (mikasa_envs/camera_group.py) gives the same pixels as
ManiSkill's per-camera path, step for step, with random actions; so do envs stepped by
several threads whose cameras render in shared passes (mikasa_envs/render_batcher.py).

    python benchmarks/gpu_camera_group_check.py RememberColor3-VLA-v0 FindImposterShape5-VLA-v0

Needs a CUDA GPU with Vulkan; prints the largest pixel difference of each step and exits 1
if more than `MAX_OVER_FRACTION` of the values differ by more than one level.
"""

from __future__ import annotations

import os
import sys
import threading

import gymnasium as gym
import mikasa_envs  # noqa: F401  (registers the envs)
import numpy as np
from mikasa_wrappers import apply_mikasa_vla_wrappers

STEPS = 10
# Poses reach the GPU as float32 on the group path and as transforms computed on the CPU on
# ManiSkill's: shading may round differently by one level, and a pixel whose centre lies on
# an edge may take the colour of the other side (seen: 14 of 4.3 M values in 4 threads).
TOLERANCE = 1
MAX_OVER_FRACTION = 1e-4


def make(env_id: str, group: bool) -> gym.Env:
    """The canonical rgb env with the camera group on or off (read when the env renders)."""
    os.environ["MIKASA_CAMERA_GROUP"] = "1" if group else "0"
    env = gym.make(env_id, obs_mode="rgb", control_mode="pd_ee_delta_pose", sim_backend="cpu")
    return apply_mikasa_vla_wrappers(env)


def compare(env_id: str) -> tuple[int, int]:
    """Values differing by more than `TOLERANCE` between the two paths over a reset and
    `STEPS` steps, and the number of values compared."""
    reference, grouped = make(env_id, False), make(env_id, True)
    obs = [reference.reset(seed=7)[0], grouped.reset(seed=7)[0]]
    if reference.unwrapped._camera_group is not None or grouped.unwrapped._camera_group is None:
        raise SystemExit("the camera-group path was not taken as asked (is there a CUDA GPU?)")
    rng = np.random.default_rng(0)
    largest, changed, over, total = [], [], 0, 0
    for step in range(STEPS + 1):
        if step:
            action = rng.uniform(-1, 1, 7).astype(np.float32)
            obs = [reference.step(action)[0], grouped.step(action)[0]]
        a, b = (o["rgb"].cpu().numpy().astype(np.int16) for o in obs)
        diff = np.abs(a - b)
        largest.append(int(diff.max()))
        changed.append(float((diff > 0).mean()))
        over, total = over + int((diff > TOLERANCE).sum()), total + diff.size
    print(
        f"{env_id}: largest pixel difference per step {largest}; "
        f"values differing: {100 * np.mean(changed):.3f}%",
        flush=True,
    )
    reference.close()
    grouped.close()
    return over, total


def _episode_images(env: gym.Env, seed: int, out: list[np.ndarray]) -> None:
    """Reset with ``seed``, then `STEPS` random steps (drawn from ``seed``): every rgb."""
    from mikasa_envs.render_batcher import participating

    rng = np.random.default_rng(seed)
    with participating():
        out.append(env.reset(seed=seed)[0]["rgb"].cpu().numpy())
        for _ in range(STEPS):
            action = rng.uniform(-1, 1, 7).astype(np.float32)
            out.append(env.step(action)[0]["rgb"].cpu().numpy())


def compare_threads(env_ids: list[str], threads: int = 4) -> tuple[int, int]:
    """Values differing by more than `TOLERANCE` between envs stepped by ``threads`` threads
    sharing render passes (tasks mixed) and the same episodes run one by one on ManiSkill's
    path, and the number of values compared."""
    from mikasa_envs import render_batcher

    ids = [env_ids[k % len(env_ids)] for k in range(threads)]
    reference = []
    for k, env_id in enumerate(ids):
        env = make(env_id, False)
        frames: list[np.ndarray] = []
        _episode_images(env, 100 + k, frames)
        reference.append(frames)
        env.close()
    batcher = render_batcher.install_batcher()
    try:
        envs = [make(env_id, True) for env_id in ids]
        batched: list[list[np.ndarray]] = [[] for _ in ids]
        workers = [
            threading.Thread(target=_episode_images, args=(env, 100 + k, batched[k]))
            for k, env in enumerate(envs)
        ]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        passes, pictures = batcher.passes, batcher.pictures
        for env in envs:
            env.close()
    finally:
        render_batcher.uninstall_batcher()
    over_all = total = 0
    for k, env_id in enumerate(ids):
        if len(batched[k]) != len(reference[k]):
            raise SystemExit(f"thread {k} ({env_id}) did not finish its episode")
        deltas = [np.abs(a.astype(np.int16) - b) for a, b in zip(reference[k], batched[k], strict=True)]
        diffs = [int(d.max()) for d in deltas]
        over = sum(int((d > TOLERANCE).sum()) for d in deltas)
        over_all, total = over_all + over, total + sum(d.size for d in deltas)
        print(
            f"thread {k} {env_id}: largest pixel difference per step {diffs}; values "
            f"differing by more than {TOLERANCE}: {over} of {sum(d.size for d in deltas)}",
            flush=True,
        )
    print(f"{threads} threads: {pictures} pictures in {passes} shared passes", flush=True)
    return over_all, total


def main() -> int:
    """Compare every env id given on the command line, alone and in shared passes."""
    env_ids = sys.argv[1:] or ["RememberColor3-VLA-v0"]
    counts = [compare(env_id) for env_id in env_ids] + [compare_threads(env_ids)]
    over, total = (sum(c[i] for c in counts) for i in (0, 1))
    ok = over <= MAX_OVER_FRACTION * total
    print(
        "CAMERA GROUP CHECK",
        "OK" if ok else "DIFFERS",
        f"({over} of {total} values differ by more than {TOLERANCE}/255; allowed "
        f"{MAX_OVER_FRACTION:.2%})",
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
