"""Push buttons with a "virtual press" read from the TCP height (``bunch_of_colors.md`` §5.3).

A button is a kinematic base box with a cylindrical cap on top. No contact is needed: the
press depth is computed from the TCP's height over the cap, and the cap is drawn lowered by
that depth. BunchOfColors, SeqOfColors, ChainOfColors, BlinkCountButtonPress,
GatherAndRecall, BatteriesChecker and TraceShapeSeq share the geometry of the cap's travel,
the depth rule and (where a family counts presses) the press / release / lift latch.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import sapien
import torch
from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.building_blocks.poses import (
    HIDE_OFFSET_Z,
    UPRIGHT_CYLINDER_QUAT,
    write_actor_poses,
)

BUTTON_BASE_HALF_HEIGHT = 0.015  # base box centre z; its top is at 0.030
BUTTON_CAP_HALF_LENGTH = 0.014
BUTTON_CAP_REST_Z = 0.044  # cap centre when unpressed
BUTTON_TOP_Z = 0.058  # cap top when unpressed
# The TCP starts pressing this far above the cap top; the cap travels at most its half length.
PRESS_REACH_ABOVE_TOP = 0.03
MAX_PRESS_DEPTH = BUTTON_CAP_HALF_LENGTH
PRESSED_DEPTH = 0.35 * MAX_PRESS_DEPTH  # 0.0049: TCP z <= 0.0831
RELEASED_DEPTH = 0.2 * MAX_PRESS_DEPTH  # 0.0028: TCP z >= 0.0852
# A press counts once the TCP has risen this far above the height where it registered.
CONFIRM_LIFT = 0.1 - 0.015


def press_depth(
    tcp_position: torch.Tensor, button_xy: torch.Tensor, radius: float, inclusive: bool = False
) -> torch.Tensor:
    """(B,) depth = clamp(top + 0.03 − TCP z, 0, 0.014) where the TCP is within ``radius`` (XY).

    ``inclusive`` counts a TCP exactly at ``radius`` as over the button (BatteriesChecker).
    """
    xy_distance = torch.linalg.norm(tcp_position[..., :2] - button_xy, dim=-1)
    over = xy_distance <= radius if inclusive else xy_distance < radius
    depth = (BUTTON_TOP_Z + PRESS_REACH_ABOVE_TOP - tcp_position[..., 2]).clamp(0.0, MAX_PRESS_DEPTH)
    return torch.where(over, depth, torch.zeros_like(depth))


class Button:
    """A base box and a cap cylinder, both kinematic with collision (or visual only)."""

    # Per-env state saved with the env's task state (``MikasaVLABaseEnv.TASK_STATE``).
    STATE_ATTRS: ClassVar[tuple[str, ...]] = ("xy", "quat", "depth")

    def __init__(
        self,
        scene: ManiSkillScene,
        name: str,
        base_half_size: Sequence[float],
        cap_radius: float,
        base_rgba: Sequence[int],
        cap_rgba: Sequence[int],
        num_envs: int,
        device: torch.device | str,
        collision: bool = True,
    ) -> None:
        self.scene = scene
        self.base = self._build(
            scene, f"{name}_base", collision, lambda b, **kw: b.add_box_visual(half_size=base_half_size, **kw),
            lambda b: b.add_box_collision(half_size=base_half_size), base_rgba,
        )
        cap_pose = sapien.Pose(q=UPRIGHT_CYLINDER_QUAT)
        self.cap = self._build(
            scene, f"{name}_cap", collision,
            lambda b, **kw: b.add_cylinder_visual(pose=cap_pose, radius=cap_radius, half_length=BUTTON_CAP_HALF_LENGTH, **kw),
            lambda b: b.add_cylinder_collision(pose=cap_pose, radius=cap_radius, half_length=BUTTON_CAP_HALF_LENGTH),
            cap_rgba,
        )
        self.xy = torch.zeros(num_envs, 2, device=device)
        self.quat = torch.tensor([1.0, 0.0, 0.0, 0.0], device=device).repeat(num_envs, 1)
        self.depth = torch.zeros(num_envs, device=device)

    @staticmethod
    def _build(scene, name, collision, add_visual, add_collision, rgba) -> Actor:
        builder = scene.create_actor_builder()
        add_visual(builder, material=sapien.render.RenderMaterial(base_color=list(rgba01(rgba))))
        if collision:
            add_collision(builder)
        builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
        return builder.build_kinematic(name=name)

    def place(self, env_idx: torch.Tensor, xy: torch.Tensor, quat: torch.Tensor | None = None) -> None:
        """Put the button at ``xy`` ((b, 2)) in envs ``env_idx``, cap up (depth 0)."""
        self.xy[env_idx] = xy.to(self.xy)
        if quat is not None:
            self.quat[env_idx] = quat.to(self.quat)
        self.depth[env_idx] = 0.0
        base_z = torch.full((len(env_idx), 1), BUTTON_BASE_HALF_HEIGHT, device=self.xy.device)
        base = torch.cat([self.xy[env_idx], base_z, self.quat[env_idx]], dim=-1)
        write_actor_poses(self.scene, [self.base], env_idx, base[:, None])
        self._write_cap(env_idx)

    def press_depth(self, tcp_position: torch.Tensor, radius: float, inclusive: bool = False) -> torch.Tensor:
        """(B,) press depth of this button for TCP positions (B, 3); see ``press_depth``."""
        return press_depth(tcp_position, self.xy, radius, inclusive)

    def show_depth(self, depth: torch.Tensor) -> None:
        """Draw each env's cap lowered by ``depth`` ((B,)); envs whose depth is unchanged are skipped.

        Outside ``_initialize_episode`` on the GPU sim the caller applies the writes.
        """
        changed = torch.nonzero(depth != self.depth).flatten()
        if len(changed):
            self.depth[changed] = depth[changed]
            self._write_cap(changed)

    def _write_cap(self, env_idx: torch.Tensor) -> None:
        z = (BUTTON_CAP_REST_Z - self.depth[env_idx])[:, None]
        cap = torch.cat([self.xy[env_idx], z, self.quat[env_idx]], dim=-1)
        write_actor_poses(self.scene, [self.cap], env_idx, cap[:, None])

    @property
    def actors(self) -> list[Actor]:
        """Base and cap."""
        return [self.base, self.cap]


class PressLatch:
    """Per-env press / release / lift state machine of a counted button.

    Starts ready. Each update, in order: (1) a release (depth <= RELEASED_DEPTH) re-arms;
    (2) a raw press (depth >= PRESSED_DEPTH while ready and not pending) records the TCP
    height and waits; (3) the press is confirmed once the TCP has risen CONFIRM_LIFT above
    that height after a release. ``release_gate`` / ``press_gate`` say in which envs steps 1
    and 2-3 may happen (e.g. the action phase; "pressable").
    """

    # Per-env state saved with the env's task state (``MikasaVLABaseEnv.TASK_STATE``).
    STATE_ATTRS: ClassVar[tuple[str, ...]] = ("ready", "pending", "press_start_z")

    def __init__(self, num_envs: int, device: torch.device | str) -> None:
        self.ready = torch.ones(num_envs, dtype=torch.bool, device=device)
        self.pending = torch.zeros(num_envs, dtype=torch.bool, device=device)
        self.press_start_z = torch.zeros(num_envs, device=device)

    def reset(self, env_idx: torch.Tensor) -> None:
        """Ready, nothing pending, in envs ``env_idx``."""
        self.ready[env_idx] = True
        self.pending[env_idx] = False
        self.press_start_z[env_idx] = 0.0

    @property
    def confirm_z(self) -> torch.Tensor:
        """(B,) the TCP height that confirms a registered press: where it registered + CONFIRM_LIFT
        (meaningful where ``pending``)."""
        return self.press_start_z + CONFIRM_LIFT

    def rise_share(self, tcp_z: torch.Tensor) -> torch.Tensor:
        """(B,) the share of CONFIRM_LIFT the TCP has risen above a registered press, in [0, 1];
        0 where no press is pending."""
        rise = ((tcp_z - self.press_start_z) / CONFIRM_LIFT).clamp(0.0, 1.0)
        return torch.where(self.pending, rise, torch.zeros_like(rise))

    def update(
        self, depth: torch.Tensor, tcp_z: torch.Tensor, release_gate: torch.Tensor, press_gate: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Advance one step; returns per env (raw press event, confirmed press event)."""
        self.ready |= release_gate & ~self.ready & (depth <= RELEASED_DEPTH)
        raw = press_gate & self.ready & ~self.pending & (depth >= PRESSED_DEPTH)
        self.press_start_z = torch.where(raw, tcp_z, self.press_start_z)
        self.pending |= raw
        self.ready &= ~raw
        confirmed = press_gate & self.pending & self.ready & (tcp_z >= self.confirm_z)
        self.pending &= ~confirmed
        return raw, confirmed
