"""TimedTransfer: move a cube from the green disc to the red disc exactly D steps after a lamp turns green.

This module also holds ``LampTaskVLABaseEnv``, the small base GatherAndRecall shares: tasks
without cue / delay phases whose only changing cue is a colour-switch lamp, that end on
success or on a latched failure, and whose dense reward carries the same smoothness penalty.
"""

from __future__ import annotations

from typing import Any, ClassVar

import torch
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.building_blocks.cubes import CUBE_HALF_SIZE, build_colored_cube, rgba01
from mikasa_envs.building_blocks.discs import build_disc
from mikasa_envs.building_blocks.lamps import ColorSwitchLamp
from mikasa_envs.building_blocks.poses import positions_to_poses, write_actor_poses
from mikasa_envs.family import Chance, TaskFamily, TaskSpec
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._lamp_task import LampTaskVLABaseEnv, uniform


def timed_transfer_window(env_class: type) -> tuple[float, int, int]:
    """(chance, window width, steps up to the window's end) of a variant: the best a policy
    without a clock gets by descending with a constant probability per step."""
    delay = env_class.DELAY_STEPS
    lo = int((1 - env_class.WINDOW_TOLERANCE) * delay)
    hi = int((1 + env_class.WINDOW_TOLERANCE) * delay)
    signal = sum(env_class.SIGNAL_STEP_RANGE) / 2
    width = hi - lo + 1
    end = signal + hi + 1
    return width / end, width, int(end)


def timed_transfer_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule: the window's share of the steps up to its end."""
    rate, width, end = timed_transfer_window(env_class)
    return Chance(
        rate,
        f"{width}/{end}: no discrete answer (a time); the window's share of the steps up to "
        f"its end bounds a clockless policy that descends with a constant probability per step",
    )


FAMILY = TaskFamily(
    "timed_transfer",
    hidden="the steps since the lamp turned green: nothing in view counts them",
    overlays="timed_transfer",
    wrapper_table_rank=(33, 34),
    chance=timed_transfer_chance,
)



class TimedTransferVLABaseEnv(LampTaskVLABaseEnv):
    """**Task Description:** a blue cube stands on a green disc next to a red disc; a lamp
    shows a white bulb, then turns green 1-3 steps into the episode and stays green. Move
    the cube onto the red disc exactly ``DELAY_STEPS`` steps after the lamp turned green
    (the instruction names the number). Everything stays visible; the memory demand is
    counting the steps.

    **Randomizations:** the centre of the disc pair (x ~ U[−0.15, −0.05), y ~ U[−0.05,
    0.05)); the signal step S ~ U{1, 2, 3}; arm joint noise.

    **Success Conditions:** on a step e with S + ⌊0.95·D⌋ ≤ e ≤ S + ⌊1.05·D⌋ the cube's
    centre is within 5 cm (XY) of the red disc's centre and below z = 0.066 (held or
    released). Placing it there earlier fails the episode; so does reaching the end of the
    window without success. The episode terminates on success or failure.
    """

    LANGUAGE_INSTRUCTION_TEMPLATE: ClassVar[str] = (
        "When the white lamp turns green, start counting steps from that exact moment. "
        "Move the blue cube from the green disc to the red disc exactly on step {D} of that count."
    )
    DELAY_STEPS: ClassVar[int] = 100
    # The window is [S + ⌊(1 − tol)·D⌋, S + ⌊(1 + tol)·D⌋] (int() truncation, as upstream).
    WINDOW_TOLERANCE: ClassVar[float] = 0.05
    SIGNAL_STEP_RANGE: ClassVar[tuple[int, int]] = (1, 3)  # inclusive
    PAIR_CENTER_X_RANGE: ClassVar[tuple[float, float]] = (-0.15, -0.05)
    PAIR_CENTER_Y_RANGE: ClassVar[tuple[float, float]] = (-0.05, 0.05)
    DISC_RADIUS: ClassVar[float] = 0.07
    DISC_HALF_HEIGHT: ClassVar[float] = 0.003
    # The green disc is at pair centre − this along y, the red one at + this.
    DISC_OFFSET_Y: ClassVar[float] = 0.11
    CUBE_HALF_SIZE: ClassVar[float] = CUBE_HALF_SIZE
    LAMP_OFFSET_X: ClassVar[float] = 0.22
    GREEN_DISC_RGBA: ClassVar[tuple[int, ...]] = (30, 180, 30, 255)
    RED_DISC_RGBA: ClassVar[tuple[int, ...]] = (200, 30, 30, 255)
    CUBE_RGBA: ClassVar[tuple[int, ...]] = (30, 30, 220, 255)
    # Lamp bulbs: name -> (RGB, emission scale); the "white" off bulb is light grey.
    LAMP_BULBS: ClassVar[dict[str, tuple[tuple[int, int, int], float]]] = {
        "off": ((220, 220, 220), 0.0),
        "green": ((0, 255, 0), 3.0),
    }
    # "On red": cube centre within this XY distance of the red disc centre and below the
    # disc top + ON_RED_MAX_HEIGHT.
    ON_RED_RADIUS: ClassVar[float] = 0.05
    ON_RED_MAX_HEIGHT: ClassVar[float] = 0.06
    # The fingers (reaching < 7 cm from the TCP) cannot touch a cube whose centre is farther
    # than this: the contact-force grasp test is skipped then.
    GRASP_REACH: ClassVar[float] = 0.15
    DENSE_REWARD_MAX = 30.0

    green_disc: Actor
    red_disc: Actor
    blue_cube: Actor
    lamp: ColorSwitchLamp

    TASK_STATE = (
        "signal_step",
        "window_start",
        "window_end",
        "green_disc_center",
        "red_disc_center",
        "too_early",
        "success_latch",
        "failed",
        "lamp",
    )

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # One instruction per variant: the template with this variant's delay (the manifest's).
        super().__init_subclass__(**kwargs)
        cls.LANGUAGE_INSTRUCTION = cls.LANGUAGE_INSTRUCTION_TEMPLATE.format(D=cls.DELAY_STEPS)

    @property
    def disc_top_z(self) -> float:
        """Height of both discs' top faces."""
        return 2 * self.DISC_HALF_HEIGHT

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        radius, half = self.DISC_RADIUS, self.DISC_HALF_HEIGHT
        self.green_disc = build_disc(self.scene, "green_disc", radius, half, self.GREEN_DISC_RGBA)
        self.red_disc = build_disc(self.scene, "red_disc", radius, half, self.RED_DISC_RGBA)
        self.blue_cube = build_colored_cube(self.scene, rgba01(self.CUBE_RGBA), "blue_cube", self.CUBE_HALF_SIZE)
        self.lamp = ColorSwitchLamp(self.scene, "signal_lamp", self.LAMP_BULBS, self.num_envs, self.device)
        n, dev = self.num_envs, self.device
        self.signal_step = torch.zeros(n, dtype=torch.int64, device=dev)
        self.window_start = torch.zeros(n, dtype=torch.int64, device=dev)
        self.window_end = torch.zeros(n, dtype=torch.int64, device=dev)
        self.green_disc_center = torch.zeros(n, 3, device=dev)
        self.red_disc_center = torch.zeros(n, 3, device=dev)
        self.too_early = torch.zeros(n, dtype=torch.bool, device=dev)
        self.success_latch = torch.zeros(n, dtype=torch.bool, device=dev)
        self.failed = torch.zeros(n, dtype=torch.bool, device=dev)
        self.oracle_info = torch.full((n,), float(self.DELAY_STEPS), dtype=torch.float32, device=dev)

    # ------------------------------------------------------------- episodes
    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Torch draws, in this order: pair centre x, pair centre y, signal step.
        b, dev = len(env_idx), self.device
        cx = uniform(b, *self.PAIR_CENTER_X_RANGE, dev)
        cy = uniform(b, *self.PAIR_CENTER_Y_RANGE, dev)
        lo, hi = self.SIGNAL_STEP_RANGE
        signal = torch.randint(lo, hi + 1, (b,), device=dev)
        self.signal_step[env_idx] = signal
        self.window_start[env_idx] = signal + int((1 - self.WINDOW_TOLERANCE) * self.DELAY_STEPS)
        self.window_end[env_idx] = signal + int((1 + self.WINDOW_TOLERANCE) * self.DELAY_STEPS)

        disc_z = torch.full((b,), self.DISC_HALF_HEIGHT, device=dev)
        green = torch.stack([cx, cy - self.DISC_OFFSET_Y, disc_z], dim=-1)
        red = torch.stack([cx, cy + self.DISC_OFFSET_Y, disc_z], dim=-1)
        self.green_disc_center[env_idx] = green
        self.red_disc_center[env_idx] = red
        write_actor_poses(self.scene, [self.green_disc, self.red_disc], env_idx, positions_to_poses(torch.stack([green, red], 1)))

        cube = green.clone()
        cube[:, 2] = self.disc_top_z + self.CUBE_HALF_SIZE
        self.blue_cube.set_pose(Pose.create(positions_to_poses(cube)))
        zeros = torch.zeros(b, 3, device=dev)
        self.blue_cube.set_linear_velocity(zeros)
        self.blue_cube.set_angular_velocity(zeros)

        lamp = torch.stack([cx + self.LAMP_OFFSET_X, cy, torch.zeros_like(cx)], dim=-1)
        self.lamp.place(env_idx, lamp, bulb=self.lamp.bulb_index("off"))

    def _visual_state(self) -> list[torch.Tensor]:
        return [self.lamp.shown]

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self.too_early[env_idx] = False
        self.success_latch[env_idx] = False
        self.failed[env_idx] = False

    # --------------------------------------------------------------- queries
    def cube_position(self) -> torch.Tensor:
        """(B, 3) the cube's centre."""
        return self.actor_positions([self.blue_cube])[:, 0]

    def evaluate(self) -> dict:
        """Signal and window flags, cube-on-red, the latches; shows the lamp of this frame.

        Idempotent for a given state (the latches only accumulate), so calling it again on
        the same step changes nothing.
        """
        e = self.elapsed_steps
        cube = self.cube_position()
        tcp = self.agent.tcp.pose.p
        obj_to_goal_pos = self.red_disc_center - cube
        red_xy_distance = torch.linalg.norm(obj_to_goal_pos[:, :2], dim=-1)
        cube_on_red = (red_xy_distance < self.ON_RED_RADIUS) & (cube[:, 2] < self.disc_top_z + self.ON_RED_MAX_HEIGHT)
        signal_on = e >= self.signal_step
        in_window = (e >= self.window_start) & (e <= self.window_end)
        before_window = signal_on & (e < self.window_start)
        past_window = e > self.window_end
        self.too_early |= cube_on_red & before_window
        self.success_latch |= cube_on_red & in_window & ~self.too_early
        self.failed |= self.too_early | (past_window & ~self.success_latch)

        green = signal_on.long() * self.lamp.bulb_index("green")
        self.update_visuals(lambda: self.lamp.show(torch.arange(self.num_envs, device=self.device), green))
        return dict(
            success=self.success_latch.clone(),
            failed=self.failed.clone(),
            too_early=self.too_early.clone(),
            signal_on=signal_on,
            in_window=in_window,
            before_window=before_window,
            past_window=past_window,
            cube_on_red=cube_on_red,
            cube_to_red_dist=torch.linalg.norm(obj_to_goal_pos, dim=-1),
            is_grasped=self._is_grasped(cube, tcp),
            obj_to_goal_pos=obj_to_goal_pos,
        )

    def _is_grasped(self, cube: torch.Tensor, tcp: torch.Tensor) -> torch.Tensor:
        """(B,) ManiSkill's contact-force grasp test of the cube, skipped where it is out of reach."""
        near = torch.linalg.norm(cube - tcp, dim=-1) < self.GRASP_REACH
        if not bool(near.any()):
            return near
        return self.agent.is_grasping(self.blue_cube) & near

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            poses = self.actor_raw_poses([self.green_disc, self.red_disc, self.blue_cube])
            obs["green_disc_pose"], obs["red_disc_pose"], obs["cube_pose"] = poses.unbind(1)
            obs["signal_on"] = info["signal_on"].float()
            obs["in_window"] = info["in_window"].float()
            obs["is_grasped"] = info["is_grasped"].float()
            obs["oracle_info"] = self.oracle_info
        return obs

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reach, grasp, place in the window, on-red and stillness in the window, minus
        an early placement and smoothness; only after the signal. 30 on success, −25 on failure."""
        tcp = self.agent.tcp.pose.p
        cube = self.cube_position()
        sig = info["signal_on"].float()
        inw = info["in_window"].float()
        on = info["cube_on_red"].float()
        early = info["before_window"].float()
        grasp = info["is_grasped"].float()
        reach = 1 - torch.tanh(10 * torch.linalg.norm(cube - tcp, dim=-1))
        place = 1 - torch.tanh(5 * info["cube_to_red_dist"])
        static = 1 - torch.tanh(5 * torch.linalg.norm(self.arm_qvel, dim=-1))
        penalty, terms = self.smoothness_penalty(action)
        reward = sig * (
            2 * reach * sig
            + 3 * grasp * sig
            + 20 * place * grasp * inw
            + 5 * on * inw
            + 3 * static * on * inw
            - 5 * on * early
            - penalty
        )
        terms = dict(reaching_reward=reach, place_reward=place, is_grasped=info["is_grasped"], static_reward=static, **terms)
        return self.finish_reward(reward, info, terms)


@register_task(FAMILY, "TimedTransferEasy-VLA-v0", number=80, split="short", data_source="MP",
               memory_type="Temporal", max_episode_steps=200)
class TimedTransferEasyVLAEnv(TimedTransferVLABaseEnv):
    """TimedTransfer with a 100-step delay (window [95, 105] after the signal)."""

    DELAY_STEPS = 100


@register_task(FAMILY, "TimedTransferMedium-VLA-v0", number=81, split="medium", data_source="MP",
               memory_type="Temporal", max_episode_steps=250)
class TimedTransferMediumVLAEnv(TimedTransferVLABaseEnv):
    """TimedTransfer with a 150-step delay (window [142, 157] after the signal)."""

    DELAY_STEPS = 150


@register_task(FAMILY, "TimedTransferHard-VLA-v0", number=82, split="medium", data_source="MP",
               memory_type="Temporal", max_episode_steps=300)
class TimedTransferHardVLAEnv(TimedTransferVLABaseEnv):
    """TimedTransfer with a 200-step delay (window [190, 210] after the signal)."""

    DELAY_STEPS = 200


@register_task(FAMILY, "TimedTransferEasy-Long-VLA-v0", number=83, split="medium", data_source="MP",
               memory_type="Temporal", max_episode_steps=600)
class TimedTransferEasyLongVLAEnv(TimedTransferVLABaseEnv):
    """TimedTransfer with a 300-step delay (window [285, 315] after the signal)."""

    DELAY_STEPS = 300


@register_task(FAMILY, "TimedTransferMedium-Long-VLA-v0", number=84, split="long", data_source="MP",
               memory_type="Temporal", max_episode_steps=900)
class TimedTransferMediumLongVLAEnv(TimedTransferVLABaseEnv):
    """TimedTransfer with a 500-step delay (window [475, 525] after the signal)."""

    DELAY_STEPS = 500


@register_task(FAMILY, "TimedTransferHard-Long-VLA-v0", number=85, split="long", data_source="MP",
               memory_type="Temporal", max_episode_steps=1200)
class TimedTransferHardLongVLAEnv(TimedTransferVLABaseEnv):
    """TimedTransfer with a 1000-step delay (window [950, 1050] after the signal)."""

    DELAY_STEPS = 1000
