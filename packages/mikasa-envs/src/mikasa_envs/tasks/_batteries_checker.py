"""Machinery shared by the two BatteriesChecker families (Easy, Hard).

A tray holds up to 15 upright batteries; the first ``ACTIVE_BATTERIES`` stand in their
slots, a random ``WORKING_BATTERIES`` of them work. Beyond the tray is a socket (a box with
a square hole) and behind it a lamp; to the side a button. The robot checks every active
battery: it drops the battery into the socket (the lamp lights up only for a working
one), takes it back to its slot (Hard; Easy returns it automatically) and presses the
button to confirm. Nothing is ever shown again: which batteries worked is only seen on the
lamp at insertion time (the "checklist" memory).

A per-env stage machine (INSERT -> RETURN -> CONFIRM -> INSERT) runs once per control
step, after the physics substeps (``batteries_checker_hard.md`` §4). It runs inside the
first ``evaluate()`` after a step (on the GPU sim that is after ManiSkill fetches the new
poses); further ``evaluate()`` calls in the same step only report, so reading the info
twice does not advance the machine.

There is no cue or delay phase: ``action_mask`` is always true, ``cue_mask`` always false.
The scene's fixed layout constants and ``slot_offsets`` live in ``_batteries_checker_layout.py``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import sapien
import torch
from mani_skill.utils import sapien_utils
from mani_skill.utils.structs import Actor

from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.building_blocks.buttons import (
    BUTTON_TOP_Z,
    MAX_PRESS_DEPTH,
    PRESSED_DEPTH,
    RELEASED_DEPTH,
    Button,
)
from mikasa_envs.building_blocks.lamps import ColorSwitchLamp
from mikasa_envs.building_blocks.poses import (
    HIDE_OFFSET_Z,
    UPRIGHT_CYLINDER_QUAT,
    write_actor_poses,
    zero_actor_velocities,
)
from mikasa_envs.tasks._batteries_checker_layout import (
    GRASP_CANDIDATE_RADIUS,
    GRASP_MAX_ANGLE_DEG,
    GRASP_MIN_FORCE,
    YAW_90_QUAT,
    _material,
    slot_offsets,
)


class BatteriesCheckerVLABaseEnv(MikasaVLABaseEnv):
    """Base of the BatteriesChecker families: check every battery in the socket, remember the
    working ones, return each (Hard) and confirm each with the button.

    Variants set ``ACTIVE_BATTERIES`` / ``WORKING_BATTERIES``; Easy adds its automatic
    return through ``_after_stage_update``.
    """

    # --- variant knobs
    ACTIVE_BATTERIES: ClassVar[int] = 3
    WORKING_BATTERIES: ClassVar[int] = 1

    # --- stage machine
    STAGE_INSERT: ClassVar[int] = 0
    STAGE_RETURN: ClassVar[int] = 1
    STAGE_CONFIRM: ClassVar[int] = 2

    # --- batteries
    MAX_BATTERIES: ClassVar[int] = 15
    BATTERY_RADIUS: ClassVar[float] = 0.010
    BATTERY_HALF_HEIGHT: ClassVar[float] = 0.030
    BATTERY_FRICTION: ClassVar[float] = 2.0
    BATTERY_RGBA: ClassVar[tuple[int, int, int, int]] = (70, 190, 90, 255)
    BATTERY_QUAT: ClassVar[tuple[float, float, float, float]] = UPRIGHT_CYLINDER_QUAT

    # --- tray (visual only); centre x ~ U[lo, hi), y ~ U[lo, hi)
    TRAY_X_RANGE: ClassVar[tuple[float, float]] = (-0.09, -0.01)
    TRAY_Y_RANGE: ClassVar[tuple[float, float]] = (-0.05, 0.05)
    TRAY_HALF_SIZE: ClassVar[tuple[float, float, float]] = (0.132, 0.076, 0.015)  # local, before the yaw
    TRAY_RGBA: ClassVar[tuple[int, int, int, int]] = (72, 86, 108, 255)
    SLOT_DISC_RADIUS: ClassVar[float] = 0.012
    SLOT_DISC_HALF_HEIGHT: ClassVar[float] = 0.0015
    SLOT_DISC_RGBA: ClassVar[tuple[int, int, int, int]] = (42, 48, 62, 255)

    # --- socket: a box with a square hole; the slot point is where an inserted battery counts
    SOCKET_OFFSET_X: ClassVar[float] = 0.20
    SOCKET_HALF_SIZE: ClassVar[tuple[float, float, float]] = (0.048, 0.040, 0.015)  # local, before the yaw
    SOCKET_HOLE_HALF_WIDTH: ClassVar[float] = 0.0184  # 1.15 × 1.6 × battery radius
    SOCKET_FLOOR_HALF_HEIGHT: ClassVar[float] = 0.00525
    SOCKET_FLOOR_BELOW_CENTRE: ClassVar[float] = 0.00975  # floor plate top at z = 0.0105
    SOCKET_HOLE_DISC_RADIUS: ClassVar[float] = 0.016
    SOCKET_RGBA: ClassVar[tuple[int, int, int, int]] = (88, 92, 98, 255)
    SOCKET_HOLE_RGBA: ClassVar[tuple[int, int, int, int]] = (32, 32, 36, 255)
    SOCKET_SLOT_Z: ClassVar[float] = 0.030
    SOCKET_TOL_XY: ClassVar[float] = 0.010
    SOCKET_TOL_Z: ClassVar[float] = 0.025

    # --- lamp
    LAMP_OFFSET_X: ClassVar[float] = 0.28
    LAMP_OFF_RGB: ClassVar[tuple[int, int, int]] = (255, 255, 255)
    LAMP_ON_RGB: ClassVar[tuple[int, int, int]] = (255, 236, 110)
    LAMP_ON_EMISSION: ClassVar[float] = 3.0
    LAMP_AFTERGLOW_STEPS: ClassVar[int] = 7

    # --- button (virtual press from the TCP height)
    BUTTON_OFFSET_Y: ClassVar[float] = 0.24
    BUTTON_BASE_HALF_SIZE: ClassVar[tuple[float, float, float]] = (0.075, 0.075, 0.015)
    BUTTON_CAP_RADIUS: ClassVar[float] = 0.033
    BUTTON_BASE_RGBA: ClassVar[tuple[int, int, int, int]] = (58, 66, 80, 255)
    BUTTON_CAP_RGBA: ClassVar[tuple[int, int, int, int]] = (205, 110, 110, 255)
    BUTTON_PRESS_RADIUS: ClassVar[float] = 0.075  # inclusive
    BUTTON_TOP_Z: ClassVar[float] = BUTTON_TOP_Z
    BUTTON_MAX_DEPTH: ClassVar[float] = MAX_PRESS_DEPTH
    BUTTON_PRESSED_DEPTH: ClassVar[float] = PRESSED_DEPTH
    BUTTON_RELEASED_DEPTH: ClassVar[float] = RELEASED_DEPTH

    # --- return / success tolerances
    RETURN_TOL_XY: ClassVar[float] = 0.023
    RETURN_TOL_Z: ClassVar[float] = 0.024
    HOME_TOL_FACTOR: ClassVar[float] = 3.0  # checked batteries must stay within 3× the return tolerances

    # --- reward (dense / DENSE_REWARD_MAX = normalized)
    DENSE_REWARD_MAX = 40.0
    ACTION_L2_COEF: ClassVar[float] = 0.01
    ACTION_DELTA_L2_COEF: ClassVar[float] = 0.02
    QVEL_L2_COEF: ClassVar[float] = 0.01

    # No cue or delay phase.
    CUE_PHASE_STEPS = (0, 0)
    EMPTY_PHASE_STEPS = (0, 0)
    RENDER_CAMERA_EYE = (0.6, 0.7, 0.6)
    RENDER_CAMERA_TARGET = (0.0, 0.0, 0.15)

    batteries: list[Actor]

    TASK_STATE = (
        "tray_center",
        "tray_slot_positions",
        "socket_slot_pos",
        "working_mask",
        "checked_mask",
        "found_mask",
        "action_stage",
        "active_battery_idx",
        "lamp_afterglow",
        "press_ready",
        "lamp",
        "button",
        "_events",
        "_grasped",
        "_battery_pos",
        "_tcp_pos",
    )

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.active_battery_count = self.ACTIVE_BATTERIES
        self.button_top_z = self.BUTTON_TOP_Z
        super().__init__(*args, **kwargs)

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        n, dev = self.num_envs, self.device
        self.tray = self._build_tray()
        self.socket = self._build_socket()
        self.batteries = [self._build_battery(k) for k in range(self.MAX_BATTERIES)]
        self.lamp = ColorSwitchLamp(
            self.scene,
            "lamp",
            {"off": (self.LAMP_OFF_RGB, 0.0), "on": (self.LAMP_ON_RGB, self.LAMP_ON_EMISSION)},
            n,
            dev,
        )
        self.button = Button(
            self.scene, "button", self.BUTTON_BASE_HALF_SIZE, self.BUTTON_CAP_RADIUS,
            self.BUTTON_BASE_RGBA, self.BUTTON_CAP_RGBA, n, dev,
        )
        self._finger_links = [link._objs[0] for link in (self.agent.finger1_link, self.agent.finger2_link)]
        self._battery_entities = [b._bodies[0].entity for b in self.batteries] if not self.gpu_sim_enabled else []

        m = self.MAX_BATTERIES
        self._slot_offsets = torch.as_tensor(slot_offsets(m), dtype=torch.float32, device=dev)
        self.tray_center = torch.zeros(n, 2, device=dev)
        self.tray_slot_positions = torch.zeros(n, m, 3, device=dev)
        self.socket_slot_pos = torch.zeros(n, 3, device=dev)
        self.active_mask = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self.active_mask[:, : self.ACTIVE_BATTERIES] = True
        self.working_mask = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self.checked_mask = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self.found_mask = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self.action_stage = torch.zeros(n, dtype=torch.int64, device=dev)
        self.active_battery_idx = torch.full((n,), -1, dtype=torch.int64, device=dev)
        self.lamp_afterglow = torch.zeros(n, dtype=torch.int64, device=dev)
        self.press_ready = torch.ones(n, dtype=torch.bool, device=dev)
        self.oracle_info = torch.zeros(n, self.WORKING_BATTERIES, dtype=torch.uint8, device=dev)
        # This step's results of the stage machine (reported by evaluate, used by the reward).
        self._events: dict[str, torch.Tensor] = {}
        self._grasped = torch.zeros(n, m, dtype=torch.bool, device=dev)
        self._battery_pos = torch.zeros(n, m, 3, device=dev)
        self._tcp_pos = torch.zeros(n, 3, device=dev)
        self._reset_step_results(torch.arange(n, device=dev))
        self._update_pending = False

    def _build_tray(self) -> Actor:
        """Visual-only tray box with a dark disc on top at each slot (local frame, before the yaw)."""
        builder = self.scene.create_actor_builder()
        builder.add_box_visual(half_size=self.TRAY_HALF_SIZE, material=_material(self.TRAY_RGBA))
        disc_material = _material(self.SLOT_DISC_RGBA)
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
        builder.add_box_visual(half_size=[hx, hy, hz], material=_material(self.SOCKET_RGBA))
        builder.add_cylinder_visual(
            pose=sapien.Pose(p=[0, 0, hz + 0.0005], q=UPRIGHT_CYLINDER_QUAT),
            radius=self.SOCKET_HOLE_DISC_RADIUS,
            half_length=0.0005,
            material=_material(self.SOCKET_HOLE_RGBA),
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
            radius=self.BATTERY_RADIUS, half_length=self.BATTERY_HALF_HEIGHT, material=_material(self.BATTERY_RGBA)
        )
        builder.initial_pose = sapien.Pose(p=[0, 0.05 * k, HIDE_OFFSET_Z], q=self.BATTERY_QUAT)
        if k < self.ACTIVE_BATTERIES:
            return builder.build(name=f"battery_{k}")
        return builder.build_kinematic(name=f"battery_{k}")

    # ------------------------------------------------------------- episodes
    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        # No phases (and no random draws for them).
        self.cue_steps_per_env[env_idx] = 0
        self.empty_steps_per_env[env_idx] = 0

    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Torch draws, in this order: tray centre x, y; the working set (top-k of uniform scores).
        b, dev = len(env_idx), self.device
        (x_lo, x_hi), (y_lo, y_hi) = self.TRAY_X_RANGE, self.TRAY_Y_RANGE
        tx = x_lo + (x_hi - x_lo) * torch.rand(b, device=dev)
        ty = y_lo + (y_hi - y_lo) * torch.rand(b, device=dev)
        scores = torch.rand(b, self.ACTIVE_BATTERIES, device=dev)
        working = torch.topk(scores, self.WORKING_BATTERIES, dim=1).indices.sort(dim=1).values

        center = torch.stack([tx, ty], dim=1)
        self.tray_center[env_idx] = center
        slots = torch.zeros(b, self.MAX_BATTERIES, 3, device=dev)
        slots[..., :2] = center[:, None] + self._slot_offsets
        slots[..., 2] = self.BATTERY_HALF_HEIGHT
        self.tray_slot_positions[env_idx] = slots
        self.socket_slot_pos[env_idx] = torch.stack(
            [tx + self.SOCKET_OFFSET_X, ty, torch.full_like(tx, self.SOCKET_SLOT_Z)], dim=1
        )
        mask = torch.zeros(b, self.MAX_BATTERIES, dtype=torch.bool, device=dev)
        mask[torch.arange(b, device=dev)[:, None], working] = True
        self.working_mask[env_idx] = mask
        self.oracle_info[env_idx] = working.to(torch.uint8)
        self._place_scene(env_idx)

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

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self.checked_mask[env_idx] = False
        self.found_mask[env_idx] = False
        self.action_stage[env_idx] = self.STAGE_INSERT
        self.active_battery_idx[env_idx] = -1
        self.lamp_afterglow[env_idx] = 0
        self.press_ready[env_idx] = True
        self._reset_step_results(env_idx)
        # The reset frame reports the state just written; the machine first runs after a step.
        self._update_pending = False

    def _reset_step_results(self, env_idx: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        for name in (
            "socket_has_battery", "socket_has_working", "new_insert_event", "new_return_event",
            "new_confirm_event", "new_button_press_event", "newly_found", "wrong_phase_press",
        ):
            self._events.setdefault(name, torch.zeros(n, dtype=torch.bool, device=dev))[env_idx] = False
        self._events.setdefault("socket_battery_idx", torch.zeros(n, dtype=torch.int64, device=dev))[env_idx] = -1
        self._events.setdefault("button_press_depth", torch.zeros(n, device=dev))[env_idx] = 0.0
        self._grasped[env_idx] = False

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

    # ---------------------------------------------------------- stage machine
    def _after_control_step(self) -> None:
        # On the GPU sim the new poses are fetched after this hook; the machine runs in evaluate().
        self._update_pending = True

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

    # --------------------------------------------------------------- evaluate
    def evaluate(self) -> dict:
        """Advance the stage machine (once per step), then report it and success (§5, §7)."""
        pos = self.battery_positions()
        tcp = self.agent.tcp.pose.p
        if self._update_pending:
            self._update_pending = False
            pos = self._update_stage_machine(pos, tcp)
        self._battery_pos, self._tcp_pos = pos, tcp
        n, dev = self.num_envs, self.device
        checked_count = self.checked_mask.sum(dim=1)
        found_count = self.found_mask.sum(dim=1)
        all_checked = checked_count >= self.ACTIVE_BATTERIES
        home_ok = (self._near_home(pos, self.HOME_TOL_FACTOR) | ~self.checked_mask).all(dim=1)
        action_mask = torch.ones(n, dtype=torch.bool, device=dev)
        success = action_mask & (found_count >= self.WORKING_BATTERIES) & all_checked & home_ok
        events = self._events
        return dict(
            success=success,
            action_mask=action_mask,
            cue_mask=torch.zeros(n, dtype=torch.bool, device=dev),
            action_stage=self.action_stage.clone(),
            active_battery_idx=self.active_battery_idx.clone(),
            socket_has_battery=events["socket_has_battery"].clone(),
            socket_battery_idx=events["socket_battery_idx"].clone(),
            socket_has_working=events["socket_has_working"].clone(),
            active_battery_count=self.active_mask.sum(dim=1),
            checked_count=checked_count,
            found_working_count=found_count,
            target_working_count=self.working_mask.sum(dim=1),
            all_checked=all_checked,
            new_insert_event=events["new_insert_event"].clone(),
            new_return_event=events["new_return_event"].clone(),
            new_confirm_event=events["new_confirm_event"].clone(),
            new_button_press_event=events["new_button_press_event"].clone(),
            button_press_depth=events["button_press_depth"].clone(),
            obj_to_goal_pos=self.socket_slot_pos - tcp,
        )

    def _terminated(self, info: dict) -> torch.Tensor:
        """Success ends the episode too (``terminated`` = success, as upstream)."""
        return super()._terminated(info) | info["success"]

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs.update(
                battery_pose=self.battery_raw_poses().reshape(self.num_envs, -1),
                tray_pose=self.tray.pose.raw_pose,
                socket_pose=self.socket.pose.raw_pose,
                button_base_pose=self.button.base.pose.raw_pose,
                button_cap_pose=self.button.cap.pose.raw_pose,
                lamp_off_pose=self.lamp.bulbs[self.lamp.bulb_index("off")].pose.raw_pose,
                lamp_on_pose=self.lamp.bulbs[self.lamp.bulb_index("on")].pose.raw_pose,
                action_stage=self.action_stage,
                action_mask=info["action_mask"],
                active_mask=self.active_mask,
                oracle_info=self.oracle_info,
            )
        return obs

    # ---------------------------------------------------------------- reward
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

        action_l2, delta_l2 = self._action_smoothness_terms(action)
        qvel_l2 = torch.linalg.norm(self.arm_qvel, dim=-1)
        smooth = (
            self.ACTION_L2_COEF * torch.tanh(2 * action_l2)
            + self.ACTION_DELTA_L2_COEF * torch.tanh(5 * delta_l2)
            + self.QVEL_L2_COEF * torch.tanh(2 * qvel_l2)
        )
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

