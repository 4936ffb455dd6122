"""The checkered floor with the same look and 1% of the triangles.

ManiSkill's ``build_ground`` draws the 100 m floor as a grid of 1 m squares: 20,000
triangles, more than any robot link, for a plane. Its texture coordinates are an affine
function of position, so a coarser grid over the same extent with the same affine map
rasterises the same texels (perspective-correct interpolation is exact on a plane). The
grid keeps 10 m cells rather than two triangles so no triangle is so large that clipping
at the near plane loses precision. Rendering cost matters: on an NVIDIA H100 or H200, triangles
are what limits many processes sharing one GPU (see camera_group.py), and on lavapipe
every vertex is CPU work.
"""

from __future__ import annotations

import numpy as np
import sapien

__all__ = ["GROUND_CELL_M", "coarsen_ground_visual"]

GROUND_CELL_M = 10.0


def _grid(lo: np.ndarray, hi: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (x, y) and triangles of a grid over [lo, hi] with square cells of ``cell``."""
    nx = max(1, int(round((hi[0] - lo[0]) / cell)))
    ny = max(1, int(round((hi[1] - lo[1]) / cell)))
    xs = np.linspace(lo[0], hi[0], nx + 1)
    ys = np.linspace(lo[1], hi[1], ny + 1)
    xx, yy = np.meshgrid(xs, ys, indexing="ij")
    xy = np.stack([xx.ravel(), yy.ravel()], axis=1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    # Counter-clockwise seen from +z, as the original grid faces up.
    triangles = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return xy, triangles


def coarsen_ground_visual(ground: object, cell: float = GROUND_CELL_M) -> None:
    """Replace each of ``ground``'s floor meshes (a ManiSkill Actor from ``build_ground``)
    with a coarse grid over the same extent, with the same material and texture mapping.

    Call it after the scene is built and before its first render.
    """
    for entity in ground._objs:  # type: ignore[attr-defined]
        body = entity.find_component_by_type(sapien.render.RenderBodyComponent)
        if body is None:  # built without a render system
            continue
        (shape,) = body.render_shapes
        (part,) = shape.parts
        vertices = np.asarray(part.vertices, dtype=np.float64)
        uv = np.asarray(part.get_vertex_uv(), dtype=np.float64)
        # The texture mapping is affine in (x, y): recover it exactly by least squares.
        design = np.concatenate([vertices[:, :2], np.ones((len(vertices), 1))], axis=1)
        uv_map, *_ = np.linalg.lstsq(design, uv, rcond=None)
        if np.abs(design @ uv_map - uv).max() > 1e-5:
            raise ValueError("ground texture coordinates are not affine in position; not coarsening")
        xy, triangles = _grid(vertices[:, :2].min(0), vertices[:, :2].max(0), cell)
        new_vertices = np.concatenate([xy, np.full((len(xy), 1), vertices[0, 2])], axis=1)
        new_uv = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ uv_map
        normals = np.tile(np.asarray(part.get_vertex_normal()[0], dtype=np.float32), (len(xy), 1))
        light = sapien.render.RenderShapeTriangleMesh(
            vertices=new_vertices.astype(np.float32),
            triangles=triangles.astype(np.uint32),
            normals=normals,
            uvs=new_uv.astype(np.float32),
            material=part.material,
        )
        light.local_pose = shape.local_pose
        entity.remove_component(body)
        new_body = sapien.render.RenderBodyComponent()
        new_body.attach(light)
        entity.add_component(new_body)
