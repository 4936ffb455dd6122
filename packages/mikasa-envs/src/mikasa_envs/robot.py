"""The Panda with wrist camera, with a light-weight camera housing mesh.

ManiSkill's ``panda_wristcam`` draws the wrist camera housing with a RealSense D415 mesh
of 425k triangles. On CPU rendering (lavapipe) that one mesh costs more than the rest of
the scene; a clustered copy of ~15k triangles looks the same at 128x128 and makes rgb
steps ~1.8x faster. The copy is generated from the installed ManiSkill asset on first use
and cached (``MIKASA_CACHE_DIR``, default ``~/.cache/mikasa-envs``). If the asset is
missing (slim ManiSkill wheels), a box of the D415's outer size stands in.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from pathlib import Path

import numpy as np
from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.robots.panda.panda_wristcam import PandaWristCam

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


class LightPandaWristCam(PandaWristCam):
    """``panda_wristcam`` (same uid, joints, cameras and controllers) with the light housing mesh."""

    @property
    def urdf_path(self) -> str:  # type: ignore[override]
        return str(light_panda_urdf())
