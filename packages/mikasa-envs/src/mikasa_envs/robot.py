"""The Panda with wrist camera, with light visual meshes and a fast CPU controller.

Rendering cost is triangles: with lavapipe every vertex is CPU work, and on the GPU
machine (H100/H200, whose graphics units are few) triangles are part of what limits many
processes sharing one GPU. ManiSkill's ``panda_wristcam`` draws ~560k: a RealSense D415
housing of 425k and Panda link meshes of 135k. By default (``MIKASA_ROBOT_MESHES=light``):

* the D415 housing is a box of its outer size (12 triangles; the base camera sees it a few
  pixels large, the wrist camera not at all). Measured on lavapipe over 15 frames of random
  motion in 3 episodes against the original mesh: base camera PSNR 43.5 dB mean (42.7 dB
  worst), wrist camera identical, rgb steps ~1.4x faster than with a 34k-triangle
  clustered copy (the previous default). Slim ManiSkill installs, which lack the asset,
  render the same box, so every install draws the same pictures;
* the arm links 0-7 are quadric-decimated to 20% of their triangles (welded first, then
  smooth-shaded with a 15° crease angle): ~27k triangles instead of 135k. Measured the same
  way: hand camera unchanged (the links are not in its view), base camera PSNR 41.8 dB
  mean (35.6 dB worst frame), rgb steps ~1.9x faster;
* the hand and fingers keep their original meshes: they fill the wrist camera's view.

``MIKASA_ROBOT_MESHES=original`` keeps ManiSkill's meshes, housing included (the box only
where the asset is missing), for pixel parity with renders of the original robot.

Light meshes are generated from the installed ManiSkill assets on first use and cached
(``MIKASA_CACHE_DIR``, default ``~/.cache/mikasa-envs``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import sapien
import torch
from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.controllers.pd_ee_pose import PDEEPoseController, PDEEPoseControllerConfig
from mani_skill.agents.robots.panda.panda_wristcam import PandaWristCam
from mani_skill.utils.structs import Pose
from transforms3d.euler import euler2quat
from transforms3d.quaternions import qmult

if TYPE_CHECKING:  # trimesh is imported where meshes are generated, not at env import
    import trimesh

D415_MESH = "realsense2_description/meshes/d415.stl"
# Outer size of the D415 housing as ManiSkill's mesh spans it (metres), and its offset.
D415_BOX_EXTENTS = (0.0989, 0.023, 0.02005)
D415_BOX_CENTER = (0.0, 0.0, -0.010025)
PANDA_DIR = Path(PACKAGE_ASSET_DIR) / "robots" / "panda"
# Arm links: keep 20% of the triangles; normals split at creases sharper than 15°.
# Meshes below LINK_MIN_FACES (small caps and plates) are left as they are.
LINK_KEEP_FRACTION = 0.2
LINK_CREASE_DEG = 15.0
LINK_MIN_FACES = 200
LIGHT_LINK_MESH = re.compile(r"/visual/link\d\.glb$")
CACHE_VERSION = "4"
ROBOT_MESHES_ENV_VAR = "MIKASA_ROBOT_MESHES"
ROBOT_MESH_CHOICES = ("light", "original")


def cache_dir() -> Path:
    """Directory for generated assets (created if needed)."""
    path = Path(os.environ.get("MIKASA_CACHE_DIR", Path.home() / ".cache" / "mikasa-envs"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def _write_atomic(path: Path, data: bytes | str) -> None:
    mode = "wb" if isinstance(data, bytes) else "w"
    with tempfile.NamedTemporaryFile(mode, dir=path.parent, delete=False, suffix=".tmp") as f:
        f.write(data)
        tmp = f.name
    os.replace(tmp, path)


def quadric_decimate(mesh: trimesh.Trimesh, keep: float, crease_deg: float) -> trimesh.Trimesh:
    """Weld, quadric-decimate to ``keep`` of the faces, smooth-shade with a crease angle."""
    import fast_simplification
    import trimesh

    welded = mesh.copy()
    welded.merge_vertices(merge_tex=True, merge_norm=True)
    vertices, faces = fast_simplification.simplify(
        np.asarray(welded.vertices, dtype=np.float32), np.asarray(welded.faces), target_reduction=1.0 - keep
    )
    light = trimesh.Trimesh(vertices, faces, process=False)
    return trimesh.graph.smooth_shade(light, angle=np.radians(crease_deg), facet_minarea=None)


def d415_box_stl() -> Path:
    """The stand-in for the D415 housing: a box of its outer size, as STL (cached)."""
    import trimesh

    out = cache_dir() / f"v{CACHE_VERSION}_box_{D415_MESH.replace('/', '_')}"
    if not out.exists():
        box = trimesh.creation.box(extents=D415_BOX_EXTENTS)
        box.apply_translation(D415_BOX_CENTER)
        _write_atomic(out, box.export(file_type="stl"))
    return out


def _light_link_copy(rel: str) -> Path:
    """Light copy of the link asset ``PANDA_DIR/rel`` (a GLB scene), cached: every mesh of
    at least `LINK_MIN_FACES` faces `quadric_decimate`-d to `LINK_KEEP_FRACTION`."""
    import trimesh

    out = cache_dir() / f"v{CACHE_VERSION}_quadric{LINK_KEEP_FRACTION:g}_{rel.replace('/', '_')}"
    if out.exists():
        return out
    loaded = trimesh.load(PANDA_DIR / rel)
    scene = loaded if isinstance(loaded, trimesh.Scene) else trimesh.Scene(loaded)
    for name, geometry in list(scene.geometry.items()):
        if len(geometry.faces) < LINK_MIN_FACES:
            continue
        light = quadric_decimate(geometry, LINK_KEEP_FRACTION, LINK_CREASE_DEG)
        if hasattr(geometry.visual, "material"):
            light.visual = trimesh.visual.TextureVisuals(material=geometry.visual.material)
        scene.geometry[name] = light
    export = scene if isinstance(loaded, trimesh.Scene) else next(iter(scene.geometry.values()))
    _write_atomic(out, export.export(file_type=out.suffix.lstrip(".")))
    return out


def robot_meshes() -> str:
    """Which robot meshes to use: ``MIKASA_ROBOT_MESHES`` (``light``, the default, or
    ``original``)."""
    value = os.environ.get(ROBOT_MESHES_ENV_VAR, "light").strip().lower() or "light"
    if value not in ROBOT_MESH_CHOICES:
        raise ValueError(f"{ROBOT_MESHES_ENV_VAR}={value!r}; accepted values: {', '.join(ROBOT_MESH_CHOICES)}")
    return value


def light_panda_urdf(meshes: str | None = None) -> Path:
    """A copy of ManiSkill's ``panda_v3.urdf``; for ``meshes="light"`` (default from
    ``MIKASA_ROBOT_MESHES``) with the box housing and light arm-link meshes.

    Every other mesh path is made absolute so the copy can live outside the asset folder.
    """
    meshes = robot_meshes() if meshes is None else meshes
    if meshes not in ROBOT_MESH_CHOICES:
        raise ValueError(f"meshes={meshes!r}; accepted values: {', '.join(ROBOT_MESH_CHOICES)}")
    # The copy holds absolute paths into this ManiSkill installation: key it by that path.
    install = hashlib.sha1(str(PANDA_DIR).encode()).hexdigest()[:10]
    out = cache_dir() / f"panda_v3_light_v{CACHE_VERSION}_{meshes}_{install}.urdf"
    if out.exists():
        return out
    text = (PANDA_DIR / "panda_v3.urdf").read_text()

    def absolute(match: re.Match) -> str:
        rel = match.group(1)
        if rel == D415_MESH and (meshes == "light" or not (PANDA_DIR / rel).exists()):
            target = d415_box_stl()
        elif meshes == "light" and LIGHT_LINK_MESH.search(rel):
            target = _light_link_copy(rel)
        else:
            target = PANDA_DIR / rel
        return f'filename="{target}"'

    _write_atomic(out, re.sub(r'filename="([^"]+)"', absolute, text))
    return out


class FastPDEEPoseController(PDEEPoseController):
    """ManiSkill's delta EE-pose controller with a numpy fast path for single-env CPU sims.

    The reference computes the target pose with batched torch quaternion ops, which cost more
    than the physics for one env. For the canonical configuration (normalised delta actions,
    root translation with root-aligned rotation, no virtual target, no interpolation) this
    does the same arithmetic on SAPIEN poses and calls the same pinocchio IK; every other
    configuration, and GPU sims, go through ManiSkill's code unchanged.
    """

    def _fast_path(self) -> bool:
        cfg = self.config
        return (
            not self.scene.gpu_sim_enabled
            and self.scene.num_envs == 1
            and cfg.use_delta
            and not cfg.use_target
            and not cfg.interpolate
            and self._normalize_action
            and cfg.frame == "root_translation:root_aligned_body_rotation"
        )

    def set_action(self, action) -> None:
        if not self._fast_path():
            return super().set_action(action)
        a = action.detach().cpu().numpy().reshape(-1).astype(np.float64)
        if getattr(self, "_pos_bounds", None) is None:  # constant per controller; not per step
            self._pos_bounds = (
                self.action_space_low[:3].cpu().numpy(),
                self.action_space_high[:3].cpu().numpy(),
            )
        low, high = self._pos_bounds
        delta_pos = low + 0.5 * (np.clip(a[:3], -1.0, 1.0) + 1.0) * (high - low)
        delta_rot = a[3:6]
        norm = np.linalg.norm(delta_rot)
        if norm > 1:  # rotation is clipped by norm, then scaled by rot_lower (as ManiSkill)
            delta_rot = delta_rot / norm
        delta_rot = delta_rot * self.config.rot_lower
        ee_at_base = self.root_link._objs[0].entity_pose.inv() * self.ee_link._objs[0].entity_pose
        # Intrinsic XYZ Euler angles, applied on the root-aligned side of the current rotation.
        q = qmult(euler2quat(*delta_rot, axes="rxyz"), ee_at_base.q)
        q = q if q[0] >= 0 else -q  # the sign ManiSkill's torch path standardises to
        target = sapien.Pose(ee_at_base.p + delta_pos, q)
        self._step = 0
        self._target_pose = Pose.create_from_pq(
            torch.tensor(target.p[None], dtype=torch.float32, device=self.device),
            torch.tensor(target.q[None], dtype=torch.float32, device=self.device),
        )
        kin = self.kinematics
        qpos = self.articulation._objs[0].qpos
        result, success, _ = kin.pmodel.compute_inverse_kinematics(
            kin.end_link_idx,
            target,
            initial_qpos=qpos[kin.pmodel_active_joint_indices.cpu().numpy()],
            active_qmask=kin.qmask,
            max_iterations=100,
        )
        if success:
            targets = result[kin.pmodel_controlled_joint_indices.cpu().numpy()]
        else:
            targets = qpos[self.active_joint_indices.cpu().numpy()]
        self._target_qpos = torch.tensor(targets[None], dtype=torch.float32, device=self.device)
        for joint, value in zip(self.joints, targets, strict=True):
            joint._objs[0].set_drive_target(float(value))


class FastPDEEPoseControllerConfig(PDEEPoseControllerConfig):
    """``PDEEPoseControllerConfig`` that builds a ``FastPDEEPoseController``."""

    controller_cls = FastPDEEPoseController


class LightPandaWristCam(PandaWristCam):
    """``panda_wristcam`` (same uid, joints, cameras and controllers) with light visual
    meshes (see the module docstring) and the fast delta EE-pose controller on CPU."""

    @property
    def urdf_path(self) -> str:  # type: ignore[override]
        return str(light_panda_urdf())

    @property
    def _controller_configs(self):
        configs = super()._controller_configs
        for combined in configs.values():
            arm = combined.get("arm") if isinstance(combined, dict) else None
            if type(arm) is PDEEPoseControllerConfig:
                combined["arm"] = FastPDEEPoseControllerConfig(**{
                    f.name: getattr(arm, f.name) for f in dataclasses.fields(arm)
                })
        return configs
