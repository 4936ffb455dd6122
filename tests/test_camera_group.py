"""The GPU camera-group path: what can be checked without a GPU.

The pixels themselves are compared with ManiSkill's per-camera path on the GPU machine
(``benchmarks/gpu_camera_group_check.py``); here: the pose rows it uploads
are the right entities' poses, and CPU rendering never takes the path.
"""

from __future__ import annotations

import numpy as np
from mikasa_envs.camera_group import (
    CameraGroupRenderer,
    assign_pose_rows,
    check_pose_layout,
    packed_poses,
)


def test_pose_rows_hold_each_render_body_and_camera_pose(make_env):
    env = make_env("RememberColor3-VLA-v0", obs_mode="rgb")
    env.reset(seed=1)
    env.step(np.full(7, 0.5, np.float32))  # the arm moved: poses are not the build poses
    base = env.unwrapped
    scene = base.scene.sub_scenes[0]
    cameras = [s.camera._render_cameras[0] for s in base.scene.sensors.values()]
    rows = assign_pose_rows(scene, cameras)
    check_pose_layout(scene)
    packed = packed_poses(scene)[rows]
    owners = [b.entity for b in scene.render_system.render_bodies] + [c.entity for c in cameras]
    seen = {}
    for entity in owners:
        seen.setdefault(entity.global_id, entity)
    assert len(rows) == len(seen)
    for q_p, entity in zip(packed, seen.values(), strict=True):
        np.testing.assert_allclose(q_p[:4], entity.pose.q, atol=1e-6)
        np.testing.assert_allclose(q_p[4:], entity.pose.p, atol=1e-6)


def test_cpu_rendering_keeps_maniskills_path(make_env):
    env = make_env("RememberColor3-VLA-v0", obs_mode="rgb")
    env.reset(seed=0)
    assert not CameraGroupRenderer.supported(env.unwrapped)
    assert env.unwrapped._camera_group is None
