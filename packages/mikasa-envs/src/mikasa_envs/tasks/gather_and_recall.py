"""GatherAndRecall: gather every cube onto a disc, then press the button of the colour a lamp flashed meanwhile."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.building_blocks.buttons import BUTTON_TOP_Z, MAX_PRESS_DEPTH, PRESSED_DEPTH, Button
from mikasa_envs.building_blocks.cubes import CUBE_HALF_SIZE, build_colored_cube, rgba01
from mikasa_envs.building_blocks.discs import build_disc
from mikasa_envs.building_blocks.lamps import ColorSwitchLamp
from mikasa_envs.building_blocks.poses import positions_to_poses, write_actor_poses
from mikasa_envs.family import Chance, TaskFamily, TaskSpec
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._lamp_task import LampTaskVLABaseEnv, uniform


def gather_and_recall_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule: a uniform guess among the three buttons."""
    return Chance(1 / 3, "1/3: the flash colour is one of 3 buttons")


FAMILY = TaskFamily(
    "gather_and_recall",
    hidden=(
        "the flash colour: the lamp flashes once, for 8-14 steps, while the robot gathers the "
        "cubes"
    ),
    overlays="step_reward",
    wrapper_table_rank=(35, 35),
    chance=gather_and_recall_chance,
)


# Colour index -> (name, RGB): cubes cycle through them, buttons and flash use them.
RGB_COLORS: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("red", (255, 0, 0)),
    ("green", (0, 255, 0)),
    ("blue", (0, 0, 255)),
)


def cluster_offsets(n: int, spacing: float) -> np.ndarray:
    """(n, 2) cube offsets of the start cluster: rows of up to 3 along x, rows stacked along y,
    both centred (``gather_and_recall.md`` §3.1)."""
    rows = -(-n // 3)
    offsets = np.zeros((n, 2))
    for i in range(n):
        row, col = divmod(i, 3)
        in_row = min(3, n - 3 * row)
        offsets[i] = ((col - (in_row - 1) / 2) * spacing, (row - (rows - 1) / 2) * spacing)
    return offsets


class GatherAndRecallVLABaseEnv(LampTaskVLABaseEnv):
    """**Task Description:** N cubes (coloured red, green, blue in turn) stand in a cluster
    on the near-right of the table; move all of them onto the grey disc. While the robot
    works, a lamp behind the disc flashes red, green or blue once for 8-14 steps (when the
    K-th distinct cube first reaches the disc). Once every cube is on the disc, press the
    button (red / green / blue, in a row beside the disc) of the flash colour.

    **Randomizations:** the disc centre (x ~ U[0, 0.08), y ~ U[0.10, 0.18)), which carries
    the cluster, the buttons and the lamp with it; ±5 mm jitter of every cube; the trigger
    count K ~ U{1, …, max(2, N) − 1}; the flash length F ~ U{8, …, 14}; the flash colour;
    arm joint noise.

    **Success Conditions:** every cube is on the disc (centre within 0.10 m of the disc
    centre in XY, below z = 0.5, slower than 0.15 m/s) and the first button pressed while
    they all were is the flash colour's. Pressing another button then fails the episode.
    The episode terminates on success or failure.
    """

    LANGUAGE_INSTRUCTION = (
        "Move all cubes onto the disc. A lamp will briefly flash while you work. "
        "After all cubes are placed, press the button matching the flash color."
    )
    N_CUBES: ClassVar[int] = 1
    DISC_X_RANGE: ClassVar[tuple[float, float]] = (0.0, 0.08)
    DISC_Y_RANGE: ClassVar[tuple[float, float]] = (0.10, 0.18)
    DISC_RADIUS: ClassVar[float] = 0.12
    DISC_HALF_HEIGHT: ClassVar[float] = 0.003
    DISC_RGBA: ClassVar[tuple[int, ...]] = (160, 160, 170, 255)
    CUBE_HALF_SIZE: ClassVar[float] = CUBE_HALF_SIZE
    # Start cluster: centred at (disc x + CLUSTER_OFFSET_X, CLUSTER_Y), cubes CLUSTER_SPACING
    # apart, each x and y jittered by U[−CLUSTER_JITTER, CLUSTER_JITTER].
    CLUSTER_OFFSET_X: ClassVar[float] = -0.08
    CLUSTER_Y: ClassVar[float] = -0.26
    CLUSTER_SPACING: ClassVar[float] = 0.09
    CLUSTER_JITTER: ClassVar[float] = 0.005
    # Buttons red / green / blue at (disc x + BUTTON_OFFSET_X, disc y + (i − 1)·BUTTON_SPACING_Y).
    BUTTON_OFFSET_X: ClassVar[float] = -0.22
    BUTTON_SPACING_Y: ClassVar[float] = 0.14
    BUTTON_BASE_HALF_SIZE: ClassVar[tuple[float, float, float]] = (0.04, 0.04, 0.015)
    BUTTON_CAP_RADIUS: ClassVar[float] = 0.025
    BUTTON_BASE_RGBA: ClassVar[tuple[int, ...]] = (55, 64, 78, 255)
    BUTTON_PRESS_RADIUS: ClassVar[float] = 0.04
    BUTTON_CAP_TRAVEL: ClassVar[float] = MAX_PRESS_DEPTH
    LAMP_OFFSET: ClassVar[tuple[float, float]] = (0.24, 0.06)
    LAMP_OFF_RGB: ClassVar[tuple[int, int, int]] = (245, 245, 245)
    LAMP_EMISSION: ClassVar[float] = 20.0
    FLASH_STEPS: ClassVar[tuple[int, int]] = (8, 14)  # inclusive
    # "On disc": XY distance to the disc centre, height and speed limits of a cube centre.
    ON_DISC_RADIUS: ClassVar[float] = 0.10
    ON_DISC_MAX_Z: ClassVar[float] = 0.5
    ON_DISC_MAX_SPEED: ClassVar[float] = 0.15
    # Reward goal: "holding" a cube within this of the TCP; goal heights over disc / button.
    HOLDING_RADIUS: ClassVar[float] = 0.05
    DISC_GOAL_Z: ClassVar[float] = 0.026
    BUTTON_GOAL_Z: ClassVar[float] = 0.063
    DENSE_REWARD_MAX = 50.0

    cubes: list[Actor]
    disc: Actor
    buttons: list[Button]
    lamp: ColorSwitchLamp
    TASK_STATE = (
        "disc_xy", "flash_trigger_count", "flash_duration", "flash_color", "cubes_on_disc", "flash_triggered",
        "flash_start", "pressed_button", "success_latch", "failed", "buttons", "lamp",
    )

    GPU_MEMORY: ClassVar[dict[str, int]] = {
        "found_lost_pairs_capacity": 2**25,
        "max_rigid_contact_count": 2**21,
        "max_rigid_patch_count": 2**18,
    }

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        n, dev = self.num_envs, self.device
        self.disc = build_disc(self.scene, "target_disc", self.DISC_RADIUS, self.DISC_HALF_HEIGHT, self.DISC_RGBA)
        self.cubes = [
            build_colored_cube(self.scene, rgba01((*RGB_COLORS[i % 3][1], 255)), f"gather_cube_{i}", self.CUBE_HALF_SIZE)
            for i in range(self.N_CUBES)
        ]
        self.buttons = [
            Button(
                self.scene, f"{name}_button", self.BUTTON_BASE_HALF_SIZE, self.BUTTON_CAP_RADIUS,
                self.BUTTON_BASE_RGBA, (*rgb, 255), n, dev,
            )
            for name, rgb in RGB_COLORS
        ]
        bulbs = {"off": (self.LAMP_OFF_RGB, 0.0)} | {name: (rgb, self.LAMP_EMISSION) for name, rgb in RGB_COLORS}
        self.lamp = ColorSwitchLamp(self.scene, "signal_lamp", bulbs, n, dev)
        self.button_top_z = BUTTON_TOP_Z
        self.disc_xy = torch.zeros(n, 2, device=dev)
        self.flash_trigger_count = torch.ones(n, dtype=torch.int64, device=dev)
        self.flash_duration = torch.full((n,), self.FLASH_STEPS[0], dtype=torch.int64, device=dev)
        self.flash_color = torch.zeros(n, dtype=torch.int64, device=dev)
        self.cubes_on_disc = torch.zeros(n, self.N_CUBES, dtype=torch.bool, device=dev)
        self.flash_triggered = torch.zeros(n, dtype=torch.bool, device=dev)
        self.flash_start = torch.zeros(n, dtype=torch.int64, device=dev)
        self.pressed_button = torch.full((n,), -1, dtype=torch.int64, device=dev)
        self.success_latch = torch.zeros(n, dtype=torch.bool, device=dev)
        self.failed = torch.zeros(n, dtype=torch.bool, device=dev)
        self.oracle_info = torch.zeros(n, dtype=torch.uint8, device=dev)
        self._cluster_offsets = torch.as_tensor(
            cluster_offsets(self.N_CUBES, self.CLUSTER_SPACING), dtype=torch.float32, device=dev
        )

    @property
    def disc_top_z(self) -> float:
        """Height of the disc's top face."""
        return 2 * self.DISC_HALF_HEIGHT

    @property
    def buttons_xy(self) -> torch.Tensor:
        """(3, B, 2) XY of the red, green and blue buttons."""
        return torch.stack([button.xy for button in self.buttons])

    # ------------------------------------------------------------- episodes
    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Torch draws, in this order: trigger count K, flash length F, flash colour, disc x,
        # disc y, cube jitter (b, N, 2). The reference's seed-0 resets put the disc and the
        # jitter after three draws; the order of K, F and the colour among them is not visible
        # at reset (the spec's order).
        b, n, dev = len(env_idx), self.N_CUBES, self.device
        self.flash_trigger_count[env_idx] = torch.randint(1, max(2, n), (b,), device=dev)
        self.flash_duration[env_idx] = torch.randint(self.FLASH_STEPS[0], self.FLASH_STEPS[1] + 1, (b,), device=dev)
        self.flash_color[env_idx] = torch.randint(0, len(RGB_COLORS), (b,), device=dev)
        self.oracle_info[env_idx] = self.flash_color[env_idx].to(torch.uint8)
        dx = uniform(b, *self.DISC_X_RANGE, dev)
        dy = uniform(b, *self.DISC_Y_RANGE, dev)
        jitter = (torch.rand(b, n, 2, device=dev) * 2 - 1) * self.CLUSTER_JITTER

        disc_xy = torch.stack([dx, dy], dim=-1)
        self.disc_xy[env_idx] = disc_xy
        disc = torch.cat([disc_xy, torch.full((b, 1), self.DISC_HALF_HEIGHT, device=dev)], dim=-1)
        write_actor_poses(self.scene, [self.disc], env_idx, positions_to_poses(disc)[:, None])

        cluster_centre = torch.stack([dx + self.CLUSTER_OFFSET_X, torch.full_like(dy, self.CLUSTER_Y)], dim=-1)
        cube_xy = cluster_centre[:, None] + self._cluster_offsets + jitter
        cube_z = torch.full((b, n, 1), self.CUBE_HALF_SIZE, device=dev)
        cube_poses = positions_to_poses(torch.cat([cube_xy, cube_z], dim=-1))
        zeros = torch.zeros(b, 3, device=dev)
        for k, cube in enumerate(self.cubes):
            cube.set_pose(Pose.create(cube_poses[:, k]))
            cube.set_linear_velocity(zeros)
            cube.set_angular_velocity(zeros)

        for i, button in enumerate(self.buttons):
            offset = torch.tensor([self.BUTTON_OFFSET_X, (i - 1) * self.BUTTON_SPACING_Y], device=dev)
            button.place(env_idx, disc_xy + offset)
        lamp = torch.cat([disc_xy + torch.tensor(self.LAMP_OFFSET, device=dev), torch.zeros(b, 1, device=dev)], dim=-1)
        self.lamp.place(env_idx, lamp, bulb=self.lamp.bulb_index("off"))

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self.cubes_on_disc[env_idx] = False
        self.flash_triggered[env_idx] = False
        self.flash_start[env_idx] = 0
        self.pressed_button[env_idx] = -1
        self.success_latch[env_idx] = False
        self.failed[env_idx] = False

    def _visual_state(self) -> list[torch.Tensor]:
        return [self.lamp.shown, *(button.depth for button in self.buttons)]

    # --------------------------------------------------------------- queries
    def cube_positions(self) -> torch.Tensor:
        """(B, N, 3) current cube centres."""
        return self.actor_positions(self.cubes)

    def cube_speeds(self) -> torch.Tensor:
        """(B, N) current linear speeds of the cubes."""
        if not self.gpu_sim_enabled:
            speeds = [np.linalg.norm(cube._bodies[0].linear_velocity) for cube in self.cubes]
            return torch.tensor(speeds, dtype=torch.float32, device=self.device)[None]
        return torch.stack([torch.linalg.norm(cube.linear_velocity, dim=-1) for cube in self.cubes], dim=1)

    def cubes_on_disc_now(self, positions: torch.Tensor) -> torch.Tensor:
        """(B, N) the current "on disc" test of each cube (its centre positions (B, N, 3))."""
        xy_distance = torch.linalg.norm(positions[..., :2] - self.disc_xy[:, None], dim=-1)
        return (
            (xy_distance < self.ON_DISC_RADIUS)
            & (positions[..., 2] < self.ON_DISC_MAX_Z)
            & (self.cube_speeds() < self.ON_DISC_MAX_SPEED)
        )

    def evaluate(self) -> dict:
        """Cubes on the disc, the flash, the recorded button press and the latches; shows this
        frame's lamp bulb and button caps.

        Idempotent for a given state (the latches only accumulate), so calling it again on
        the same step changes nothing.
        """
        e = self.elapsed_steps
        tcp = self.agent.tcp.pose.p
        positions = self.cube_positions()
        on_disc_now = self.cubes_on_disc_now(positions)
        self.cubes_on_disc |= on_disc_now
        n_on_disc = self.cubes_on_disc.sum(dim=-1)
        all_on_disc = on_disc_now.all(dim=-1)

        trigger = ~self.flash_triggered & (n_on_disc >= self.flash_trigger_count)
        self.flash_start = torch.where(trigger, e, self.flash_start)
        self.flash_triggered |= trigger
        flash_active = self.flash_triggered & (e >= self.flash_start) & (e < self.flash_start + self.flash_duration)

        depths = torch.stack([button.press_depth(tcp, self.BUTTON_PRESS_RADIUS) for button in self.buttons])
        pressed = depths >= PRESSED_DEPTH  # (3, B)
        record = all_on_disc & (self.pressed_button < 0) & pressed.any(dim=0)
        self.pressed_button = torch.where(record, pressed.long().argmax(dim=0), self.pressed_button)
        recorded = self.pressed_button >= 0
        self.failed |= recorded & (self.pressed_button != self.flash_color)
        self.success_latch |= recorded & (self.pressed_button == self.flash_color) & all_on_disc

        bulb = torch.where(flash_active, self.flash_color + 1, 0)

        def show() -> None:
            self.lamp.show(torch.arange(self.num_envs, device=self.device), bulb)
            for button, depth in zip(self.buttons, depths, strict=True):
                button.show_depth(depth)

        self.update_visuals(show)
        return dict(
            success=self.success_latch & all_on_disc,
            failed=self.failed.clone(),
            n_on_disc=n_on_disc,
            all_on_disc=all_on_disc,
            flash_active=flash_active,
            flash_triggered=self.flash_triggered.clone(),
            flash_color=self.flash_color.clone(),
            pressed_button=self.pressed_button.clone(),
            obj_to_goal_pos=self._goal_vector(tcp, positions, all_on_disc),
        )

    def _goal_vector(self, tcp: torch.Tensor, positions: torch.Tensor, all_on_disc: torch.Tensor) -> torch.Tensor:
        """(B, 3) what the reward reaches for: the disc while a not-yet-placed cube is held,
        else the nearest such cube; then the flash colour's button; else nothing (0)."""
        never_placed = ~self.cubes_on_disc
        cube_distance = torch.linalg.norm(positions - tcp[:, None], dim=-1)
        holding = (never_placed & (cube_distance < self.HOLDING_RADIUS)).any(dim=-1)
        nearest = torch.where(never_placed, cube_distance, torch.inf).argmin(dim=-1)
        rows = torch.arange(self.num_envs, device=self.device)
        disc_goal = torch.cat([self.disc_xy, torch.full_like(self.disc_xy[:, :1], self.DISC_GOAL_Z)], dim=-1)
        collect = torch.where(holding[:, None], disc_goal, positions[rows, nearest]) - tcp
        button_xy = self.buttons_xy[self.flash_color, rows]
        press = torch.cat([button_xy, torch.full_like(button_xy[:, :1], self.BUTTON_GOAL_Z)], dim=-1) - tcp
        collecting = never_placed.any(dim=-1) & ~all_on_disc
        pressing = all_on_disc & (self.pressed_button < 0)
        goal = torch.where(pressing[:, None], press, torch.zeros_like(press))
        return torch.where(collecting[:, None], collect, goal)

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs["obj_to_goal_pos"] = info["obj_to_goal_pos"]
            obs["oracle_info"] = self.oracle_info
            poses = self.actor_raw_poses([self.disc, *self.cubes]).unbind(1)
            obs["disc_pose"] = poses[0]
            obs["cubes_on_disc"] = self.cubes_on_disc.float()
            obs["n_on_disc"] = info["n_on_disc"].float()
            obs["all_on_disc"] = info["all_on_disc"].float()
            obs["flash_active"] = info["flash_active"].float()
            obs["flash_color"] = info["flash_color"].float()
            obs["pressed_button"] = info["pressed_button"].float()
            for i, pose in enumerate(poses[1:]):
                obs[f"cube_{i}_pose"] = pose
        return obs

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reach the current goal, progress of cubes placed, then the press depth of the right
        button; 50 on success, −25 on failure."""
        all_on_disc = info["all_on_disc"].float()
        reach = 1 - torch.tanh(8 * torch.linalg.norm(info["obj_to_goal_pos"], dim=-1))
        progress = info["n_on_disc"].float() / self.N_CUBES
        rows = torch.arange(self.num_envs, device=self.device)
        correct_depth = torch.stack([button.depth for button in self.buttons])[self.flash_color, rows]
        press = (correct_depth / self.BUTTON_CAP_TRAVEL).clamp(0.0, 1.0)
        penalty, terms = self.smoothness_penalty(action)
        reward = 2 * reach + 10 * progress + 3 * all_on_disc * reach + 5 * all_on_disc * press - penalty
        terms = dict(reaching_reward=reach, progress=progress, press_reward=press, **terms)
        return self.finish_reward(reward, info, terms)


@register_task(FAMILY, "GatherAndRecall1-VLA-v0", number=86, split="short", data_source="MP",
               memory_type="Prospective", max_episode_steps=200)
class GatherAndRecall1VLAEnv(GatherAndRecallVLABaseEnv):
    """GatherAndRecall with 1 cube (the flash starts when it first reaches the disc)."""

    N_CUBES = 1


@register_task(FAMILY, "GatherAndRecall3-VLA-v0", number=87, split="medium", data_source="MP",
               memory_type="Prospective", max_episode_steps=400)
class GatherAndRecall3VLAEnv(GatherAndRecallVLABaseEnv):
    """GatherAndRecall with 3 cubes (flash after 1-2 of them)."""

    N_CUBES = 3


@register_task(FAMILY, "GatherAndRecall5-VLA-v0", number=88, split="medium", data_source="MP",
               memory_type="Prospective", max_episode_steps=600)
class GatherAndRecall5VLAEnv(GatherAndRecallVLABaseEnv):
    """GatherAndRecall with 5 cubes (flash after 1-4 of them)."""

    N_CUBES = 5


@register_task(FAMILY, "GatherAndRecall7-VLA-v0", number=89, split="long", data_source="MP",
               memory_type="Prospective", max_episode_steps=800)
class GatherAndRecall7VLAEnv(GatherAndRecallVLABaseEnv):
    """GatherAndRecall with 7 cubes (flash after 1-6 of them)."""

    N_CUBES = 7


@register_task(FAMILY, "GatherAndRecall9-VLA-v0", number=90, split="long", data_source="MP",
               memory_type="Prospective", max_episode_steps=1000)
class GatherAndRecall9VLAEnv(GatherAndRecallVLABaseEnv):
    """GatherAndRecall with 9 cubes (flash after 1-8 of them)."""

    N_CUBES = 9
