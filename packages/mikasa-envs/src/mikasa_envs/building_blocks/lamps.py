"""The colour-switch lamp (``_shell_game_shared.md`` §5, procedural bulb of §5.2).

One visual-only body (base, stem, collar) and one visual-only bulb actor per state; in each
env exactly one bulb is shown, by teleporting it to the lamp and parking the others
``HIDE_OFFSET_Z`` above it. Families give their own bulb colours, emission scales and lamp
positions (their task files); shell games, TraceShape, TimedTransfer, BlinkCount,
GatherAndRecall and BatteriesChecker share the geometry.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import sapien
import torch
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.building_blocks.poses import (
    HIDE_OFFSET_Z,
    UPRIGHT_CYLINDER_QUAT,
    positions_to_poses,
    write_actor_poses,
)

# Lamp-local geometry (z up, base bottom at z = 0): (half size, centre z) per body box.
LAMP_BASE = ((0.0216, 0.0216, 0.008), 0.008)
LAMP_STEM = ((0.004, 0.004, 0.020), 0.036)
LAMP_COLLAR = ((0.0099, 0.0099, 0.0032), 0.0592)
LAMP_BASE_RGBA = (65, 70, 80, 255)
LAMP_STEM_RGBA = (205, 205, 205, 255)
# Procedural bulb: a neck on the collar (z 0.0624 -> 0.0704) and a glass sphere.
BULB_NECK_RADIUS = 0.007
BULB_NECK_HALF_LENGTH = 0.004
BULB_NECK_Z = 0.0664
BULB_GLASS_RADIUS = 0.015
BULB_GLASS_Z = 0.085


def bulb_material(rgb255: Sequence[int], emission_scale: float = 0.0) -> sapien.render.RenderMaterial:
    """Base colour ``rgb255``; emission = scale × colour (0: not emissive)."""
    rgba = rgba01((*rgb255[:3], 255))
    emission = [*(rgba[:3] * emission_scale), 1.0]
    return sapien.render.RenderMaterial(base_color=list(rgba), emission=emission)


class ColorSwitchLamp:
    """A lamp with named bulbs, one shown per env.

    ``bulbs`` maps a bulb name to (RGB 0-255, emission scale), e.g.
    ``{"off": ((255, 255, 255), 0.0), "red": ((255, 0, 0), 2.0)}``; bulb k is the k-th entry.
    Call ``place`` in ``_initialize_episode`` and ``show`` whenever the lamp changes.
    """

    # Per-env state saved with the env's task state (``MikasaVLABaseEnv.TASK_STATE``).
    STATE_ATTRS: ClassVar[tuple[str, ...]] = ("position", "shown")

    def __init__(
        self,
        scene: ManiSkillScene,
        name: str,
        bulbs: Mapping[str, tuple[Sequence[int], float]],
        num_envs: int,
        device: torch.device | str,
    ) -> None:
        self.scene = scene
        self.bulb_names: list[str] = list(bulbs)
        self.body = self._build_body(scene, f"{name}_body")
        self.bulbs: list[Actor] = [
            self._build_bulb(scene, f"{name}_bulb_{bulb}", bulb_material(rgb, scale))
            for bulb, (rgb, scale) in bulbs.items()
        ]
        self.position = torch.zeros(num_envs, 3, device=device)
        # Per env, the index of the bulb shown (-1: none written yet).
        self.shown = torch.full((num_envs,), -1, dtype=torch.long, device=device)

    @staticmethod
    def _build_body(scene: ManiSkillScene, name: str) -> Actor:
        builder = scene.create_actor_builder()
        base_material = sapien.render.RenderMaterial(base_color=list(rgba01(LAMP_BASE_RGBA)))
        stem_material = sapien.render.RenderMaterial(base_color=list(rgba01(LAMP_STEM_RGBA)))
        for (half, z), material in ((LAMP_BASE, base_material), (LAMP_STEM, stem_material), (LAMP_COLLAR, stem_material)):
            builder.add_box_visual(pose=sapien.Pose(p=[0, 0, z]), half_size=half, material=material)
        builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
        return builder.build_kinematic(name=name)

    @staticmethod
    def _build_bulb(scene: ManiSkillScene, name: str, material: sapien.render.RenderMaterial) -> Actor:
        builder = scene.create_actor_builder()
        builder.add_cylinder_visual(
            pose=sapien.Pose(p=[0, 0, BULB_NECK_Z], q=UPRIGHT_CYLINDER_QUAT),
            radius=BULB_NECK_RADIUS,
            half_length=BULB_NECK_HALF_LENGTH,
            material=material,
        )
        builder.add_sphere_visual(pose=sapien.Pose(p=[0, 0, BULB_GLASS_Z]), radius=BULB_GLASS_RADIUS, material=material)
        builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
        return builder.build_kinematic(name=name)

    def bulb_index(self, name: str) -> int:
        """The index of bulb ``name``; a clear error names the lamp's bulbs."""
        if name not in self.bulb_names:
            raise KeyError(f"no bulb {name!r}; this lamp has {self.bulb_names}")
        return self.bulb_names.index(name)

    def place(self, env_idx: torch.Tensor, positions: torch.Tensor, bulb: torch.Tensor | int = 0) -> None:
        """Put the lamp (base bottom) at ``positions`` ((b, 3)) in envs ``env_idx``, showing ``bulb``."""
        self.position[env_idx] = positions.to(self.position)
        write_actor_poses(self.scene, [self.body], env_idx, positions_to_poses(self.position[env_idx])[:, None])
        self.shown[env_idx] = -1
        self.show(env_idx, bulb)

    def show(self, env_idx: torch.Tensor, bulb: torch.Tensor | int) -> None:
        """Show bulb ``bulb`` (index per env, or one for all) in envs ``env_idx``; others hidden.

        Only envs whose bulb changes are written. Outside ``_initialize_episode`` on the GPU
        sim the caller applies the writes (``scene.px.gpu_apply_rigid_dynamic_data()``).
        """
        bulb = torch.as_tensor(bulb, dtype=torch.long, device=self.shown.device).expand(len(env_idx))
        changed = self.shown[env_idx] != bulb
        if not bool(changed.any()):
            return
        env_idx, bulb = env_idx[changed], bulb[changed]
        self.shown[env_idx] = bulb
        base = self.position[env_idx]
        hidden = base + torch.tensor([0.0, 0.0, HIDE_OFFSET_Z], device=base.device)
        k = torch.arange(len(self.bulbs), device=base.device)
        positions = torch.where((bulb[:, None] == k)[..., None], base[:, None], hidden[:, None])
        write_actor_poses(self.scene, self.bulbs, env_idx, positions_to_poses(positions))

    @property
    def actors(self) -> list[Actor]:
        """The body and every bulb."""
        return [self.body, *self.bulbs]
