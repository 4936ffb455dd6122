"""All cameras of one CPU-simulated scene rendered in one batched GPU pass.

With CPU physics and a CUDA render device, ManiSkill renders each camera on its own: a
``take_picture`` and a blocking ``get_picture`` download per camera, then a
``torch.cuda.synchronize()``. Rendering both cameras through one SAPIEN camera group (the
batched API ManiSkill uses for GPU simulation) submits one pass instead of two and returns
the same pixels (within 1/255, `benchmarks/gpu_camera_group_check.py`). Measured on an
H200: one process ~200 rgb steps/s either way; in the bench's 16-worker runner ~770-930
together, where the GPU shared by the processes is the limit.

The camera group reads object poses from a CUDA buffer. Here that buffer is filled from
the CPU scene: ``Scene.pack_poses()`` gives every entity's pose in one call (a few µs),
the rows that render bodies and cameras use are copied to pinned memory, uploaded, and
the group renders all pictures into CUDA memory, and they come back in one copy. The
images are returned on the CPU, with the rest of a CPU-simulated env's observation.
(ManiSkill's per-camera path returns views of the GPU picture buffers instead; every
later operation on them is then a small CUDA launch queued behind the other processes'
work: the bench's 16 workers made 790 rgb steps/s that way, 927 with CPU images.)
The wait for the copy uses a blocking CUDA event, so a waiting process yields its core
to the others instead of spinning.

Conditions (checked by `CameraGroupRenderer.supported`): CPU simulation of one env, a CUDA
render device, the ``minimal`` sensor shader (8-bit colour), only ``rgb`` requested, no
ManiSkill-hidden objects, and a scene that does not add or remove objects after its
first render (SAPIEN forbids that once the group exists). ``MIKASA_CAMERA_GROUP=0``
turns it off.

With a CPU render device (lavapipe) and the same conditions but the device,
`read_rgb_pictures` reads ManiSkill's pictures without its copy through ``torch.tensor``.
Copies of 49-65k values go to torch's intra-op thread pool, whose threads then spin
between steps: with them, one env kept all 16 cores of a machine with one NVIDIA GPU and 16 CPU cores busy (73 CPU-ms per
step instead of 3) and ran 20% slower. Images here are copied by numpy instead.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import sapien
import torch

__all__ = [
    "CAMERA_GROUP_ENV_VAR",
    "CameraGroupRenderer",
    "assign_pose_rows",
    "camera_group_enabled",
    "check_pose_layout",
    "packed_poses",
    "read_rgb_pictures",
    "renders_on_cuda",
    "rgb_cameras_readable",
]

CAMERA_GROUP_ENV_VAR = "MIKASA_CAMERA_GROUP"
_POSE_ROW_WIDTH = 13  # the layout of PhysX GPU body data that SAPIEN reads: p, q, v, w


def camera_group_enabled() -> bool:
    """False when ``MIKASA_CAMERA_GROUP`` is set to 0/false/no/off."""
    return os.environ.get(CAMERA_GROUP_ENV_VAR, "1").strip().lower() not in {"0", "false", "no", "off"}


def assign_pose_rows(
    scene: sapien.Scene, cameras: list[sapien.render.RenderCameraComponent], first_row: int = 0
) -> np.ndarray:
    """Give every render shape and camera of ``scene`` a row of the group's pose buffer,
    one row per entity they hang on, numbered from ``first_row``; return, for each row, the
    entity's index in ``scene.entities`` (the order of ``Scene.pack_poses``)."""
    # Keyed by global id: Python wrappers of SAPIEN objects are not unique.
    entity_index = {e.global_id: i for i, e in enumerate(scene.entities)}
    rows: list[int] = []
    row_of: dict[int, int] = {}

    def row(entity: sapien.Entity) -> int:
        key = entity.global_id
        if key not in row_of:
            row_of[key] = first_row + len(rows)
            rows.append(entity_index[key])
        return row_of[key]

    for body in scene.render_system.render_bodies:
        r = row(body.entity)
        for shape in body.render_shapes:
            shape.set_gpu_pose_batch_index(r)
    for cam in cameras:
        cam.set_gpu_pose_batch_index(row(cam.entity))
    return np.asarray(rows, dtype=np.int64)


def packed_poses(scene: sapien.Scene) -> np.ndarray:
    """Every entity's pose as rows [qw, qx, qy, qz, x, y, z] (``Scene.pack_poses`` layout)."""
    return np.frombuffer(scene.pack_poses(), dtype=np.float32).reshape(-1, 7)


def check_pose_layout(scene: sapien.Scene) -> None:
    """Raise if `packed_poses` does not match the entities' poses (a SAPIEN change)."""
    packed = packed_poses(scene)
    entities = scene.entities
    if len(packed) != len(entities):
        raise RuntimeError("Scene.pack_poses() does not hold one pose per entity")
    for i, entity in enumerate(entities):
        pose = entity.pose
        if not (np.allclose(packed[i, :4], pose.q, atol=1e-5) and np.allclose(packed[i, 4:], pose.p, atol=1e-5)):
            raise RuntimeError("Scene.pack_poses() layout is not [q, p] per entity")


SceneCameras = tuple[sapien.Scene, dict[str, sapien.render.RenderCameraComponent]]
"""A scene and its cameras by name."""


class CameraGroupRenderer:
    """Renders named cameras of one or more SAPIEN scenes together on the GPU, in one pass;
    returns uint8 RGB on the CPU."""

    def __init__(
        self,
        views: Sequence[SceneCameras],
        device: torch.device | str = "cuda",
        first_group: Sequence[bool] | None = None,
    ):
        """``first_group[i]``: scene ``i`` has not been in a camera group before (default:
        all); only such a scene gets its render system's first update (and a check of the
        pose layout). A scene already in a group may be mid-episode in another thread."""
        if not views:
            raise ValueError("a camera group needs at least one scene")
        self.scenes = [scene for scene, _ in views]
        self.names = [list(cameras) for _, cameras in views]
        cams = [cam for _, cameras in views for cam in cameras.values()]
        sizes = {(c.width, c.height) for c in cams}
        if len(sizes) != 1:
            raise ValueError(f"a camera group needs cameras of one size, got {sorted(sizes)}")
        self.width, self.height = sizes.pop()

        # Each scene's rows of the shared pose buffer: (first row, entity index per row).
        self._rows: list[tuple[int, np.ndarray]] = []
        n_rows = 0
        first_group = [True] * len(views) if first_group is None else list(first_group)
        for (scene, cameras), first in zip(views, first_group, strict=True):
            rows = assign_pose_rows(scene, list(cameras.values()), first_row=n_rows)
            self._rows.append((n_rows, rows))
            n_rows += len(rows)
            if first:
                check_pose_layout(scene)
                scene.update_render()  # the render system's own first update, before any group

        self._stream = torch.cuda.current_stream(device)
        self._host_poses = torch.zeros((n_rows, _POSE_ROW_WIDTH), dtype=torch.float32).pin_memory()
        self._host_np = self._host_poses.numpy()
        self._device_poses = torch.zeros((n_rows, _POSE_ROW_WIDTH), dtype=torch.float32, device=device)
        self._group = sapien.render.RenderSystemGroup([scene.render_system for scene in self.scenes])
        self._group.set_cuda_poses(sapien.pysapien.CudaArray(self._device_poses))
        self._group.set_cuda_stream(self._stream.cuda_stream)
        self._cameras = self._group.create_camera_group(cams, ["Color"])
        self._images = torch.zeros((len(cams), self.height, self.width, 3), dtype=torch.uint8).pin_memory()
        self._images_np = self._images.numpy()
        self._copied = torch.cuda.Event(blocking=True)  # waited on without spinning a core

    def render_all(self, refresh: Sequence[int] | None = None) -> list[dict[str, torch.Tensor]]:
        """Render every camera: per scene, name -> uint8 [1, H, W, 3] on the CPU, with the
        rest of a CPU-simulated env's observation.

        The poses of the scenes listed in ``refresh`` (default: all) are read now; the
        others are drawn at the poses they had when last read, and their pictures are
        not meant to be used. (A scene that another thread may be stepping must not be
        read: see render_batcher.py.)"""
        indices = range(len(self.scenes)) if refresh is None else refresh
        for i in indices:
            start, rows = self._rows[i]
            packed = packed_poses(self.scenes[i])[rows]
            self._host_np[start : start + len(rows), 0:3] = packed[:, 4:7]
            self._host_np[start : start + len(rows), 3:7] = packed[:, 0:4]
        self._device_poses.copy_(self._host_poses, non_blocking=True)
        self._group.update_render()
        self._cameras.take_picture()
        pictures = self._cameras.get_picture_cuda("Color").torch()
        self._images.copy_(pictures[..., :3], non_blocking=True)
        self._copied.record(self._stream)
        self._copied.synchronize()
        # Copies, as the pinned buffer is reused by the next render; made by numpy, as a torch
        # copy of 49k values goes to torch's thread pool, whose threads then spin between
        # steps (one env kept all 16 cores of a machine with one NVIDIA GPU and 16 CPU cores busy, and ran 20% slower).
        out, i = [], 0
        for names in self.names:
            out.append(
                {name: torch.from_numpy(self._images_np[i + j : i + j + 1].copy()) for j, name in enumerate(names)}
            )
            i += len(names)
        return out

    def render(self) -> dict[str, torch.Tensor]:
        """`render_all` for a single-scene group: name -> uint8 [1, H, W, 3] on the CPU."""
        return self.render_all()[0]

    @staticmethod
    def supported(env: Any) -> bool:
        """Whether ``env`` (a ManiSkill BaseEnv) can render its sensors through a group."""
        return rgb_cameras_readable(env) and renders_on_cuda(env)


def renders_on_cuda(env: Any) -> bool:
    """Whether ``env`` (a ManiSkill BaseEnv) renders on a CUDA device torch can use."""
    return torch.cuda.is_available() and env.backend.render_device.is_cuda()


def rgb_cameras_readable(env: Any) -> bool:
    """Whether the sensors of ``env`` (a ManiSkill BaseEnv) are plain rgb cameras whose
    pictures can be read directly: CPU simulation of one env, ``minimal`` shader, only rgb
    requested, no ManiSkill-hidden objects, camera groups not turned off."""
    if not camera_group_enabled():
        return False
    if env.scene is None or env.scene.gpu_sim_enabled or env.num_envs != 1 or env._hidden_objects:
        return False
    visual = env.obs_mode_struct.visual
    if not visual.rgb or visual.depth or visual.position or visual.segmentation or visual.normal or visual.albedo:
        return False
    from mani_skill.sensors.camera import Camera

    sensors = env.scene.sensors
    return bool(sensors) and all(
        isinstance(s, Camera)
        and s.config.shader_config.shader_pack == "minimal"
        and len(s.camera._render_cameras) == 1
        for s in sensors.values()
    )


def read_rgb_pictures(cameras: dict[str, sapien.render.RenderCameraComponent]) -> dict[str, torch.Tensor]:
    """The rgb of pictures already taken, name -> uint8 [1, H, W, 3] (a view of the RGBA
    picture, as ManiSkill returns it) — without ManiSkill's copy through ``torch.tensor``,
    which hands 65k values to torch's thread pool (threads that then spin between steps)."""
    return {name: torch.from_numpy(cam.get_picture("Color"))[None, ..., :3] for name, cam in cameras.items()}


def env_cameras(env: Any) -> SceneCameras:
    """A ManiSkill env's (one) scene and its sensor cameras by name."""
    cameras = {name: s.camera._render_cameras[0] for name, s in env.scene.sensors.items()}
    return env.scene.sub_scenes[0], cameras


def env_render_device(env: Any) -> torch.device:
    """The CUDA device a ManiSkill env renders on."""
    return torch.device("cuda", env.backend.render_device.cuda_id)

