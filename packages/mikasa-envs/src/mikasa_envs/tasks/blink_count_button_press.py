"""BlinkCountButtonPress: count a lamp's blinks, press a button that many times, submit.

A blue lamp blinks N times during the cue while a red phase lamp is lit; when the phase
lamp turns green the robot presses the red button exactly N times (press, come back up)
and then the black button to submit. Both buttons are "virtual" (``buttons.py``): presses
are read from the TCP height over the cap. There is no separate memory phase; the cue
ends with the last blink's dark time (``blink_count_button_press.md``).

State advances once per frame inside ``evaluate`` (after the physics of the step, as the
reference does), guarded so that a second ``evaluate`` call for the same frame neither
double-counts presses nor moves the caps again.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import torch

from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.building_blocks.buttons import (
    BUTTON_BASE_HALF_HEIGHT,
    BUTTON_CAP_REST_Z,
    BUTTON_TOP_Z,
    CONFIRM_LIFT,
    MAX_PRESS_DEPTH,
    PRESSED_DEPTH,
    RELEASED_DEPTH,
    Button,
    PressLatch,
)
from mikasa_envs.building_blocks.lamps import ColorSwitchLamp
from mikasa_envs.building_blocks.poses import positions_to_poses
from mikasa_envs.family import Chance, TaskFamily, TaskSpec
from mikasa_envs.registration import register_task


def blink_count_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule: a uniform guess among the possible blink counts."""
    lo, hi = env_class.BLINK_COUNT_RANGE
    k = hi - lo + 1
    return Chance(1 / k, f"1/{k}: the blink count is one of {lo}..{hi}")


FAMILY = TaskFamily(
    "blink_count_button_press",
    hidden="the number of blinks, counted during the cue, and the presses made so far",
    overlays="blink_count",
    wrapper_table_rank=(29, 30),
    chance=blink_count_chance,
)


DEFAULT_BLINK_RGB = (0, 0, 255)
# Bulb names of the two lamps (ColorSwitchLamp indices follow this order).
BLINK_BULBS = ("off", "on")
PHASE_BULBS = ("wait", "ready")


def blink_rgb255(color: Sequence[float]) -> tuple[float, float, float]:
    """The ``blink_color`` kwarg as RGB 0-255: RGB or RGBA, in 0-1 (all values <= 1) or 0-255."""
    values = [float(v) for v in color]
    if len(values) not in (3, 4) or any(not 0.0 <= v <= 255.0 for v in values):
        raise ValueError(f"blink_color must be RGB or RGBA with values in 0-1 or 0-255, got {tuple(color)!r}")
    scale = 255.0 if max(values) <= 1.0 else 1.0
    r, g, b = (v * scale for v in values[:3])
    return r, g, b


def _with_rows(values: torch.Tensor, env_idx: torch.Tensor, value: float | bool) -> torch.Tensor:
    """A copy of ``values`` whose rows ``env_idx`` are set to ``value``."""
    values = values.clone()
    values[env_idx] = value
    return values


class BlinkCountButtonPressVLABaseEnv(MikasaVLABaseEnv):
    """**Task Description:** during the cue a lamp blinks N times (blue by default) while a
    second lamp shows red; when that lamp turns green, press the red button exactly N times
    (each press: push down over the cap, come back up), then press the black button to
    submit the count.

    **Randomizations:** N, the dark steps before the first blink and each blink's dark
    time (3-5 steps; every blink is lit for 3 steps); the red button's position
    (x ~ U[-0.15, -0.05), y ~ U[-0.12, 0.12)), the black button and both lamps keep fixed
    offsets from it; arm joint noise.

    **Success Conditions:** in the action phase, a submit (black button pressed) while the
    red button's counted presses equal N. Pushing the red button down more than N times,
    or submitting another count, fails the episode; success and failure both terminate it.
    """

    LANGUAGE_INSTRUCTION = (
        "Count how many times the blue lamp blinks, press the red button exactly that many times "
        "when the red lamp turns green, then press the black button to submit your answer."
    )
    DENSE_REWARD_MAX = 30.0
    FAIL_PENALTY: ClassVar[float] = 25.0

    # Inclusive ranges: blink count N, dark steps before the first blink, each blink's dark time.
    BLINK_COUNT_RANGE: ClassVar[tuple[int, int]] = (1, 3)
    PRE_BLINK_STEPS: ClassVar[tuple[int, int]] = (5, 10)
    BLINK_ON_STEPS: ClassVar[int] = 3
    BLINK_OFF_STEPS: ClassVar[tuple[int, int]] = (3, 5)
    # No memory delay: the action phase starts when the cue ends.
    EMPTY_PHASE_STEPS = (0, 0)

    RENDER_CAMERA_EYE = (0.6, 0.7, 0.6)
    RENDER_CAMERA_TARGET = (0.0, 0.0, 0.15)

    # Red ("count") button: x ~ U[lo, hi), y ~ U[lo, hi); the black ("submit") one sits
    # BUTTON_CONFIRM_OFFSET_Y to +y (clamped to BUTTON_CONFIRM_Y_LIMIT, never active).
    BUTTON_X_RANGE: ClassVar[tuple[float, float]] = (-0.15, -0.05)
    BUTTON_Y_RANGE: ClassVar[tuple[float, float]] = (-0.12, 0.12)
    BUTTON_CONFIRM_OFFSET_Y: ClassVar[float] = 0.16
    BUTTON_CONFIRM_Y_LIMIT: ClassVar[float] = 0.28
    BUTTON_BASE_HALF_SIZE: ClassVar[tuple[float, float, float]] = (0.065, 0.065, BUTTON_BASE_HALF_HEIGHT)
    BUTTON_CAP_RADIUS: ClassVar[float] = 0.03
    BUTTON_PRESS_RADIUS: ClassVar[float] = 0.065
    BUTTON_TOP_Z: ClassVar[float] = BUTTON_TOP_Z
    BUTTON_BASE_RGBA: ClassVar[tuple[int, int, int, int]] = (55, 64, 78, 255)
    BUTTON_CAP_RGBA: ClassVar[tuple[int, int, int, int]] = (210, 80, 80, 255)
    BUTTON_CONFIRM_BASE_RGBA: ClassVar[tuple[int, int, int, int]] = (40, 40, 40, 255)
    BUTTON_CONFIRM_CAP_RGBA: ClassVar[tuple[int, int, int, int]] = (20, 20, 20, 255)
    # A press is counted once the TCP rises this much (less the tolerance) above where it
    # registered (buttons.CONFIRM_LIFT).
    REQUIRED_LIFT_HEIGHT: ClassVar[float] = 0.1
    LIFT_TOLERANCE: ClassVar[float] = 0.1 - CONFIRM_LIFT

    # Lamps stand on the table at these offsets from the red button. (Upstream names the
    # phase lamp's offset an x offset but applies it along -y; spec quirk 1.)
    BLINK_LAMP_OFFSET: ClassVar[tuple[float, float]] = (0.22, 0.0)
    PHASE_LAMP_OFFSET: ClassVar[tuple[float, float]] = (0.22, -0.20)
    BLINK_OFF_RGB: ClassVar[tuple[int, int, int]] = (245, 245, 245)
    BLINK_EMISSION: ClassVar[float] = 20.0
    PHASE_WAIT_RGB: ClassVar[tuple[int, int, int]] = (255, 0, 0)
    PHASE_READY_RGB: ClassVar[tuple[int, int, int]] = (0, 255, 0)
    PHASE_EMISSION: ClassVar[float] = 3.0

    def __init__(self, *args: Any, blink_color: Sequence[float] = DEFAULT_BLINK_RGB, **kwargs: Any) -> None:
        self.blink_color = blink_rgb255(blink_color)
        super().__init__(*args, **kwargs)

    GPU_MEMORY: ClassVar[dict[str, int]] = {"found_lost_pairs_capacity": 2**25, "max_rigid_patch_count": 2**18}
    TASK_STATE = (
        "button", "confirm_button", "blink_lamp", "phase_lamp", "target_blinks", "blink_start_steps",
        "blink_on_schedule", "blink_off_schedule", "latch", "press_count", "raw_press_count",
        "confirm_press_ready", "submit_attempted", "submit_success", "failed", "_events", "_advanced_at",
        "_tcp_raw_pose", "_tcp_position",
    )

    @property
    def max_blinks(self) -> int:
        """The largest N of this variant (width of the schedule tensors)."""
        return self.BLINK_COUNT_RANGE[1]

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        n, device = self.num_envs, self.device
        self.button = Button(
            self.scene, "count_button", self.BUTTON_BASE_HALF_SIZE, self.BUTTON_CAP_RADIUS,
            self.BUTTON_BASE_RGBA, self.BUTTON_CAP_RGBA, n, device,
        )
        self.confirm_button = Button(
            self.scene, "confirm_button", self.BUTTON_BASE_HALF_SIZE, self.BUTTON_CAP_RADIUS,
            self.BUTTON_CONFIRM_BASE_RGBA, self.BUTTON_CONFIRM_CAP_RGBA, n, device,
        )
        self.blink_lamp = ColorSwitchLamp(
            self.scene, "blink_lamp",
            {"off": (self.BLINK_OFF_RGB, 0.0), "on": (self.blink_color, self.BLINK_EMISSION)}, n, device,
        )
        self.phase_lamp = ColorSwitchLamp(
            self.scene, "phase_lamp",
            {"wait": (self.PHASE_WAIT_RGB, self.PHASE_EMISSION), "ready": (self.PHASE_READY_RGB, self.PHASE_EMISSION)},
            n, device,
        )
        k = self.max_blinks
        # Per env: N, and per blink i (padded to max_blinks) its start step, on and off
        # lengths; padding entries have start -1 and lengths 0.
        self.target_blinks = torch.zeros(n, dtype=torch.int64, device=device)
        self.blink_start_steps = torch.full((n, k), -1, dtype=torch.int64, device=device)
        self.blink_on_schedule = torch.zeros(n, k, dtype=torch.int64, device=device)
        self.blink_off_schedule = torch.zeros(n, k, dtype=torch.int64, device=device)
        self.latch = PressLatch(n, device)
        self.press_count = torch.zeros(n, dtype=torch.int64, device=device)
        self.raw_press_count = torch.zeros(n, dtype=torch.int64, device=device)
        self.confirm_press_ready = torch.ones(n, dtype=torch.bool, device=device)
        self.submit_attempted = torch.zeros(n, dtype=torch.bool, device=device)
        self.submit_success = torch.zeros(n, dtype=torch.bool, device=device)
        self.failed = torch.zeros(n, dtype=torch.bool, device=device)
        # This frame's events and the frame (elapsed step) the state last advanced to.
        self._events = {
            name: torch.zeros(n, dtype=torch.bool, device=device)
            for name in ("raw_press", "press", "release", "confirm_press")
        }
        self._advanced_at = torch.full((n,), -1, dtype=torch.int64, device=device)
        self._all_envs = torch.arange(n, device=device)
        self._lit_bulb = self.blink_lamp.bulb_index("on")

    # -------------------------------------------------------------- episodes
    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Torch draws only, as the reference (its seed-0 reset reproduced; no numpy draw before
        # the arm noise): the red button's x, y for the reset envs, then the answer N; the blink
        # schedule follows in _sample_phase_lengths.
        b = len(env_idx)
        (x_lo, x_hi), (y_lo, y_hi) = self.BUTTON_X_RANGE, self.BUTTON_Y_RANGE
        xy = torch.rand(b, 2, device=self.device)
        lo, hi = self.BLINK_COUNT_RANGE
        self.target_blinks[env_idx] = torch.randint(lo, hi + 1, (b,), device=self.device)
        self.oracle_info = self.target_blinks.to(torch.uint8)
        xy[:, 0] = x_lo + (x_hi - x_lo) * xy[:, 0]
        xy[:, 1] = y_lo + (y_hi - y_lo) * xy[:, 1]
        self.button.place(env_idx, xy)
        confirm = xy.clone()
        limit = self.BUTTON_CONFIRM_Y_LIMIT
        confirm[:, 1] = (xy[:, 1] + self.BUTTON_CONFIRM_OFFSET_Y).clamp(-limit, limit)
        self.confirm_button.place(env_idx, confirm)
        zeros = torch.zeros(b, 1, device=self.device)
        self.blink_lamp.place(env_idx, torch.cat([self._lamp_xy(xy, self.BLINK_LAMP_OFFSET), zeros], dim=-1))
        self.phase_lamp.place(env_idx, torch.cat([self._lamp_xy(xy, self.PHASE_LAMP_OFFSET), zeros], dim=-1))

    @staticmethod
    def _lamp_xy(button_xy: torch.Tensor, offset: tuple[float, float]) -> torch.Tensor:
        return button_xy + torch.tensor(offset, device=button_xy.device)

    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        # The cue is the blink schedule (torch, as the reference): the pre-blink dark steps P
        # for all reset envs, then max_blinks "on" lengths per env (a draw from the one-value
        # range [3, 3], so always BLINK_ON_STEPS), then max_blinks dark times per env (entries
        # past N unused).
        b, k = len(env_idx), self.max_blinks
        p_lo, p_hi = self.PRE_BLINK_STEPS
        off_lo, off_hi = self.BLINK_OFF_STEPS
        pre = torch.randint(p_lo, p_hi + 1, (b,), device=self.device)
        torch.randint(self.BLINK_ON_STEPS, self.BLINK_ON_STEPS + 1, (b, k), device=self.device)
        off = torch.randint(off_lo, off_hi + 1, (b, k), device=self.device)
        used = torch.arange(k, device=self.device) < self.target_blinks[env_idx, None]
        on = torch.where(used, self.BLINK_ON_STEPS, 0)
        off = torch.where(used, off, 0)
        period = on + off
        starts = pre[:, None] + torch.cumsum(period, dim=1) - period
        self.blink_start_steps[env_idx] = torch.where(used, starts, -1)
        self.blink_on_schedule[env_idx] = on
        self.blink_off_schedule[env_idx] = off
        self.cue_steps_per_env[env_idx] = pre + period.sum(dim=1)
        self.empty_steps_per_env[env_idx] = 0

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self.latch.reset(env_idx)
        # New tensors, not in-place writes: the last info of an ending episode keeps its values.
        self.press_count = _with_rows(self.press_count, env_idx, 0)
        self.raw_press_count = _with_rows(self.raw_press_count, env_idx, 0)
        self.submit_attempted = _with_rows(self.submit_attempted, env_idx, False)
        self.submit_success = _with_rows(self.submit_success, env_idx, False)
        self.failed = _with_rows(self.failed, env_idx, False)
        self.confirm_press_ready = _with_rows(self.confirm_press_ready, env_idx, True)
        self._events = {name: _with_rows(event, env_idx, False) for name, event in self._events.items()}
        # The reset frame is state 0: nothing advances until the first step.
        self._advanced_at[env_idx] = 0
        t = self.elapsed_steps[env_idx]
        self.blink_lamp.show(env_idx, self._light_on(t, env_idx).long())
        self.phase_lamp.show(env_idx, (t >= self.cue_steps_per_env[env_idx]).long())

    # --------------------------------------------------------------- phases
    def _light_on(self, t: torch.Tensor, env_idx: torch.Tensor | None = None) -> torch.Tensor:
        """Per env, whether the blink lamp is lit at elapsed step ``t``."""
        rows = slice(None) if env_idx is None else env_idx
        starts, on = self.blink_start_steps[rows], self.blink_on_schedule[rows]
        lit = (starts >= 0) & (t[:, None] >= starts) & (t[:, None] < starts + on)
        return lit.any(dim=1)

    @property
    def action_mask(self) -> torch.Tensor:
        """Per env, whether the action phase has started (the phase lamp is green)."""
        return self.elapsed_steps >= self.action_phase_start

    @property
    def button_xy(self) -> torch.Tensor:
        """(B, 2) red button centre."""
        return self.button.xy

    @property
    def confirm_button_xy(self) -> torch.Tensor:
        """(B, 2) black button centre."""
        return self.confirm_button.xy

    @property
    def button_top_z(self) -> float:
        """Height of the unpressed red cap's top."""
        return self.BUTTON_TOP_Z

    @property
    def confirm_button_top_z(self) -> float:
        """Height of the unpressed black cap's top."""
        return self.BUTTON_TOP_Z

    # ------------------------------------------------------------- stepping
    def _terminated(self, info: dict) -> torch.Tensor:
        """An episode ends on success or failure."""
        return info["success"] | info["failed"]

    def _advance(self, tcp: torch.Tensor, depth: torch.Tensor, confirm_depth: torch.Tensor) -> None:
        """Advance the press / submit state of the envs whose frame moved on (spec §5).

        Counters and flags are replaced, not updated in place, so the info of earlier
        frames keeps its values without copies.
        """
        t = self.elapsed_steps
        fresh = self._advanced_at != t
        self._advanced_at = t.to(torch.int64, copy=True)
        phase = t >= self.action_phase_start
        # Counting: action phase, not failed (§5.2); PressLatch applies rules 1-3 in order.
        gate = fresh & phase & ~self.failed
        release = gate & ~self.latch.ready & (depth <= RELEASED_DEPTH)
        raw, counted = self.latch.update(depth, tcp[:, 2], gate, gate)
        self.raw_press_count = self.raw_press_count + raw
        self.press_count = self.press_count + counted
        failed = self.failed | (self.raw_press_count > self.target_blinks)
        # Submit (§5.3): re-armed by a released black cap, first submit only.
        active = fresh & phase
        ready = self.confirm_press_ready | (active & (confirm_depth <= RELEASED_DEPTH))
        submit = active & ready & ~self.submit_attempted & (confirm_depth >= PRESSED_DEPTH)
        self.confirm_press_ready = ready & ~submit
        self.submit_attempted = self.submit_attempted | submit
        right = self.press_count == self.target_blinks
        self.failed = failed | (submit & ~right)
        self.submit_success = self.submit_success | (submit & right & ~self.failed)
        for name, event in (("raw_press", raw), ("press", counted), ("release", release), ("confirm_press", submit)):
            self._events[name] = torch.where(fresh, event, self._events[name])
        # What the cameras show for this frame: lamps and (lowered) caps.
        self.blink_lamp.show(self._all_envs, self._light_on(t).long())
        self.phase_lamp.show(self._all_envs, phase.long())
        self.button.show_depth(depth)
        self.confirm_button.show_depth(confirm_depth)
        if self.gpu_sim_enabled:
            self.scene.px.gpu_apply_rigid_dynamic_data()

    def evaluate(self) -> dict:
        """Advance the press state for the current frame (once) and report it (spec §7)."""
        tcp_pose = self.agent.tcp.pose
        # Kept for this frame's observation and reward (both follow evaluate in a step).
        self._tcp_raw_pose = tcp_pose.raw_pose
        tcp = self._tcp_position = tcp_pose.p
        depth = self.button.press_depth(tcp, self.BUTTON_PRESS_RADIUS)
        confirm_depth = self.confirm_button.press_depth(tcp, self.BUTTON_PRESS_RADIUS)
        self._advance(tcp, depth, confirm_depth)
        phase = self.elapsed_steps >= self.action_phase_start
        lift_target_z = self.latch.confirm_z
        cap_centre = torch.cat([self.button.xy, (BUTTON_CAP_REST_Z - depth)[:, None]], dim=-1)
        return dict(
            success=phase & self.submit_success,
            failed=self.failed,
            submit_attempted=self.submit_attempted,
            submit_success=self.submit_success,
            action_mask=phase,
            phase_ready=phase,
            light_on=self.blink_lamp.shown == self._lit_bulb,
            press_count=self.press_count,
            raw_press_count=self.raw_press_count,
            target_blinks=self.target_blinks.clone(),
            new_raw_press_event=self._events["raw_press"],
            new_press_event=self._events["press"],
            new_release_event=self._events["release"],
            new_confirm_press_event=self._events["confirm_press"],
            # The latch updates these in place.
            press_ready=self.latch.ready.clone(),
            pending_press=self.latch.pending.clone(),
            lift_target_z=lift_target_z,
            at_lift_target=tcp[:, 2] >= lift_target_z,
            xy_dist_to_button=torch.linalg.norm(tcp[:, :2] - self.button.xy, dim=-1),
            press_depth=depth,
            xy_dist_to_confirm_button=torch.linalg.norm(tcp[:, :2] - self.confirm_button.xy, dim=-1),
            confirm_press_depth=confirm_depth,
            obj_to_goal_pos=cap_centre - tcp,
        )

    # ----------------------------------------------------------- observations
    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self._tcp_raw_pose)
        if self.obs_mode not in ("state", "state_dict"):
            return obs
        for name, button in (("button", self.button), ("confirm_button", self.confirm_button)):
            base_z = torch.full_like(button.depth, BUTTON_BASE_HALF_HEIGHT)[:, None]
            obs[f"{name}_base_pose"] = torch.cat([button.xy, base_z, button.quat], dim=-1)
            cap_z = (BUTTON_CAP_REST_Z - button.depth)[:, None]
            obs[f"{name}_cap_pose"] = torch.cat([button.xy, cap_z, button.quat], dim=-1)
        # The shown bulb of each lamp stands at the lamp's position.
        obs["indicator_pose"] = positions_to_poses(self.blink_lamp.position)
        obs["phase_indicator_pose"] = positions_to_poses(self.phase_lamp.position)
        obs["press_count"] = self.press_count
        obs["target_blinks"] = self.target_blinks
        obs["action_mask"] = info["action_mask"]
        obs["phase_ready"] = info["phase_ready"]
        obs["press_ready"] = self.latch.ready
        obs["pending_press"] = self.latch.pending
        obs["submit_attempted"] = self.submit_attempted
        obs["submit_success"] = self.submit_success
        obs["at_lift_target"] = info["at_lift_target"]
        obs["oracle_info"] = self.oracle_info
        return obs

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """The staged press / lift / submit reward of spec §6; -25 on failure, 30 on success.

        The spec's reward is multiplied by the phase flag, so its cue-phase terms never pay,
        and its raw- and counted-press bonuses read the pending flag after the update, so they
        never pay either (spec quirk 2). Both are left out here; the values are identical.
        """
        tcp = self._tcp_position
        phase = info["action_mask"].float()
        pending = info["pending_press"].float()
        a1, a2 = phase * (1.0 - pending), phase * pending
        confirm_cap = torch.cat(
            [self.confirm_button.xy, (BUTTON_CAP_REST_Z - info["confirm_press_depth"])[:, None]], dim=-1
        )
        reach = 1 - torch.tanh(8 * torch.linalg.norm(info["obj_to_goal_pos"], dim=-1))
        confirm_reach = 1 - torch.tanh(8 * torch.linalg.norm(confirm_cap - tcp, dim=-1))
        progress = info["press_depth"] / MAX_PRESS_DEPTH
        confirm_progress = info["confirm_press_depth"] / MAX_PRESS_DEPTH
        n = self.target_blinks.float()
        count_progress = 1 - ((n - self.press_count).abs() / n.clamp(min=1)).clamp(max=1)
        lift = 1 - torch.tanh(4 * (self.latch.press_start_z + self.REQUIRED_LIFT_HEIGHT - tcp[:, 2]).clamp(min=0))
        vertical = 1 - torch.tanh(8 * info["xy_dist_to_button"])
        above_top = (tcp[:, 2] - self.BUTTON_TOP_Z).clamp(min=0)
        lift_penalty = ((above_top - 0.20) / 0.1).clamp(0, 1)
        hover_penalty = ((above_top - 0.06) / 0.1).clamp(0, 1)
        count_right = (self.press_count == self.target_blinks).float()
        action_l2, delta_l2 = self._action_smoothness_terms(action)
        qvel_l2 = torch.linalg.norm(self.arm_qvel, dim=-1)
        smooth = 0.01 * torch.tanh(2 * action_l2) + 0.03 * torch.tanh(5 * delta_l2) + 0.01 * torch.tanh(2 * qvel_l2)
        pressing = 1.5 * reach + 2 * progress + count_progress - 1.5 * lift_penalty - 3 * hover_penalty
        lifting = 5 * lift + 2 * vertical + 2 * info["new_release_event"].float() - 2 * progress
        submitting = count_right * (1.5 * confirm_reach + 2 * confirm_progress)
        reward = (
            0.25 * reach + a1 * pressing + a2 * lifting + submitting
            + 10 * info["new_confirm_press_event"].float() - smooth
        )
        reward = reward * phase - self.FAIL_PENALTY * info["failed"].float()
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = {
            "reach_reward": reach,
            "confirm_reach_reward": confirm_reach,
            "press_progress": progress,
            "confirm_press_progress": confirm_progress,
            "count_progress": count_progress,
            "lift_reward": lift,
            "vertical_reward": vertical,
            "lift_penalty": a1 * lift_penalty,
            "hover_penalty": a1 * hover_penalty,
            "action_l2": action_l2,
            "delta_action_l2": delta_l2,
            "qvel_l2": qvel_l2,
            "smooth_penalty": smooth,
            "failed": info["failed"],
            "success": info["success"],
        }
        return reward


@register_task(FAMILY, "BlinkCountButtonPressEasy-VLA-v0", number=48, split="short",
               data_source="MP", memory_type="Temporal", max_episode_steps=150)
class BlinkCountButtonPressEasyVLAEnv(BlinkCountButtonPressVLABaseEnv):
    """1-3 blinks after 5-10 dark steps."""

    BLINK_COUNT_RANGE = (1, 3)
    PRE_BLINK_STEPS = (5, 10)


@register_task(FAMILY, "BlinkCountButtonPressMedium-VLA-v0", number=49, split="short",
               data_source="MP", memory_type="Temporal", max_episode_steps=200)
class BlinkCountButtonPressMediumVLAEnv(BlinkCountButtonPressVLABaseEnv):
    """1-5 blinks after 5-10 dark steps."""

    BLINK_COUNT_RANGE = (1, 5)
    PRE_BLINK_STEPS = (5, 10)


@register_task(FAMILY, "BlinkCountButtonPressHard-VLA-v0", number=50, split="medium",
               data_source="MP", memory_type="Temporal", max_episode_steps=300)
class BlinkCountButtonPressHardVLAEnv(BlinkCountButtonPressVLABaseEnv):
    """1-7 blinks after 5-10 dark steps."""

    BLINK_COUNT_RANGE = (1, 7)
    PRE_BLINK_STEPS = (5, 10)


@register_task(FAMILY, "BlinkCountButtonPressEasy-Long-VLA-v0", number=71, split="long",
               data_source="MP", memory_type="Temporal", max_episode_steps=1200)
class BlinkCountButtonPressEasyLongVLAEnv(BlinkCountButtonPressVLABaseEnv):
    """1-10 blinks after 5-50 dark steps."""

    BLINK_COUNT_RANGE = (1, 10)
    PRE_BLINK_STEPS = (5, 50)


@register_task(FAMILY, "BlinkCountButtonPressMedium-Long-VLA-v0", number=72, split="long",
               data_source="MP", memory_type="Temporal", max_episode_steps=1200)
class BlinkCountButtonPressMediumLongVLAEnv(BlinkCountButtonPressVLABaseEnv):
    """10-20 blinks after 5-50 dark steps."""

    BLINK_COUNT_RANGE = (10, 20)
    PRE_BLINK_STEPS = (5, 50)


@register_task(FAMILY, "BlinkCountButtonPressHard-Long-VLA-v0", number=73, split="long",
               data_source="MP", memory_type="Temporal", max_episode_steps=1200)
class BlinkCountButtonPressHardLongVLAEnv(BlinkCountButtonPressVLABaseEnv):
    """20-30 blinks after 5-50 dark steps."""

    BLINK_COUNT_RANGE = (20, 30)
    PRE_BLINK_STEPS = (5, 50)
