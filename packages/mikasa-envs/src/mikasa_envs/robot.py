"""The Panda with wrist camera, with light visual meshes and a fast CPU controller.

ManiSkill's ``panda_wristcam`` draws the wrist camera housing with a RealSense D415 mesh
of 425k triangles. On CPU rendering (lavapipe) that one mesh costs more than the rest of
the scene; a clustered copy of ~15k triangles looks the same at 128x128 and makes rgb
steps ~1.8x faster, so it is always used. With ``MIKASA_LIGHT_ROBOT=1`` the Panda's link
meshes (135k triangles) are clustered too (4 mm cells, ~64k triangles): rgb steps get
another ~2x faster at a small cost in fidelity (base-camera PSNR ≈ 35 dB against the full
meshes), which suits RL training but not pixel parity with published datasets.

Light meshes are generated from the installed ManiSkill assets on first use and cached
(``MIKASA_CACHE_DIR``, default ``~/.cache/mikasa-envs``). If the D415 asset is missing
(slim ManiSkill wheels), a box of its outer size stands in.
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
# Clustering cells: 1.2 mm keeps the housing's bevels; 4 mm is below a base-camera pixel
# (~9 mm at the robot) for the links.
D415_CELL_M = 0.0012
LINK_CELL_M = 0.004
# Vertices whose normals differ by more than ~1 quantisation step are not merged, so hard
# edges keep their shading.
NORMAL_BUCKETS = 1.0
CACHE_VERSION = "2"
LIGHT_ROBOT_ENV_VAR = "MIKASA_LIGHT_ROBOT"


def cache_dir() -> Path:
    """Directory for generated assets (created if needed)."""
    path = Path(os.environ.get("MIKASA_CACHE_DIR", Path.home() / ".cache" / "mikasa-envs"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def cluster_decimate(
    vertices: np.ndarray, faces: np.ndarray, cell: float, normals: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertex-clustering decimation: merge vertices sharing a grid cell (and, if normals
    are given, a normal bucket), drop degenerate and duplicate faces.

    Returns (vertices, faces, normals) with each cluster at the mean of its members.
    """
    keys = np.floor(vertices / cell).astype(np.int64)
    if normals is not None:
        keys = np.concatenate([keys, np.round(normals * NORMAL_BUCKETS).astype(np.int64)], axis=1)
    _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.reshape(-1)

    def mean(values: np.ndarray) -> np.ndarray:
        sums = np.zeros((len(counts), values.shape[1]))
        np.add.at(sums, cluster, values)
        return sums / counts[:, None]

    new_normals = None
    if normals is not None:
        new_normals = mean(normals)
        new_normals /= np.linalg.norm(new_normals, axis=1, keepdims=True).clip(1e-9)
    new_faces = cluster[faces]
    keep = (
        (new_faces[:, 0] != new_faces[:, 1])
        & (new_faces[:, 1] != new_faces[:, 2])
        & (new_faces[:, 0] != new_faces[:, 2])
    )
    new_faces = new_faces[keep]
    _, first = np.unique(np.sort(new_faces, axis=1), axis=0, return_index=True)
    return mean(vertices), new_faces[np.sort(first)], new_normals


def _write_atomic(path: Path, data: bytes | str) -> None:
    mode = "wb" if isinstance(data, bytes) else "w"
    with tempfile.NamedTemporaryFile(mode, dir=path.parent, delete=False, suffix=".tmp") as f:
        f.write(data)
        tmp = f.name
    os.replace(tmp, path)


def _light_copy(rel: str, cell: float) -> Path:
    """Clustered copy of the asset ``PANDA_DIR/rel`` (an STL mesh or a GLB scene), cached."""
    import trimesh

    source = PANDA_DIR / rel
    out = cache_dir() / f"v{CACHE_VERSION}_{cell * 1000:g}mm_{rel.replace('/', '_')}"
    if out.exists():
        return out
    if not source.exists() and rel == D415_MESH:
        # Outer size of the D415 housing as the original mesh spans it (metres).
        box = trimesh.creation.box(extents=(0.0989, 0.023, 0.02005))
        box.apply_translation((0.0, 0.0, -0.010025))
        _write_atomic(out, box.export(file_type="stl"))
        return out
    loaded = trimesh.load(source)
    scene = loaded if isinstance(loaded, trimesh.Scene) else trimesh.Scene(loaded)
    for name, geometry in list(scene.geometry.items()):
        vertices, faces, normals = cluster_decimate(
            np.asarray(geometry.vertices), np.asarray(geometry.faces), cell, np.asarray(geometry.vertex_normals)
        )
        light = trimesh.Trimesh(vertices, faces, vertex_normals=normals, process=False)
        if hasattr(geometry.visual, "material"):
            light.visual = trimesh.visual.TextureVisuals(material=geometry.visual.material)
        scene.geometry[name] = light
    export = scene if isinstance(loaded, trimesh.Scene) else next(iter(scene.geometry.values()))
    _write_atomic(out, export.export(file_type=out.suffix.lstrip(".")))
    return out


def light_robot_enabled() -> bool:
    """Whether ``MIKASA_LIGHT_ROBOT`` asks for clustered link meshes too."""
    return os.environ.get(LIGHT_ROBOT_ENV_VAR, "").strip().lower() in {"1", "true", "yes", "on"}


def light_panda_urdf(light_links: bool | None = None) -> Path:
    """A copy of ManiSkill's ``panda_v3.urdf`` using the light housing mesh (and, with
    ``light_links``, light link meshes; default from ``MIKASA_LIGHT_ROBOT``).

    Every other mesh path is made absolute so the copy can live outside the asset folder.
    """
    light_links = light_robot_enabled() if light_links is None else light_links
    # The copy holds absolute paths into this ManiSkill installation: key it by that path.
    install = hashlib.sha1(str(PANDA_DIR).encode()).hexdigest()[:10]
    variant = "links" if light_links else "d415"
    out = cache_dir() / f"panda_v3_light_v{CACHE_VERSION}_{variant}_{install}.urdf"
    if out.exists():
        return out
    text = (PANDA_DIR / "panda_v3.urdf").read_text()

    def absolute(match: re.Match) -> str:
        rel = match.group(1)
        if rel == D415_MESH:
            target = _light_copy(rel, D415_CELL_M)
        elif light_links and "/visual/" in rel:
            target = _light_copy(rel, LINK_CELL_M)
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
