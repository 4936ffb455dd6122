"""The per-env stage machine of the BatteriesChecker base (``_batteries_checker.py``,
``batteries_checker_hard.md`` §4): INSERT -> RETURN -> CONFIRM -> INSERT, advanced once per
control step from ``evaluate()``, with the grasp test, the socket / home tests and the
battery teleports it uses.

``BatteriesCheckerStageMachineMixin`` relies on the class constants and per-env state of
``BatteriesCheckerVLABaseEnv`` (``action_stage``, ``working_mask``, ``lamp``, ``button``, ...),
which it precedes in its method resolution order.
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils import sapien_utils

from mikasa_envs.building_blocks.poses import write_actor_poses, zero_actor_velocities
from mikasa_envs.tasks._batteries_checker_layout import (
    GRASP_CANDIDATE_RADIUS,
    GRASP_MAX_ANGLE_DEG,
    GRASP_MIN_FORCE,
)


class BatteriesCheckerStageMachineMixin:
    """One step of the stage machine (``_update_stage_machine``), the family hook run after it
    (``_after_stage_update``, Easy's automatic return) and the helpers it uses: the
    contact-force grasp test, the socket and home tests, and the teleports that set a battery
    in the socket or back in its slot."""

    def _teleport_batteries(self, env_idx: torch.Tensor, battery_idx: torch.Tensor, positions: torch.Tensor) -> None:
        """Set battery ``battery_idx[i]`` of env ``env_idx[i]`` upright at ``positions[i]``, at rest."""
        quat = torch.tensor(self.BATTERY_QUAT, device=self.device)
        for k in torch.unique(battery_idx).tolist():
            rows = battery_idx == k
            envs = env_idx[rows]
            poses = torch.cat([positions[rows], quat.expand(len(envs), 4)], dim=-1)
            write_actor_poses(self.scene, [self.batteries[k]], envs, poses[:, None])
            zero_actor_velocities(self.scene, [self.batteries[k]], envs)

    def _update_stage_machine(self, pos: torch.Tensor, tcp: torch.Tensor) -> torch.Tensor:
        """One step of §4 (socket, afterglow, insert, lamp, button, return, confirm) for TCP
        positions ``tcp``; returns the battery positions after any teleport."""
        b, dev = self.num_envs, self.device
        rows = torch.arange(b, device=dev)
        grasped = self._grasp_flags(pos)

        # 1. Socket detection.
        in_socket = self._in_socket(pos, grasped)
        socket_has = in_socket.any(dim=1)
        socket_idx = torch.where(socket_has, in_socket.int().argmax(dim=1), -1)
        # 2. Afterglow.
        self.lamp_afterglow = (self.lamp_afterglow - 1).clamp(min=0)
        # 3. Insert.
        insert = (self.action_stage == self.STAGE_INSERT) & socket_has
        inserted = socket_idx.clamp(min=0)
        self.action_stage = torch.where(insert, self.STAGE_RETURN, self.action_stage)
        self.active_battery_idx = torch.where(insert, socket_idx, self.active_battery_idx)
        inserted_working = insert & self.working_mask[rows, inserted]
        self.lamp_afterglow = torch.where(inserted_working, self.LAMP_AFTERGLOW_STEPS, self.lamp_afterglow)
        if bool(insert.any()):
            envs = torch.nonzero(insert).flatten()
            # Centred in the hole, resting on the floor plate, upright and still.
            rest = self.socket_slot_pos[envs].clone()
            rest[:, 2] = self._socket_rest_z
            self._teleport_batteries(envs, inserted[envs], rest)
            pos = pos.clone()
            pos[envs, inserted[envs]] = rest
        # 4. Lamp.
        socket_has_working = (in_socket & self.working_mask).any(dim=1)
        self.lamp.show(rows, (socket_has_working | (self.lamp_afterglow > 0)).long())
        # 5. Button.
        depth = self.button.press_depth(tcp, self.BUTTON_PRESS_RADIUS, inclusive=True)
        self.button.show_depth(depth)
        press = (depth >= self.BUTTON_PRESSED_DEPTH) & self.press_ready
        self.press_ready = (self.press_ready & ~press) | (depth <= self.BUTTON_RELEASED_DEPTH)
        # 6. Return.
        active = self.active_battery_idx.clamp(min=0)
        returned = (
            (self.action_stage == self.STAGE_RETURN)
            & (self.active_battery_idx >= 0)
            & self._near_home(pos, 1.0)[rows, active]
            & ~grasped[rows, active]
            & ~in_socket[rows, active]
        )
        self.action_stage = torch.where(returned, self.STAGE_CONFIRM, self.action_stage)
        # 7. Confirm.
        confirm = (self.action_stage == self.STAGE_CONFIRM) & press
        wrong_phase_press = press & (self.action_stage != self.STAGE_CONFIRM)
        newly_checked = confirm & ~self.checked_mask[rows, active]
        newly_found = newly_checked & self.working_mask[rows, active]
        self.checked_mask[rows[confirm], active[confirm]] = True
        self.found_mask[rows[newly_found], active[newly_found]] = True
        self.action_stage = torch.where(confirm, self.STAGE_INSERT, self.action_stage)
        self.active_battery_idx = torch.where(confirm, -1, self.active_battery_idx)

        self._events.update(
            socket_has_battery=socket_has,
            socket_battery_idx=socket_idx,
            socket_has_working=socket_has_working,
            new_insert_event=insert,
            new_return_event=returned,
            new_confirm_event=confirm,
            new_button_press_event=press,
            button_press_depth=depth,
            newly_found=newly_found,
            wrong_phase_press=wrong_phase_press,
        )
        self._grasped = grasped
        pos = self._after_stage_update(pos)
        if self.gpu_sim_enabled:
            self.scene.px.gpu_apply_rigid_dynamic_data()
        return pos

    def _after_stage_update(self, pos: torch.Tensor) -> torch.Tensor:
        """Family hook run at the end of the stage machine (Easy's automatic return)."""
        return pos

    def _return_active_home(self, env_mask: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        """Put each masked env's active battery back in its slot (upright, at rest); returns
        the updated (B, 15, 3) battery positions."""
        envs = torch.nonzero(env_mask).flatten()
        if len(envs) == 0:
            return pos
        battery = self.active_battery_idx[envs]
        home = self.tray_slot_positions[envs, battery]
        self._teleport_batteries(envs, battery, home)
        pos = pos.clone()
        pos[envs, battery] = home
        return pos

    @property
    def _socket_rest_z(self) -> float:
        floor_top = self.SOCKET_HALF_SIZE[2] - self.SOCKET_FLOOR_BELOW_CENTRE + self.SOCKET_FLOOR_HALF_HEIGHT
        return floor_top + self.BATTERY_HALF_HEIGHT

    def _in_socket(self, pos: torch.Tensor, grasped: torch.Tensor) -> torch.Tensor:
        """(B, 15) active, not grasped, centre within the socket tolerances of the slot point."""
        offset = pos - self.socket_slot_pos[:, None]
        return (
            self.active_mask
            & (torch.linalg.norm(offset[..., :2], dim=-1) <= self.SOCKET_TOL_XY)
            & (offset[..., 2].abs() <= self.SOCKET_TOL_Z)
            & ~grasped
        )

    def _near_home(self, pos: torch.Tensor, scale: float) -> torch.Tensor:
        """(B, 15) centre within ``scale`` × the return tolerances of its own slot."""
        offset = pos - self.tray_slot_positions
        return (torch.linalg.norm(offset[..., :2], dim=-1) <= scale * self.RETURN_TOL_XY) & (
            offset[..., 2].abs() <= scale * self.RETURN_TOL_Z
        )

    # ------------------------------------------------------------ grasp test
    def _grasp_flags(self, positions: torch.Tensor) -> torch.Tensor:
        """(B, 15) the contact-force grasp test (ManiSkill's Panda ``is_grasping``) per active battery."""
        flags = torch.zeros(self.num_envs, self.MAX_BATTERIES, dtype=torch.bool, device=self.device)
        if self.gpu_sim_enabled:
            for k in range(self.ACTIVE_BATTERIES):
                flags[:, k] = self.agent.is_grasping(self.batteries[k])
            return flags
        # CPU (one env): one pass over the contact list, in numpy. Only batteries near the
        # TCP can touch both fingers.
        tcp = self.agent.tcp._objs[0].entity_pose.p
        near = np.linalg.norm(positions[0, : self.ACTIVE_BATTERIES].numpy() - tcp, axis=-1) < GRASP_CANDIDATE_RADIUS
        candidates = np.flatnonzero(near).tolist()
        if not candidates:
            return flags
        contacts = self.scene.px.get_contacts()
        entities = [self._battery_entities[k] for k in candidates]
        grasp = np.ones(len(candidates), dtype=bool)
        for finger, sign in zip(self._finger_links, (1.0, -1.0), strict=True):
            pairs = sapien_utils.get_multiple_pairwise_contacts(contacts, finger.entity, entities)
            force = np.array([sapien_utils.compute_total_impulse(pairs[e]) for e in entities]) / self.scene.px.timestep
            # The finger's opening direction: its local +y (finger 1) or −y (finger 2).
            direction = sign * finger.entity_pose.to_transformation_matrix()[:3, 1]
            magnitude = np.linalg.norm(force, axis=-1)
            cos = force @ direction / np.maximum(magnitude * np.linalg.norm(direction), 1e-12)
            angle = np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)))
            grasp &= (magnitude >= GRASP_MIN_FORCE) & (angle <= GRASP_MAX_ANGLE_DEG)
        flags[0, candidates] = torch.from_numpy(grasp).to(self.device)
        return flags
