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
The scene's fixed layout constants and ``slot_offsets`` live in ``_batteries_checker_layout.py``,
the stage machine in ``_batteries_checker_stage.py``, and the scene building / placement /
pose queries and the dense reward in ``_batteries_checker_mixins.py``; names that lived
here before the split are re-exported.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import torch
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
from mikasa_envs.building_blocks.poses import (  # noqa: F401  (HIDE_OFFSET_Z, write/zero_*: re-exported)
    HIDE_OFFSET_Z,
    UPRIGHT_CYLINDER_QUAT,
    write_actor_poses,
    zero_actor_velocities,
)
from mikasa_envs.family import Chance, TaskSpec
from mikasa_envs.tasks._batteries_checker_layout import (  # noqa: F401  (all but slot_offsets: re-exported)
    GRASP_CANDIDATE_RADIUS,
    GRASP_MAX_ANGLE_DEG,
    GRASP_MIN_FORCE,
    YAW_90_QUAT,
    flat_material,
    slot_offsets,
)
from mikasa_envs.tasks._batteries_checker_mixins import (
    BatteriesCheckerRewardMixin,
    BatteriesCheckerSceneMixin,
)
from mikasa_envs.tasks._batteries_checker_stage import BatteriesCheckerStageMachineMixin


class BatteriesCheckerVLABaseEnv(
    BatteriesCheckerStageMachineMixin,
    BatteriesCheckerSceneMixin,
    BatteriesCheckerRewardMixin,
    MikasaVLABaseEnv,
):
    """Base of the BatteriesChecker families: check every battery in the socket, remember the
    working ones, return each (Hard) and confirm each with the button.

    Variants set ``ACTIVE_BATTERIES`` / ``WORKING_BATTERIES``; Easy adds its automatic
    return through ``_after_stage_update``. The stage machine, the scene's builders and
    pose queries, and the dense reward come from the mixins.
    """

    # --- variant knobs
    ACTIVE_BATTERIES: ClassVar[int] = 3
    CHECK_CYCLE_STEPS: ClassVar[int]  # the oracle's steps per check cycle (chance rule)
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

    # ------------------------------------------------------------------ step
    def _after_control_step(self) -> None:
        # On the GPU sim the new poses are fetched after this hook; the machine runs in evaluate().
        self._update_pending = True

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


def coupon_chance(n: int, draws: int) -> float:
    """P(``draws`` uniform picks among ``n`` items pick every item) (inclusion-exclusion)."""
    return sum((-1) ** j * math.comb(n, j) * ((n - j) / n) ** draws for j in range(n + 1))


def batteries_checker_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of the BatteriesChecker families (a checklist): the chance that check
    cycles on uniformly drawn batteries cover all of them within the horizon."""
    n = env_class.ACTIVE_BATTERIES
    cycles = task.max_episode_steps // env_class.CHECK_CYCLE_STEPS
    return Chance(
        coupon_chance(n, cycles),
        f"no discrete answer (a checklist): {cycles} check cycles fit the horizon; chance that "
        f"cycles on uniformly drawn batteries cover all {n}",
    )
