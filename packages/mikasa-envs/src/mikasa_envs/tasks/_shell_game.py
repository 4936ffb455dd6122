"""Machinery shared by the six shell-game families (``_shell_game_shared.md``).

Three upside-down mugs stand at three slots 0.2 m apart along y (0 Left, 1 Center, 2 Right);
a cue shows what is under them, then the robot must act on the right mug. Two kinds of
family share the scene, the slot draw, the phase clock and the success/reward helpers here:

* ``HiddenBallShellGameVLABaseEnv`` (Touch, Push, Pick): dynamic mugs the robot can move,
  one red ball under mug t. During the cue the mugs are parked 1000 m up and pinned there
  (pose and zero velocity written before and after the physics substeps of every step);
  the step that produces the first action frame stands them at their slots at rest, then
  they are free. This fixes the reference's free-fall / sink / pop-out bug (§6.1).
* ``ScriptedShellGameVLABaseEnv`` (ColorLamp, Shuffle, ShuffleColorLamp): kinematic mugs
  and balls whose pose is scripted for every frame (cue, shuffle animation, action layout),
  written before the substeps of the step that produces the frame. Kinematic bodies keep
  no velocity, so the reference's velocity build-up (§6.2) cannot happen.

Phase clock: C = ``cue_steps_per_env``, S = ``empty_steps_per_env`` (the shuffle length; 0
without a shuffle); the action phase starts at frame C + S. Success is always gated on the
action phase (the reference did this only in the dense reward modes, §1).

The fixed layout (slots, mug orientations, balls, swap schedule, lamp colours) lives in
``_shell_game_layout.py`` and the TouchMug / RedBall / GoalSite mixins in
``_shell_game_mixins.py``; both are re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
import sapien
import torch
from mani_skill.utils.structs import Actor

from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.building_blocks.cups import build_mug, mug_rest_height
from mikasa_envs.building_blocks.lamps import ColorSwitchLamp
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z, write_actor_poses
from mikasa_envs.family import Chance, TaskSpec
from mikasa_envs.tasks._shell_game_layout import (  # noqa: F401  (re-exported)
    BALL_COLORS,
    LAMP_BULBS,
    MUG_NAMES,
    MUG_QUAT_HANDLE_AWAY,
    MUG_QUAT_HANDLE_TOWARD_ROBOT,
    NUM_SLOTS,
    SHUFFLE_TASK_STATE,
    SLOT_NAMES,
    build_ball,
    normalized_quat,
    swap_schedule,
)
from mikasa_envs.tasks._shell_game_mixins import (  # noqa: F401  (re-exported)
    GoalSiteMixin,
    RedBallMixin,
    TouchMugMixin,
)


class ShellGameVLABaseEnv(MikasaVLABaseEnv):
    """Three inverted mugs on three slots; a cue, then the robot acts on one mug.

    Subclasses build their balls / markers / lamp in ``_load_task_objects``, draw their answer
    in ``_sample_answer`` and lay out each frame in ``_apply_frame``.
    """

    BALL_RADIUS: ClassVar[float] = 0.02
    MIN_DIST: ClassVar[float] = 0.2
    HEIGHT_OFFSET: ClassVar[float] = HIDE_OFFSET_Z
    # The procedural mug is built at the reference's YCB scale (building_blocks/cups.py).
    MUG_SCALE: ClassVar[float] = 1.3
    GOAL_THRESH: ClassVar[float] = 0.08
    STATIC_QVEL_THRESH: ClassVar[float] = 0.2
    # The slot base point P is drawn from U[−0.1, 0.1)² around the table centre.
    SLOT_BASE_RANGE: ClassVar[float] = 0.1
    # A ball resting on the table under a slot has its centre at this height.
    BALL_ON_TABLE_Z: ClassVar[float] = 0.02
    CUE_PHASE_STEPS = (1, 5)
    EMPTY_PHASE_STEPS = (0, 0)
    MUG_QUAT: ClassVar[tuple[float, float, float, float]] = MUG_QUAT_HANDLE_AWAY
    MUG_BODY_TYPE: ClassVar[str] = "dynamic"
    # Touch / Push / Pick end the episode at the first success (ManiSkill's rule); the others never.
    TERMINATE_ON_SUCCESS: ClassVar[bool] = True
    RENDER_CAMERA_EYE = (0.6, 0.7, 0.6)
    RENDER_CAMERA_TARGET = (0.0, 0.0, 0.15)

    mugs: list[Actor]

    GPU_MEMORY: ClassVar[dict[str, int]] = {
        "found_lost_pairs_capacity": 2**25,
        "max_rigid_patch_count": 2**21,
        "max_rigid_contact_count": 2**22,
    }
    TASK_STATE = ("slot_positions", "final_slot_of_mug", "final_positions", "_tcp_pose")

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self.mugs = [build_mug(self.scene, name, self.MUG_BODY_TYPE) for name in MUG_NAMES]
        self.mug_rest_z = mug_rest_height()
        b = self.num_envs
        self.slot_positions = torch.zeros(b, NUM_SLOTS, 3, device=self.device)
        # Per env, the slot each mug stands in during the action phase (identity without a shuffle).
        self.final_slot_of_mug = torch.arange(NUM_SLOTS, device=self.device).repeat(b, 1)
        # Per env, the position of the slot each mug stands in during the action phase.
        self.final_positions = torch.zeros(b, NUM_SLOTS, 3, device=self.device)
        self._tcp_pose = torch.zeros(b, 7, device=self.device)
        self._mug_quat = torch.tensor(self.MUG_QUAT, dtype=torch.float32, device=self.device)
        self._load_task_objects()

    def _load_task_objects(self) -> None:
        """Build the family's own objects (balls, goal marker, lamp)."""

    # -------------------------------------------------------------- episodes
    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Draw order: the answer (numpy, each env's RNG), then the slot base point (torch).
        self._sample_answer(env_idx)
        b = len(env_idx)
        base_xy = (torch.rand(b, 2, device=self.device) * 2 - 1) * self.SLOT_BASE_RANGE
        base = torch.cat([base_xy, torch.full((b, 1), self.mug_rest_z, device=self.device)], dim=1)
        offsets = torch.zeros(NUM_SLOTS, 3, device=self.device)
        offsets[:, 1] = (torch.arange(NUM_SLOTS, device=self.device) - 1) * self.MIN_DIST
        self.slot_positions[env_idx] = base[:, None, :] + offsets
        self.final_slot_of_mug[env_idx] = torch.arange(NUM_SLOTS, device=self.device)

    def _sample_answer(self, env_idx: torch.Tensor) -> None:
        """Draw the episode's answer for the envs in ``env_idx``."""
        raise NotImplementedError

    def _draw_slot_choice(self, env_idx: torch.Tensor) -> torch.Tensor:
        """One uniform index in {0, 1, 2} per env, from that env's numpy episode RNG."""
        keys = self._batched_episode_rng[env_idx.cpu().numpy()].choice(NUM_SLOTS)
        return torch.as_tensor(np.asarray(keys).reshape(-1), dtype=torch.long, device=self.device)

    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        # Only the cue is drawn; there is no empty phase unless a shuffle sets one.
        lo, hi = self.CUE_PHASE_STEPS
        self.cue_steps_per_env[env_idx] = torch.randint(lo, hi + 1, (len(env_idx),), device=self.device)
        self.empty_steps_per_env[env_idx] = 0

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        index = self.final_slot_of_mug[env_idx, :, None].expand(-1, -1, 3)
        self.final_positions[env_idx] = torch.gather(self.slot_positions[env_idx], 1, index)
        mask = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        mask[env_idx] = True
        self._apply_frame(self.elapsed_steps, mask, after_physics=True)

    # ------------------------------------------------------------- stepping
    def _apply_frame(self, t: torch.Tensor, env_mask: torch.Tensor | None, after_physics: bool) -> bool:
        """Write the scripted poses of frame ``t`` (per env) in the envs of ``env_mask`` (None:
        all); return whether anything was written. Called before the physics substeps of the
        step that produces frame t (``after_physics`` False), after them (True) and at reset."""
        raise NotImplementedError

    def _before_control_step(self) -> None:
        if self._apply_frame(self.elapsed_steps + 1, None, after_physics=False) and self.gpu_sim_enabled:
            self.scene.px.gpu_apply_rigid_dynamic_data()

    def _after_control_step(self) -> None:
        if self.gpu_sim_enabled:
            # ManiSkill fetches the GPU bodies only after this hook: read (ball follow) and
            # write (pins) the post-physics state, not the stale pre-step buffer.
            self.scene.px.gpu_fetch_rigid_dynamic_data()
        if self._apply_frame(self.elapsed_steps + 1, None, after_physics=True) and self.gpu_sim_enabled:
            self.scene.px.gpu_apply_rigid_dynamic_data()

    def _terminated(self, info: dict) -> torch.Tensor:
        """Touch / Push / Pick end on success (their reference has no override)."""
        if self.TERMINATE_ON_SUCCESS:
            return info["success"].clone()
        return super()._terminated(info)

    # --------------------------------------------------------------- writes
    def _write_poses(
        self, actors: Sequence[Actor], env_mask: torch.Tensor, poses: torch.Tensor, zero_velocity: bool
    ) -> bool:
        """Set ``actors[k]``'s pose to ``poses[:, k]`` ((B, K, 7)) in the envs of ``env_mask``.

        Through `write_actor_poses` (CPU: SAPIEN entities directly; GPU: only the masked rows,
        which the caller applies). Returns whether any env was written.
        """
        idx = torch.nonzero(env_mask).flatten()
        if len(idx) == 0:
            return False
        write_actor_poses(self.scene, actors, idx, poses[idx], zero_velocity)
        return True

    def _mug_poses_from_positions(self, positions: torch.Tensor) -> torch.Tensor:
        """(B, 3, 3) mug positions -> (B, 3, 7) raw poses with the task's mug orientation."""
        quat = self._mug_quat.expand(*positions.shape[:-1], 4)
        return torch.cat([positions, quat], dim=-1)

    # -------------------------------------------------------------- queries
    def actor_raw_poses(self, actors: Sequence[Actor]) -> torch.Tensor:
        """(B, K, 7) current raw poses [x, y, z, qw, qx, qy, qz] of ``actors``."""
        if not self.gpu_sim_enabled:
            rows = [np.concatenate([a._objs[0].pose.p, a._objs[0].pose.q]) for a in actors]
            return torch.from_numpy(np.asarray(rows, dtype=np.float32))[None].to(self.device)
        return torch.stack([a.pose.raw_pose for a in actors], dim=1)

    def mug_positions(self) -> torch.Tensor:
        """(B, 3, 3) current centres of mug 0, 1, 2."""
        return self.actor_raw_poses(self.mugs)[..., :3]

    def read_tcp_pose(self) -> torch.Tensor:
        """(B, 7) TCP raw pose, also kept for this frame's observation and reward (``_tcp_pose``)."""
        self._tcp_pose = self.agent.tcp.pose.raw_pose
        return self._tcp_pose

    def in_action_phase(self) -> torch.Tensor:
        """(B,) whether the current frame is in the action phase (t ≥ C + S)."""
        return self.elapsed_steps >= self.action_phase_start

    def is_robot_static(self) -> torch.Tensor:
        """(B,) every arm joint slower than ``STATIC_QVEL_THRESH`` rad/s."""
        return self.arm_qvel.abs().max(dim=-1).values <= self.STATIC_QVEL_THRESH

    def static_reward(self) -> torch.Tensor:
        """1 − tanh(5·‖arm qvel‖₂)."""
        return 1 - torch.tanh(5 * torch.linalg.norm(self.arm_qvel, dim=-1))

    def touch_reward(self, info: dict, penalty: torch.Tensor | None = None) -> tuple[torch.Tensor, dict]:
        """The touch families' dense reward: (reaching + static·placed + still·placed [− penalty])
        in the action phase, ``DENSE_REWARD_MAX`` on success; and its first ``reward_dict`` terms."""
        distance = torch.linalg.norm(info["obj_to_goal_pos"], dim=-1)
        reaching = 1 - torch.tanh(5 * distance)
        static = self.static_reward()
        placed = info["is_obj_placed"].float()
        still = info["is_robot_static"].float()
        reward = reaching + static * placed + still * placed
        if penalty is not None:
            reward = reward - penalty
        reward = reward * self.in_action_phase().float()
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        return reward, {"reaching_reward": reaching, "static_reward": static, "tcp_to_obj_dist": distance}


# ------------------------------------------------------------- Touch / Push / Pick
class HiddenBallShellGameVLABaseEnv(RedBallMixin, ShellGameVLABaseEnv):
    """Touch, Push, Pick: a red ball under one of three dynamic mugs.

    Cue frames (t < C) show the ball at slot t with the mugs parked ``HEIGHT_OFFSET`` up;
    from frame C the mugs stand on their slots and mug t covers the ball. The ball (visual
    only) follows mug t's xy while that mug's centre is at most ``BALL_FOLLOW_LIFT`` above
    rest height, so a lifted mug leaves it exposed on the table.
    """

    MUG_BODY_TYPE = "dynamic"
    BALL_FOLLOW_LIFT: ClassVar[float] = 0.05
    # The CPU "mugs are free" step: a cache the pinning recomputes (dropped on restore).
    TRANSIENT_STATE = ("_free_after_step",)

    def _load_task_objects(self) -> None:
        super()._load_task_objects()
        # CPU: the step after which the mugs are free (no pinning left this episode).
        self._free_after_step: int | None = None

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self._free_after_step = None
        super()._on_episode_start(env_idx)
        ball = self.slot_positions[env_idx, self.cup_with_ball_number[env_idx].long()].clone()
        ball[:, 2] = self.BALL_ON_TABLE_Z
        self._set_ball(env_idx, ball)

    def _set_ball(self, env_idx: torch.Tensor, positions: torch.Tensor) -> None:
        poses = torch.zeros(self.num_envs, 1, 7, device=self.device)
        poses[env_idx, 0, :3] = positions
        poses[:, 0, 3] = 1.0
        mask = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        mask[env_idx] = True
        self._write_poses([self.red_ball], mask, poses, zero_velocity=False)

    def _apply_frame(self, t: torch.Tensor, env_mask: torch.Tensor | None, after_physics: bool) -> bool:
        wrote = self._pin_mugs(t, env_mask)
        if after_physics:
            wrote |= self._ball_follows_mug()
        return wrote

    def _pin_mugs(self, t: torch.Tensor, env_mask: torch.Tensor | None) -> bool:
        """Pin the mugs for cue frames (parked up) and the first action frame (at rest on
        their slots, zero velocity); later frames leave them free."""
        if self._free_after_step is not None and int(t[0]) > self._free_after_step:
            return False  # CPU: the mugs are free for the rest of this episode
        cue = self.cue_steps_per_env
        pinned = t <= cue
        if env_mask is not None:
            pinned &= env_mask
        if not self.gpu_sim_enabled and not bool(pinned[0]):
            self._free_after_step = int(t[0])
            return False
        positions = self.slot_positions.clone()
        positions[..., 2] += torch.where(t < cue, self.HEIGHT_OFFSET, 0.0)[:, None]
        return self._write_poses(self.mugs, pinned, self._mug_poses_from_positions(positions), zero_velocity=True)

    def _on_state_restored(self, env_idx: torch.Tensor) -> None:
        super()._on_state_restored(env_idx)
        self._free_after_step = None

    def _ball_follows_mug(self) -> bool:
        if not self.gpu_sim_enabled:
            mug = self.mugs[int(self.cup_with_ball_number[0])]._objs[0].pose.p
            if mug[2] > self.mug_rest_z + self.BALL_FOLLOW_LIFT:
                return False
            self.red_ball._objs[0].pose = sapien.Pose([mug[0], mug[1], self.BALL_ON_TABLE_Z])
            return True
        rows = torch.arange(self.num_envs, device=self.device)
        mug = self.actor_raw_poses(self.mugs)[rows, self.cup_with_ball_number.long(), :3]
        follow = mug[:, 2] <= self.mug_rest_z + self.BALL_FOLLOW_LIFT
        ball = torch.cat([mug[:, :2], torch.full_like(mug[:, :1], self.BALL_ON_TABLE_Z)], dim=1)
        poses = torch.cat([ball, torch.tensor([1.0, 0, 0, 0], device=self.device).expand(len(ball), 4)], dim=1)
        return self._write_poses([self.red_ball], follow, poses[:, None], zero_velocity=False)


# ---------------------------------------------------- ColorLamp / Shuffle / ShuffleColorLamp
class ScriptedShellGameVLABaseEnv(ShellGameVLABaseEnv):
    """Kinematic mugs (and balls) whose pose is scripted for every frame, optionally shuffled.

    Without a shuffle (``SHUFFLE_STEPS`` None) the mugs are parked up during the cue and
    stand on their slots from frame C. With one, C cue frames are followed by S shuffle
    frames in which N swaps of k = ⌊S/N⌋ frames each move two mugs along a half circle
    (counter-clockwise seen from above) while rising ``SWAP_ARC_HEIGHT``
    (``shell_game_shuffle_touch.md``); the action phase starts at frame C + S.
    """

    MUG_BODY_TYPE = "kinematic"
    TERMINATE_ON_SUCCESS = False
    SWAP_ARC_HEIGHT: ClassVar[float] = 0.06
    # Inclusive ranges of the shuffle length S and the number of swaps N; None: no shuffle.
    SHUFFLE_STEPS: ClassVar[tuple[int, int] | None] = None
    NUM_SWAPS: ClassVar[tuple[int, int]] = (0, 0)
    SWAP_SLOT_PAIRS: ClassVar[tuple[tuple[int, int], ...]] = ((0, 1), (0, 2), (1, 2))

    @property
    def has_shuffle(self) -> bool:
        """Whether the mugs are shuffled between the cue and the action phase."""
        return self.SHUFFLE_STEPS is not None

    @property
    def max_swaps(self) -> int:
        """N_max: swap pairs are drawn for this many swaps; only the first N are performed."""
        return self.NUM_SWAPS[1]

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        if self.has_shuffle:
            b, n_max = self.num_envs, self.max_swaps
            device = self.device
            self.shuffle_steps_per_env = torch.zeros(b, dtype=torch.int64, device=device)
            self.num_swaps_per_env = torch.zeros(b, dtype=torch.int64, device=device)
            self.steps_per_swap_per_env = torch.ones(b, dtype=torch.int64, device=device)
            self.swap_pairs = torch.zeros(b, n_max, 2, dtype=torch.int64, device=device)
            self.slot_of_mug = torch.arange(NUM_SLOTS, device=device).repeat(b, n_max + 1, 1)
        self._scripted_actors = self.mugs + self._scripted_balls()

    def _scripted_balls(self) -> list[Actor]:
        """The balls whose pose the family scripts per frame (``_ball_positions_at``)."""
        return []

    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        super()._sample_phase_lengths(env_idx)
        if not self.has_shuffle:
            return
        # Torch draws after C: S, then N, then N_max swap pairs per env.
        b, device = len(env_idx), self.device
        s_lo, s_hi = self.SHUFFLE_STEPS
        n_lo, n_hi = self.NUM_SWAPS
        shuffle = torch.randint(s_lo, s_hi + 1, (b,), device=device)
        swaps = torch.randint(n_lo, n_hi + 1, (b,), device=device)
        pair_choice = torch.randint(0, len(self.SWAP_SLOT_PAIRS), (b, self.max_swaps), device=device)
        pairs = torch.tensor(self.SWAP_SLOT_PAIRS, device=device)[pair_choice]
        self.shuffle_steps_per_env[env_idx] = shuffle
        self.empty_steps_per_env[env_idx] = shuffle
        self.num_swaps_per_env[env_idx] = swaps
        self.steps_per_swap_per_env[env_idx] = shuffle // swaps
        self.swap_pairs[env_idx] = pairs
        self.slot_of_mug[env_idx] = swap_schedule(pairs, swaps)
        rows = torch.arange(b, device=device)
        self.final_slot_of_mug[env_idx] = self.slot_of_mug[env_idx][rows, swaps]

    # -------------------------------------------------------------- frames
    def mug_positions_at(self, t: torch.Tensor) -> torch.Tensor:
        """(B, 3, 3) scripted centre of each mug in frame ``t`` (per env)."""
        slots = self.slot_positions
        cue = (t < self.cue_steps_per_env)[:, None, None]
        parked = slots + torch.tensor([0.0, 0.0, self.HEIGHT_OFFSET], device=self.device)
        positions = self.final_positions
        if self.has_shuffle:
            positions = self._shuffle_positions(t, positions)
        return torch.where(cue, parked, positions)

    def _shuffle_positions(self, t: torch.Tensor, final: torch.Tensor) -> torch.Tensor:
        """Mug centres during swap frames; ``final`` (the last arrangement, at rest) otherwise,
        including the S − N·k remainder frames after the last swap."""
        k = self.steps_per_swap_per_env
        j = (t - self.cue_steps_per_env).clamp(min=0)
        swap = j // k
        swapping = (t >= self.cue_steps_per_env) & (swap < self.num_swaps_per_env)
        s = swap.clamp(max=self.max_swaps - 1)
        rows = torch.arange(self.num_envs, device=self.device)
        before = torch.gather(self.slot_positions, 1, self.slot_of_mug[rows, s][..., None].expand(-1, -1, 3))
        after = torch.gather(self.slot_positions, 1, self.slot_of_mug[rows, s + 1][..., None].expand(-1, -1, 3))
        tau = ((j - swap * k).float() / k.float())[:, None]
        phi = math.pi * tau * tau * (3 - 2 * tau)  # smoothstep-eased half turn
        middle, half = (before + after) / 2, (before - after) / 2
        # The half-chord turned +90° about z: the two swapped mugs stay diametrically opposite.
        perpendicular = torch.stack([-half[..., 1], half[..., 0]], dim=-1)
        xy = middle[..., :2] + torch.cos(phi)[..., None] * half[..., :2] + torch.sin(phi)[..., None] * perpendicular
        # Every mug, the one left in place too, rises and falls with the swap (reference).
        z = self.mug_rest_z + self.SWAP_ARC_HEIGHT * torch.sin(phi).expand(-1, NUM_SLOTS)
        animated = torch.cat([xy, z[..., None]], dim=-1)
        return torch.where(swapping[:, None, None], animated, final)

    def _ball_positions_at(self, t: torch.Tensor) -> torch.Tensor:
        """(B, K, 3) scripted centre of each ball of ``_scripted_balls`` in frame ``t``."""
        return torch.zeros(self.num_envs, 0, 3, device=self.device)

    def _apply_frame(self, t: torch.Tensor, env_mask: torch.Tensor | None, after_physics: bool) -> bool:
        # Kinematic bodies do not move by themselves: one write before the substeps suffices.
        if after_physics and env_mask is None:
            return False
        mask = torch.ones(self.num_envs, dtype=torch.bool, device=self.device) if env_mask is None else env_mask
        mugs = self._mug_poses_from_positions(self.mug_positions_at(t))
        balls = self._ball_positions_at(t)
        identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=self.device).expand(*balls.shape[:-1], 4)
        poses = torch.cat([mugs, torch.cat([balls, identity], dim=-1)], dim=1)
        wrote = self._write_poses(self._scripted_actors, mask, poses, zero_velocity=False)
        return self._after_frame_written(t, mask) or wrote

    def _after_frame_written(self, t: torch.Tensor, env_mask: torch.Tensor) -> bool:
        """Family hook run with every frame write (the lamp); returns whether it wrote."""
        return False


# -------------------------------------------------------------------- colour lamp
class ColorLampShellGameVLABaseEnv(ScriptedShellGameVLABaseEnv):
    """ColorLamp families: red, green and blue balls at slots 0, 1, 2 during the cue, then
    hidden; a lamp behind the centre slot is white until the action phase, then shows
    colour k. Touch the mug that started over the ball of colour k (mug k)."""

    LAMP_BEHIND_OFFSET_X: ClassVar[float] = 0.25
    LAMP_HEIGHT: ClassVar[float] = 0.06
    DENSE_REWARD_MAX = 3.0
    TASK_STATE = ("target_color", "lamp")

    def _load_task_objects(self) -> None:
        self.balls = [build_ball(self.scene, name, rgba, self.BALL_RADIUS) for name, rgba in BALL_COLORS.items()]
        self.ball_red, self.ball_green, self.ball_blue = self.balls
        self.lamp = ColorSwitchLamp(self.scene, "lamp", LAMP_BULBS, self.num_envs, self.device)
        self.target_color = torch.zeros(self.num_envs, dtype=torch.uint8, device=self.device)

    def _scripted_balls(self) -> list[Actor]:
        return self.balls

    def _sample_answer(self, env_idx: torch.Tensor) -> None:
        self.target_color[env_idx] = self._draw_slot_choice(env_idx).to(torch.uint8)
        self.task_cue = self.target_color.clone()

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        rows = torch.arange(self.num_envs, device=self.device)
        # The answer slot: where mug k (the one that started over colour k) ends up.
        self.oracle_info = self.final_slot_of_mug[rows, self.target_color.long()].to(torch.uint8)
        lamp = self.slot_positions[env_idx, 1].clone()
        lamp[:, 0] += self.LAMP_BEHIND_OFFSET_X
        lamp[:, 2] = self.LAMP_HEIGHT
        self.lamp.place(env_idx, lamp, self.lamp.bulb_index("white"))
        super()._on_episode_start(env_idx)

    def _ball_positions_at(self, t: torch.Tensor) -> torch.Tensor:
        # Cue: each ball on the table at its slot; afterwards all parked above slot 0.
        shown = self.slot_positions.clone()
        shown[..., 2] = self.BALL_ON_TABLE_Z
        hidden = self.slot_positions[:, :1].expand(-1, NUM_SLOTS, -1).clone()
        hidden[..., 2] += self.HEIGHT_OFFSET
        cue = (t < self.cue_steps_per_env)[:, None, None]
        return torch.where(cue, shown, hidden)

    def _after_frame_written(self, t: torch.Tensor, env_mask: torch.Tensor) -> bool:
        idx = torch.nonzero(env_mask).flatten()
        lit = (t >= self.action_phase_start)[idx]
        bulb = torch.where(lit, self.target_color[idx].long() + 1, 0)
        changed = bool((self.lamp.shown[idx] != bulb).any())
        self.lamp.show(idx, bulb)
        return changed

    def target_slot_position(self) -> torch.Tensor:
        """(B, 3) the answer slot's position (where mug k stands in the action phase)."""
        rows = torch.arange(self.num_envs, device=self.device)
        return self.slot_positions[rows, self.oracle_info.long()]

    def evaluate(self) -> dict:
        """Placed over the answer slot, static, in the action phase."""
        obj_to_goal_pos = self.target_slot_position() - self.read_tcp_pose()[:, :3]
        is_obj_placed = torch.linalg.norm(obj_to_goal_pos, dim=-1) <= self.GOAL_THRESH
        is_robot_static = self.is_robot_static()
        return dict(
            obj_to_goal_pos=obj_to_goal_pos,
            is_obj_placed=is_obj_placed,
            is_robot_static=is_robot_static,
            success=is_obj_placed & is_robot_static & self.in_action_phase(),
        )

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self._tcp_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs["obj_to_goal_pos"] = info["obj_to_goal_pos"]
            obs["target_color"] = self.target_color
            obs["oracle_info"] = self.oracle_info
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """(reaching + static·placed + still·placed) in the action phase; 3 on success."""
        reward, terms = self.touch_reward(info)
        self._reward_dict = {**terms, "is_obj_placed": info["is_obj_placed"]}
        return reward


def shell_game_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of the shell games: a uniform guess among the three mugs."""
    return Chance(1 / 3, "1/3: the ball's mug is one of 3 mugs")


RL_SHELL_GAME_TIMING = {"CUE_PHASE_STEPS": (5, 5), "EMPTY_PHASE_STEPS": (0, 0)}
"""The RL release's shell-game clock: the ball is visible while ``elapsed_steps < 5`` (the
mugs are away), then the mugs stand over the slots; success and reward count from step 5 on
(the VLA families draw the cue length from [1, 5])."""
