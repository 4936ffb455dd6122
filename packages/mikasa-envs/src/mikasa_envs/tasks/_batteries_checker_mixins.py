"""Mixins of the BatteriesChecker base (``_batteries_checker.py``): the scene's actors
(building the tray, socket and batteries, placing every fixture at the episode's tray centre,
reading the batteries' poses, the button and the lamp) and the dense reward.

They rely on the class constants and per-env state of ``BatteriesCheckerVLABaseEnv``
(``TRAY_HALF_SIZE``, ``tray_slot_positions``, ``batteries``, ``_events``, ...), which they
precede in its method resolution order.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import sapien
import torch
from mani_skill.utils.structs import Actor

from mikasa_envs.building_blocks.poses import (
    HIDE_OFFSET_Z,
    UPRIGHT_CYLINDER_QUAT,
    write_actor_poses,
    zero_actor_velocities,
)
from mikasa_envs.tasks._batteries_checker_layout import YAW_90_QUAT, flat_material, slot_offsets


class BatteriesCheckerSceneMixin:
    """Tray, socket and batteries: their builders, the per-episode placement of every fixture
    (lamp and button included) and the pose queries (CPU and GPU paths)."""

    # ---------------------------------------------------------------- build
    def _build_tray(self) -> Actor:
        """Visual-only tray box with a dark disc on top at each slot (local frame, before the yaw)."""
        builder = self.scene.create_actor_builder()
        builder.add_box_visual(half_size=self.TRAY_HALF_SIZE, material=flat_material(self.TRAY_RGBA))
        disc_material = flat_material(self.SLOT_DISC_RGBA)
        disc_z = self.TRAY_HALF_SIZE[2] + self.SLOT_DISC_HALF_HEIGHT
        for dx, dy in slot_offsets(self.MAX_BATTERIES):
            # World offset (dx, dy) in the tray frame turned by +90°: local (dy, −dx).
            builder.add_cylinder_visual(
                pose=sapien.Pose(p=[dy, -dx, disc_z], q=UPRIGHT_CYLINDER_QUAT),
                radius=self.SLOT_DISC_RADIUS,
                half_length=self.SLOT_DISC_HALF_HEIGHT,
                material=disc_material,
            )
        builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
        return builder.build_kinematic(name="tray")

    def _build_socket(self) -> Actor:
        """A box with a square hole: collision = floor plate + four walls; visual = the full box
        with a dark disc marking the hole (local frame, before the yaw)."""
        hx, hy, hz = self.SOCKET_HALF_SIZE
        hole = self.SOCKET_HOLE_HALF_WIDTH
        floor_hz = self.SOCKET_FLOOR_HALF_HEIGHT
        wall_x = (hx - hole) / 2  # half thickness of the walls on the local ±x sides (0.0148)
        wall_y = (hy - hole) / 2  # ... on the local ±y sides (0.0108)
        builder = self.scene.create_actor_builder()
        builder.add_box_collision(pose=sapien.Pose(p=[0, 0, -self.SOCKET_FLOOR_BELOW_CENTRE]), half_size=[hx, hy, floor_hz])
        for side in (-1.0, 1.0):
            builder.add_box_collision(pose=sapien.Pose(p=[side * (hole + wall_x), 0, 0]), half_size=[wall_x, hy, hz])
            builder.add_box_collision(pose=sapien.Pose(p=[0, side * (hole + wall_y), 0]), half_size=[hole, wall_y, hz])
        builder.add_box_visual(half_size=[hx, hy, hz], material=flat_material(self.SOCKET_RGBA))
        builder.add_cylinder_visual(
            pose=sapien.Pose(p=[0, 0, hz + 0.0005], q=UPRIGHT_CYLINDER_QUAT),
            radius=self.SOCKET_HOLE_DISC_RADIUS,
            half_length=0.0005,
            material=flat_material(self.SOCKET_HOLE_RGBA),
        )
        builder.initial_pose = sapien.Pose(p=[0, 0, HIDE_OFFSET_Z])
        return builder.build_kinematic(name="socket")

    def _build_battery(self, k: int) -> Actor:
        """Battery k: an upright cylinder. Only active ones are dynamic; the others never
        leave their hiding place, so they are kinematic (nothing to pin)."""
        builder = self.scene.create_actor_builder()
        material = sapien.physx.PhysxMaterial(self.BATTERY_FRICTION, self.BATTERY_FRICTION, 0.0)
        builder.add_cylinder_collision(
            radius=self.BATTERY_RADIUS, half_length=self.BATTERY_HALF_HEIGHT, material=material
        )
        builder.add_cylinder_visual(
            radius=self.BATTERY_RADIUS, half_length=self.BATTERY_HALF_HEIGHT, material=flat_material(self.BATTERY_RGBA)
        )
        builder.initial_pose = sapien.Pose(p=[0, 0.05 * k, HIDE_OFFSET_Z], q=self.BATTERY_QUAT)
        if k < self.ACTIVE_BATTERIES:
            return builder.build(name=f"battery_{k}")
        return builder.build_kinematic(name=f"battery_{k}")

    # ---------------------------------------------------------------- place
    def _place_scene(self, env_idx: torch.Tensor) -> None:
        """Tray, socket, lamp, button and batteries at this episode's places."""
        b, dev = len(env_idx), self.device
        center = self.tray_center[env_idx]
        yaw = torch.tensor(YAW_90_QUAT, device=dev).expand(b, 4)
        half_z = torch.full((b, 1), self.TRAY_HALF_SIZE[2], device=dev)
        tray = torch.cat([center, half_z, yaw], dim=1)
        socket = torch.cat([self.socket_slot_pos[env_idx, :2], half_z, yaw], dim=1)
        write_actor_poses(self.scene, [self.tray, self.socket], env_idx, torch.stack([tray, socket], dim=1))
        lamp_xyz = torch.cat([center + torch.tensor([self.LAMP_OFFSET_X, 0.0], device=dev), torch.zeros(b, 1, device=dev)], 1)
        self.lamp.place(env_idx, lamp_xyz, bulb=0)
        self.button.place(env_idx, center + torch.tensor([0.0, self.BUTTON_OFFSET_Y], device=dev), yaw)
        # Active batteries stand in their slots; the others are parked above theirs.
        positions = self.tray_slot_positions[env_idx].clone()
        positions[:, self.ACTIVE_BATTERIES :, 2] = HIDE_OFFSET_Z
        quat = torch.tensor(self.BATTERY_QUAT, device=dev).expand(b, self.MAX_BATTERIES, 4)
        write_actor_poses(self.scene, self.batteries, env_idx, torch.cat([positions, quat], dim=-1))
        zero_actor_velocities(self.scene, self.batteries[: self.ACTIVE_BATTERIES], env_idx)

    # --------------------------------------------------------------- queries
    def battery_raw_poses(self) -> torch.Tensor:
        """(B, 15, 7) raw poses of every battery (hidden ones included)."""
        if not self.gpu_sim_enabled:
            rows = [np.concatenate([(pose := b._objs[0].pose).p, pose.q]) for b in self.batteries]
            return torch.from_numpy(np.asarray(rows, dtype=np.float32))[None].to(self.device)
        return torch.stack([b.pose.raw_pose for b in self.batteries], dim=1)

    def battery_positions(self) -> torch.Tensor:
        """(B, 15, 3) current battery centres."""
        if not self.gpu_sim_enabled:
            rows = [b._objs[0].pose.p for b in self.batteries]
            return torch.from_numpy(np.asarray(rows, dtype=np.float32))[None].to(self.device)
        return torch.stack([b.pose.p for b in self.batteries], dim=1)

    @property
    def button_xy(self) -> torch.Tensor:
        """(B, 2) the button centre."""
        return self.button.xy

    def lamp_is_on(self) -> torch.Tensor:
        """(B,) whether the yellow bulb is the one shown."""
        return self.lamp.shown == self.lamp.bulb_index("on")


class BatteriesCheckerRewardMixin:
    """The stage-shaped dense reward (``batteries_checker_hard.md`` §6); it reads the step's
    results that the stage machine left in ``_events``, ``_grasped``, ``_battery_pos`` and
    ``_tcp_pos``."""

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Stage-shaped reaching / carrying / returning / pressing terms plus event bonuses (§6); 40 on success."""
        b, dev = self.num_envs, self.device
        rows = torch.arange(b, device=dev)
        pos, tcp, events = self._battery_pos, self._tcp_pos, self._events
        stage = self.action_stage
        s_insert = (stage == self.STAGE_INSERT).float()
        s_return = (stage == self.STAGE_RETURN).float()
        s_confirm = (stage == self.STAGE_CONFIRM).float()

        to_tcp = torch.linalg.norm(pos - tcp[:, None], dim=-1)
        unchecked = self.active_mask & ~self.checked_mask
        nearest = torch.where(unchecked, to_tcp, torch.full_like(to_tcp, float("inf"))).min(dim=1).values
        reach_unchecked = torch.where(unchecked.any(dim=1), 1 - torch.tanh(4 * nearest), torch.zeros_like(nearest))
        grasped_any = self._grasped.any(dim=1)
        carried = pos[rows, self._grasped.int().argmax(dim=1)]
        carry = torch.where(
            grasped_any, 1 - torch.tanh(4 * torch.linalg.norm(carried - self.socket_slot_pos, dim=-1)), torch.zeros(b, device=dev)
        )
        active = self.active_battery_idx.clamp(min=0)
        return_reward = 1 - torch.tanh(6 * torch.linalg.norm(pos[rows, active] - self.tray_slot_positions[rows, active], dim=-1))
        # Upstream measures the "button" reach to the socket point (obj_to_goal_pos), see quirk 2.
        button_reach = 1 - torch.tanh(8 * torch.linalg.norm(info["obj_to_goal_pos"], dim=-1))
        button_press = (events["button_press_depth"] / self.BUTTON_MAX_DEPTH).clamp(0, 1)

        smooth, _ = self.smoothness_penalty(action)
        insert, returned, confirm = (events[k].float() for k in ("new_insert_event", "new_return_event", "new_confirm_event"))
        newly_found, wrong_press = events["newly_found"].float(), events["wrong_phase_press"].float()
        reward = (
            s_insert * (1.2 * reach_unchecked + 2.0 * carry)
            + s_return * 3.0 * return_reward
            + s_confirm * (1.8 * button_reach + 2.5 * button_press)
            + 5.0 * insert + 6.0 * returned + 7.0 * confirm + 12.0 * newly_found
            - 2.0 * wrong_press
            - smooth
        )
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = dict(
            reach_unchecked=reach_unchecked,
            carry_reward=carry,
            return_reward=return_reward,
            button_reach_reward=button_reach,
            button_press_reward=button_press,
            insert_event=events["new_insert_event"],
            return_event=events["new_return_event"],
            confirm_event=events["new_confirm_event"],
            newly_found=events["newly_found"],
            wrong_phase_press=events["wrong_phase_press"],
            smooth_penalty=smooth,
            success=info["success"],
        )
        return reward
