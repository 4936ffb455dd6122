"""The light robot description and the fast controller path agree with ManiSkill's."""

from __future__ import annotations

import re

import numpy as np
import torch
from mani_skill.agents.controllers.pd_ee_pose import PDEEPoseController
from mikasa_envs import robot


def test_light_urdf_swaps_only_visual_meshes(tmp_path, monkeypatch):
    monkeypatch.setenv("MIKASA_CACHE_DIR", str(tmp_path))
    original = (robot.PANDA_DIR / "panda_v3.urdf").read_text()
    for meshes in ("original", "light"):
        text = robot.light_panda_urdf(meshes).read_text()
        files = re.findall(r'filename="([^"]+)"', text)
        assert len(files) == len(re.findall(r'filename="([^"]+)"', original))
        swapped = [f for f in files if str(tmp_path) in f]
        # The housing is a box in the light description (and only where the asset is missing
        # in the original one).
        assert any("d415" in f for f in swapped) == (meshes == "light" or not (robot.PANDA_DIR / robot.D415_MESH).exists())
        assert all("collision" not in f for f in swapped)
        assert any("link3" in f for f in swapped) == (meshes == "light")
        # The hand and fingers fill the wrist camera's view: never decimated.
        assert not any("hand" in f or "finger" in f for f in swapped)


def test_fast_controller_matches_maniskill(make_env):
    env = make_env("RememberColor3-VLA-v0")
    env.reset(seed=0)
    base = env.unwrapped
    arm = base.agent.controller.controllers["arm"]
    assert isinstance(arm, robot.FastPDEEPoseController) and arm._fast_path()
    rng = np.random.default_rng(0)
    for _ in range(15):
        action = rng.uniform(-1.5, 1.5, 7).astype(np.float32)
        base.agent.set_action(torch.from_numpy(action[None]))
        fast = arm._target_qpos.clone()
        PDEEPoseController.set_action(arm, torch.from_numpy(action[None, :6]))
        torch.testing.assert_close(fast, arm._target_qpos, atol=1e-5, rtol=0)
        env.step(action)


def test_quadric_decimation_keeps_the_shape():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4)
    light = robot.quadric_decimate(sphere, keep=0.2, crease_deg=15.0)
    assert 0.15 * len(sphere.faces) <= len(light.faces) <= 0.25 * len(sphere.faces)
    assert abs(np.linalg.norm(light.vertices, axis=1) - 1.0).max() < 0.02


def test_unknown_robot_meshes_value_names_the_choices(monkeypatch):
    import pytest

    monkeypatch.setenv("MIKASA_ROBOT_MESHES", "fancy")
    with pytest.raises(ValueError, match="light, original"):
        robot.robot_meshes()


def test_housing_box_has_the_original_outer_size():
    import trimesh

    box = trimesh.load(robot.d415_box_stl())
    assert len(box.faces) == 12
    original = robot.PANDA_DIR / robot.D415_MESH
    if original.exists():  # slim installs lack it
        np.testing.assert_allclose(box.bounds, trimesh.load(original).bounds, atol=5e-4)
