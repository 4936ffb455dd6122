"""The GPU camera-group path: what can be checked without a GPU.

The pixels themselves are compared with ManiSkill's per-camera path on a GPU
(``benchmarks/gpu_camera_group_check.py``); here: the pose rows it uploads
are the right entities' poses, CPU rendering never takes the path, and its direct read of
the pictures gives ManiSkill's observations exactly.
"""

from __future__ import annotations

import numpy as np
import torch
from mikasa_envs.camera_group import (
    CAMERA_GROUP_ENV_VAR,
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


def test_cpu_rendering_takes_no_camera_group(make_env):
    env = make_env("RememberColor3-VLA-v0", obs_mode="rgb")
    env.reset(seed=0)
    assert not CameraGroupRenderer.supported(env.unwrapped)
    assert env.unwrapped._camera_group is None


def _sensor_frames(env) -> list[dict[str, torch.Tensor]]:
    obs, _ = env.reset(seed=5)
    frames = [obs["sensor_data"]]
    actions = np.random.default_rng(0).uniform(-1, 1, (6, 7)).astype(np.float32)
    for action in actions:
        obs, *_ = env.step(action)
        frames.append(obs["sensor_data"])
    return frames


def test_direct_picture_read_equals_maniskills_path(make_env, monkeypatch):
    direct = make_env("RememberColor3-VLA-v0", obs_mode="rgb")
    direct_frames = _sensor_frames(direct)
    assert direct.unwrapped._camera_view  # the direct read was taken
    monkeypatch.setenv(CAMERA_GROUP_ENV_VAR, "0")
    reference = make_env("RememberColor3-VLA-v0", obs_mode="rgb")
    reference_frames = _sensor_frames(reference)
    assert reference.unwrapped._camera_view is None
    for ours, theirs in zip(direct_frames, reference_frames, strict=True):
        assert ours.keys() == theirs.keys()
        for name in ours:
            a, b = ours[name]["rgb"], theirs[name]["rgb"]
            assert a.dtype == b.dtype == torch.uint8 and a.shape == b.shape == (1, 128, 128, 3)
            assert torch.equal(a, b)
