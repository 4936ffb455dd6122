"""Procedural shape library of the VLA tasks (spec: ``shapes.md``).

Every object is assembled from SAPIEN primitives (boxes, cylinders, spheres)
with ManiSkill actor builders, so nothing is loaded from disk or the network.

Conventions shared by all builders:

* the scene comes first, one actor is built and returned;
* each part is added as a collision shape (only if ``add_collision``) and as a
  visual shape with identical geometry and local pose, using a plain render
  material whose base colour is ``color`` (RGBA floats in [0, 1]);
* default density (1000 kg/m^3) and default physical material;
* SAPIEN cylinders lie along their **local x axis**; the rotation
  ``euler2quat(0, pi/2, alpha)`` (static x-y-z) turns that axis vertical.

Overlapping parts are kept overlapping on purpose: PhysX sums the mass of every
collision shape, and the masses of ``shapes.md`` §1 include the overlaps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import sapien
import sapien.render
from mani_skill.utils.building.actor_builder import ActorBuilder
from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.pose import Pose
from transforms3d.euler import euler2quat

if TYPE_CHECKING:
    from mani_skill.envs.scene import ManiSkillScene

__all__ = [
    "SHAPE_NAMES",
    "SHAPE_AND_COLOR_SHAPES",
    "SHAPE_SCALE",
    "SHAPE_REST_Z",
    "TARGET_RED",
    "shape_orientation",
    "build_task_shape",
    "build_cross",
    "build_torus",
    "build_star",
    "build_pyramid",
    "build_t_shape",
    "build_crescent",
    "build_target",
    "set_actor_visual_rgba",
]

Color = Sequence[float]
BodyType = Literal["dynamic", "static", "kinematic"]
PoseLike = Pose | sapien.Pose | None
SceneIdxs = Any | None  # list / np.ndarray / torch.Tensor of sub-scene indices

# Used when a builder whose spec signature has ``color=None`` gets no colour.
_DEFAULT_COLOR: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 1.0)
# Inner arc of the crescent: solid but invisible (shapes.md §1, §4.2).
_INVISIBLE: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
TARGET_RED: tuple[float, float, float, float] = tuple(c / 255 for c in (194, 19, 22, 255))
_WHITE: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)

# Quaternion (wxyz) that turns a cylinder's local x axis to vertical; with the
# extra yaw ``alpha`` of the spec it is euler2quat(0, pi/2, alpha).
_UPRIGHT_QUAT: tuple[float, float, float, float] = (0.7071068, 0.0, 0.7071068, 0.0)
_IDENTITY_QUAT: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
# +90 deg about x, used by the T shape (stem's long z axis -> +y).
_ROT_X90 = tuple(float(v) for v in euler2quat(math.pi / 2, 0.0, 0.0))


# --------------------------------------------------------------------------------------
# Private helpers shared by every builder
# --------------------------------------------------------------------------------------


def _rgba(color: Color | None) -> list[float]:
    """Normalise a colour to 4 floats (alpha 1 when only RGB is given)."""
    if color is None:
        return list(_DEFAULT_COLOR)
    values = [float(c) for c in np.asarray(color, dtype=np.float64).reshape(-1)]
    if len(values) == 3:
        values.append(1.0)
    if len(values) != 4:
        raise ValueError(f"color must have 3 or 4 components, got {len(values)}")
    return values


def _add_part(
    builder: ActorBuilder,
    kind: Literal["box", "cylinder", "sphere"],
    size: float | Sequence[float],
    color: Color | None,
    pose: sapien.Pose | None = None,
    add_collision: bool = True,
) -> None:
    """Add one primitive as collision (if requested) + visual with a plain material.

    ``size`` is the box half sizes, ``(radius, half_length)`` for a cylinder, or
    the sphere radius. Collision and visual share geometry and local pose.
    """
    pose = sapien.Pose() if pose is None else pose
    material = sapien.render.RenderMaterial(base_color=_rgba(color))
    if kind == "box":
        half = [float(v) for v in size]  # type: ignore[union-attr]
        if add_collision:
            builder.add_box_collision(pose=pose, half_size=half)
        builder.add_box_visual(pose=pose, half_size=half, material=material)
    elif kind == "cylinder":
        radius, half_length = (float(v) for v in size)  # type: ignore[union-attr]
        if add_collision:
            builder.add_cylinder_collision(pose=pose, radius=radius, half_length=half_length)
        builder.add_cylinder_visual(
            pose=pose, radius=radius, half_length=half_length, material=material
        )
    elif kind == "sphere":
        radius = float(size)  # type: ignore[arg-type]
        if add_collision:
            builder.add_sphere_collision(pose=pose, radius=radius)
        builder.add_sphere_visual(pose=pose, radius=radius, material=material)
    else:  # pragma: no cover - programming error
        raise ValueError(f"unknown part kind {kind!r}")


def _finish(
    builder: ActorBuilder,
    name: str,
    body_type: str = "dynamic",
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Apply scene_idxs / initial_pose and build the actor with the requested body type."""
    if body_type not in ("dynamic", "static", "kinematic"):
        # Checked before touching the builder so a typo fails loudly and early.
        raise ValueError(
            f"Unknown body_type {body_type!r}; expected 'dynamic', 'static' or 'kinematic'"
        )
    if scene_idxs is not None:
        builder.set_scene_idxs(scene_idxs)
    if initial_pose is not None:
        builder.set_initial_pose(initial_pose)
    if body_type == "dynamic":
        return builder.build(name=name)
    if body_type == "static":
        return builder.build_static(name=name)
    return builder.build_kinematic(name=name)


def _vertical_cylinder_quat(yaw: float) -> np.ndarray:
    """Rotation Euler (0, pi/2, yaw): cylinder axis (local x) turned vertical."""
    return euler2quat(0.0, math.pi / 2, yaw)


def _add_chord_discs(
    builder: ActorBuilder,
    center: tuple[float, float],
    radius: float,
    angles: Sequence[float],
    disc_radius: float,
    color: Color | None,
    add_collision: bool,
) -> None:
    """Add one vertical cylinder per chord between consecutive ``angles`` on a circle.

    Each cylinder has radius ``disc_radius`` and half length chord/2, sits at the
    chord midpoint and is rotated (0, pi/2, chord direction), i.e. it stands on
    the table as a flat disc whose height equals the chord (torus, crescent).
    """
    cx, cy = center
    for a0, a1 in zip(angles[:-1], angles[1:], strict=True):
        x0, y0 = cx + radius * math.cos(a0), cy + radius * math.sin(a0)
        x1, y1 = cx + radius * math.cos(a1), cy + radius * math.sin(a1)
        chord = math.hypot(x1 - x0, y1 - y0)
        pose = sapien.Pose(
            p=[(x0 + x1) / 2, (y0 + y1) / 2, 0.0],
            q=_vertical_cylinder_quat(math.atan2(y1 - y0, x1 - x0)),
        )
        _add_part(builder, "cylinder", (disc_radius, chord / 2), color, pose, add_collision)


# --------------------------------------------------------------------------------------
# Builders of shapes.md §2.1 (selection families)
# --------------------------------------------------------------------------------------


def build_cross(
    scene: ManiSkillScene,
    arm_length: float,
    width: float,
    color: Color | None,
    name: str,
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Flat "+": two bars (half sizes arm_length x width/2 x width/2) crossing at the origin."""
    builder = scene.create_actor_builder()
    _add_part(builder, "box", (arm_length, width / 2, width / 2), color, None, add_collision)
    _add_part(builder, "box", (width / 2, arm_length, width / 2), color, None, add_collision)
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


def build_torus(
    scene: ManiSkillScene,
    radius: float,
    tube_radius: float,
    segments: int = 8,
    color: Color | None = None,
    name: str = "torus",
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Ring of ``segments`` vertical discs (radius tube_radius) on the chords of a circle."""
    builder = scene.create_actor_builder()
    angles = [2 * math.pi * k / segments for k in range(segments + 1)]
    _add_chord_discs(builder, (0.0, 0.0), radius, angles, tube_radius, color, add_collision)
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


def build_star(
    scene: ManiSkillScene,
    radius: float,
    thickness: float,
    points: int = 5,
    color: Color | None = None,
    name: str = "star",
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """``points`` arms (boxes ``radius`` long) radiating from the origin, first along +x."""
    builder = scene.create_actor_builder()
    for k in range(points):
        theta = 2 * math.pi * k / points
        pose = sapien.Pose(
            p=[radius / 2 * math.cos(theta), radius / 2 * math.sin(theta), 0.0],
            q=euler2quat(0.0, 0.0, theta),
        )
        half = (radius / 2, thickness / 2, thickness / 2)
        _add_part(builder, "box", half, color, pose, add_collision)
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


def build_pyramid(
    scene: ManiSkillScene,
    base_size: float,
    height: float,
    color: Color | None,
    name: str,
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Stepped pyramid of three slabs; ``base_size`` is the bottom slab's *half* width.

    The origin is at the centre of the bottom slab (slabs centred at z 0, h/2, h).
    """
    builder = scene.create_actor_builder()
    for frac, z in ((1.0, 0.0), (0.7, height / 2), (0.4, height)):
        half = (frac * base_size, frac * base_size, height / 4)
        _add_part(builder, "box", half, color, sapien.Pose(p=[0.0, 0.0, z]), add_collision)
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


def build_t_shape(
    scene: ManiSkillScene,
    width: float,
    height: float,
    thickness: float,
    color: Color | None = None,
    name: str = "t_shape",
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Flat "T": stem along +y from the origin (foot of the stem) and a bar across its end."""
    builder = scene.create_actor_builder()
    # Both parts are rotated +90 deg about x; only the stem's shape changes (its
    # long local z axis becomes +y), positions are not rotated.
    bar = sapien.Pose(p=[0.0, height - thickness / 2, 0.0], q=_ROT_X90)
    _add_part(builder, "box", (width / 2, thickness / 2, thickness / 2), color, bar, add_collision)
    stem = sapien.Pose(p=[0.0, height / 2, 0.0], q=_ROT_X90)
    _add_part(
        builder, "box", (thickness / 2, thickness / 2, height / 2), color, stem, add_collision
    )
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


def build_crescent(
    scene: ManiSkillScene,
    outer_radius: float,
    thickness: float,
    height: float,
    segments: int = 12,
    color: Color | None = None,
    name: str = "crescent",
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Flat "C": outer arc of vertical discs plus an invisible but solid inner arc.

    Angles run pi*k/(segments-1) for k = 0..segments, so the arc spans a bit more
    than half a circle (upstream geometry, kept on purpose). Origin = outer arc centre.
    """
    builder = scene.create_actor_builder()
    angles = [math.pi * k / (segments - 1) for k in range(segments + 1)]
    disc_radius = height / 2
    _add_chord_discs(builder, (0.0, 0.0), outer_radius, angles, disc_radius, color, add_collision)
    inner_radius = outer_radius - thickness
    inner_center = (0.7 * thickness, 0.0)
    _add_chord_discs(
        builder, inner_center, inner_radius, angles, disc_radius, _INVISIBLE, add_collision
    )
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


# --------------------------------------------------------------------------------------
# Builder of shapes.md §2.2 used by other families
# --------------------------------------------------------------------------------------


def build_target(
    scene: ManiSkillScene,
    radius: float,
    thickness: float,
    name: str,
    primary_color: Color = TARGET_RED,
    secondary_color: Color = _WHITE,
    body_type: BodyType = "dynamic",
    add_collision: bool = True,
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Bull's-eye disc of 5 coaxial cylinders along local x (caller rotates it flat).

    Ring i has radius radius*(5-i)/5 and half length thickness/2 + i*1e-5 so inner
    rings stand 10 um proud of outer ones and stay visible (no z-fighting).
    """
    builder = scene.create_actor_builder()
    for i in range(5):
        color = primary_color if i % 2 == 0 else secondary_color
        size = (radius * (5 - i) / 5, thickness / 2 + i * 1e-5)
        _add_part(builder, "cylinder", size, color, None, add_collision)
    return _finish(builder, name, body_type, scene_idxs, initial_pose)


# --------------------------------------------------------------------------------------
# Task-level API (RememberShape*, FindImposterShape*)
# --------------------------------------------------------------------------------------

SHAPE_NAMES: tuple[str, ...] = (
    "cube",
    "sphere",
    "cylinder",
    "cross",
    "torus",
    "star",
    "pyramide",  # sic: upstream spelling, shown in overlays
    "t_shape",
    "crescent",
)
"""Shape name per index of RememberShape / FindImposterShape."""

SHAPE_AND_COLOR_SHAPES: tuple[str, ...] = ("cube", "sphere", "t_shape", "cross", "torus")
"""Shape name per shape index of the ShapeAndColor families."""

SHAPE_SCALE: float = 0.02
"""Scale s (m) every shape task builds its objects with."""


def _rest_z(name: str, s: float = SHAPE_SCALE) -> float:
    """Height of the origin above the table for the task orientation (shapes.md §3).

    Derived from the collision geometry: the lowest collision point below the origin.
    """
    if name in ("cube", "sphere", "cylinder"):
        return s  # half size / radius / half length (cylinder stood upright)
    if name in ("cross", "star", "t_shape"):
        return 0.75 * s / 2  # boxes of thickness 0.75 s centred at z = 0
    if name == "pyramide":
        return s / 4  # bottom slab half height = height / 4
    if name == "torus":
        # Vertical discs: half length = half chord of a 8-gon of radius s.
        return s * math.sin(math.pi / 8)
    if name == "crescent":
        # Tallest discs are the outer ones: half chord of step pi/11 on radius s.
        return s * math.sin(math.pi / 22)
    raise _unknown_shape(name)


def _unknown_shape(name: str) -> ValueError:
    return ValueError(f"Unknown shape {name!r}; accepted names: {', '.join(SHAPE_NAMES)}")


SHAPE_REST_Z: dict[str, float] = {n: _rest_z(n) for n in SHAPE_NAMES}
"""Rest height (m) of each task shape's origin above the table, task orientation."""


def shape_orientation(name: str) -> list[float]:
    """Quaternion (wxyz) the tasks place a shape with: upright for the cylinder, else identity."""
    if name not in SHAPE_NAMES:
        raise _unknown_shape(name)
    return list(_UPRIGHT_QUAT if name == "cylinder" else _IDENTITY_QUAT)


def build_task_shape(
    scene: ManiSkillScene,
    name: str,
    color: Color,
    actor_name: str,
    scale: float = SHAPE_SCALE,
    body_type: BodyType = "dynamic",
    scene_idxs: SceneIdxs = None,
    initial_pose: PoseLike = None,
) -> Actor:
    """Build one of the nine task shapes with the parameters of shapes.md §1.

    The orientation is not baked in (the cylinder lies along x until the caller
    applies ``shape_orientation``). Without ``initial_pose`` the actor starts at
    the origin in its task pose (rest z, task orientation) so that the builder does
    not warn and objects never start inside the table.
    """
    s = scale
    if name not in SHAPE_NAMES:
        raise _unknown_shape(name)
    if initial_pose is None:
        initial_pose = sapien.Pose(p=[0.0, 0.0, _rest_z(name, s)], q=shape_orientation(name))
    common = dict(body_type=body_type, scene_idxs=scene_idxs, initial_pose=initial_pose)
    if name == "cross":
        return build_cross(scene, 1.5 * s, 0.75 * s, color, actor_name, **common)
    if name == "torus":
        return build_torus(scene, s, s / 2, 8, color, actor_name, **common)
    if name == "star":
        return build_star(scene, 1.5 * s, 0.75 * s, 5, color, actor_name, **common)
    if name == "pyramide":
        return build_pyramid(scene, s, s, color, actor_name, **common)
    if name == "t_shape":
        return build_t_shape(scene, 2 * s, 2 * s, 0.75 * s, color, actor_name, **common)
    if name == "crescent":
        return build_crescent(scene, s, s / 2, s, 12, color, actor_name, **common)
    # ManiSkill-style primitives, built with the same helpers as everything else.
    builder = scene.create_actor_builder()
    if name == "cube":
        _add_part(builder, "box", (s, s, s), color)
    elif name == "sphere":
        _add_part(builder, "sphere", s, color)
    else:  # cylinder: radius s, half length s along local x
        _add_part(builder, "cylinder", (s, s), color)
    return _finish(builder, actor_name, **common)


# --------------------------------------------------------------------------------------
# Appearance
# --------------------------------------------------------------------------------------

_TEXTURE_SETTERS = (
    "set_base_color_texture",
    "set_diffuse_texture",
    "set_emission_texture",
    "set_metallic_texture",
    "set_normal_texture",
    "set_roughness_texture",
    "set_transmission_texture",
)


def set_actor_visual_rgba(
    actor: Actor,
    rgba: Color,
    emission_scale: float = 0.0,
    remove_textures: bool = False,
) -> None:
    """Recolour every render shape of every per-scene object of ``actor``.

    Base colour becomes ``rgba`` (alpha 1 if only RGB is given), emission
    (r, g, b) * emission_scale with alpha 1; optionally all texture slots are
    cleared first (a texture would otherwise override the base colour).
    """
    color = _rgba(rgba)
    emission = [
        color[0] * emission_scale,
        color[1] * emission_scale,
        color[2] * emission_scale,
        1.0,
    ]
    for obj in actor._objs:
        entity = getattr(obj, "entity", obj)  # Actor._objs are entities; be lenient
        body = entity.find_component_by_type(sapien.render.RenderBodyComponent)
        if body is None:  # e.g. built without a render system
            continue
        for shape in body.render_shapes:
            # Primitive shapes expose their single material as a one-element part list.
            for part in shape.parts:
                material = part.material
                if remove_textures:
                    for setter in _TEXTURE_SETTERS:
                        getattr(material, setter)(None)
                material.set_base_color(color)
                material.set_emission(emission)


# Upstream name (shapes.md §2.2): other task modules call the private spelling.
_set_actor_visual_rgba = set_actor_visual_rgba
