"""The Panda with wrist camera, with a light-weight camera housing mesh.

ManiSkill's ``panda_wristcam`` draws the wrist camera housing with a RealSense D415 mesh
of 425k triangles. On CPU rendering (lavapipe) that one mesh costs more than the rest of
the scene; a clustered copy of ~15k triangles looks the same at 128x128 and makes rgb
steps ~1.8x faster. The copy is generated from the installed ManiSkill asset on first use
and cached (``MIKASA_CACHE_DIR``, default ``~/.cache/mikasa-envs``). If the asset is
missing (slim ManiSkill wheels), a box of the D415's outer size stands in.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import tempfile
from pathlib import Path

import numpy as np
import sapien
import torch
from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.controllers.pd_ee_pose import PDEEPoseController, PDEEPoseControllerConfig
from mani_skill.agents.robots.panda.panda_wristcam import PandaWristCam
from mani_skill.utils.structs import Pose
from transforms3d.euler import euler2quat
from transforms3d.quaternions import qmult

D415_MESH = "realsense2_description/meshes/d415.stl"
PANDA_DIR = Path(PACKAGE_ASSET_DIR) / "robots" / "panda"
# Grid cell of the vertex clustering: 1.2 mm keeps the housing's bevels at 128 px.
CLUSTER_CELL_M = 0.0012
CACHE_VERSION = "1"


def cache_dir() -> Path:
    """Directory for generated assets (created if needed)."""
    path = Path(os.environ.get("MIKASA_CACHE_DIR", Path.home() / ".cache" / "mikasa-envs"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def cluster_decimate(
    vertices: np.ndarray, faces: np.ndarray, cell: float
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex-clustering decimation: merge vertices sharing a grid cell, drop degenerate faces."""
    keys = np.floor(vertices / cell).astype(np.int64)
    _, cluster_of_vertex, counts = np.unique(
        keys, axis=0, return_inverse=True, return_counts=True
    )
    cluster_of_vertex = cluster_of_vertex.reshape(-1)
    # Each cluster is represented by the mean of its vertices.
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, cluster_of_vertex, vertices)
    new_vertices = sums / counts[:, None]
    new_faces = cluster_of_vertex[faces]
    keep = (
        (new_faces[:, 0] != new_faces[:, 1])
        & (new_faces[:, 1] != new_faces[:, 2])
        & (new_faces[:, 0] != new_faces[:, 2])
    )
    new_faces = new_faces[keep]
    # Faces that collapse onto the same three clusters are duplicates.
    _, first = np.unique(np.sort(new_faces, axis=1), axis=0, return_index=True)
    return new_vertices, new_faces[np.sort(first)]


def _write_atomic(path: Path, data: bytes | str) -> None:
    mode = "wb" if isinstance(data, bytes) else "w"
    with tempfile.NamedTemporaryFile(mode, dir=path.parent, delete=False, suffix=".tmp") as f:
        f.write(data)
        tmp = f.name
    os.replace(tmp, path)


def light_d415_mesh() -> Path:
    """Path of the light camera-housing mesh, generating it on first use."""
    import trimesh

    out = cache_dir() / f"d415_light_v{CACHE_VERSION}.stl"
    if out.exists():
        return out
    source = PANDA_DIR / D415_MESH
    if source.exists():
        mesh = trimesh.load(source, force="mesh")
        vertices, faces = cluster_decimate(mesh.vertices, mesh.faces, CLUSTER_CELL_M)
        light = trimesh.Trimesh(vertices, faces, process=False)
    else:
        # Outer size of the D415 housing as the original mesh spans it (metres).
        light = trimesh.creation.box(extents=(0.0989, 0.023, 0.02005))
        light.apply_translation((0.0, 0.0, -0.010025))
    _write_atomic(out, light.export(file_type="stl"))
    return out


def light_panda_urdf() -> Path:
    """A copy of ManiSkill's ``panda_v3.urdf`` that uses the light housing mesh.

    Every other mesh path is made absolute so the copy can live outside the asset folder.
    """
    mesh = light_d415_mesh()
    # The copy holds absolute paths into this ManiSkill installation: key it by that path.
    install = hashlib.sha1(str(PANDA_DIR).encode()).hexdigest()[:10]
    out = cache_dir() / f"panda_v3_light_v{CACHE_VERSION}_{install}.urdf"
    if out.exists():
        return out
    text = (PANDA_DIR / "panda_v3.urdf").read_text()

    def absolute(match: re.Match) -> str:
        rel = match.group(1)
        target = mesh if rel == D415_MESH else PANDA_DIR / rel
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
        low, high = self.action_space_low[:3].cpu().numpy(), self.action_space_high[:3].cpu().numpy()
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
        for joint, value in zip(self.joints, targets):
            joint._objs[0].set_drive_target(float(value))


class FastPDEEPoseControllerConfig(PDEEPoseControllerConfig):
    """``PDEEPoseControllerConfig`` that builds a ``FastPDEEPoseController``."""

    controller_cls = FastPDEEPoseController


class LightPandaWristCam(PandaWristCam):
    """``panda_wristcam`` (same uid, joints, cameras and controllers) with the light housing
    mesh and the fast delta EE-pose controller on CPU."""

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
