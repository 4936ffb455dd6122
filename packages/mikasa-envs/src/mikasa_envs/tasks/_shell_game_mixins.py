"""Mixins of the shell-game family bases (``_shell_game.py``): the touch rules, the red ball
hidden under a mug and the goal site of Push and Pick.

They rely on the attributes and helpers of ``ShellGameVLABaseEnv`` (``mugs``,
``final_positions``, ``actor_raw_poses``, ``_write_poses``, ...), which they precede in the
method resolution order of the classes that use them.
"""

from __future__ import annotations

from typing import Any, ClassVar

import sapien
import torch
from mani_skill.utils.building import actors as actor_builders

from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z
from mikasa_envs.tasks._shell_game_layout import build_ball


# ---------------------------------------------------------------------------- touch rules
class TouchMugMixin:
    """Success, reward and state of the touch-the-ball-mug families (Touch, ShuffleTouch).

    The target is mug t (``cup_with_ball_number``), wherever it stands. Success: the TCP
    within ``GOAL_THRESH`` of its centre, the arm static, no mug moved more than
    ``MUG_DISPLACEMENT_SUCCESS_THRESH`` in xy from its action-phase slot, action phase.
    """

    MUG_DISPLACEMENT_PENALTY_COEF: ClassVar[float] = 0.1
    MUG_DISPLACEMENT_SUCCESS_THRESH: ClassVar[float] = 0.05
    DENSE_REWARD_MAX = 3.0
    TASK_STATE = ("_target_mug_pose",)

    def evaluate(self) -> dict:
        """Placed, static, mug displacement and success (gated on the action phase)."""
        poses = self.actor_raw_poses(self.mugs)
        rows = torch.arange(self.num_envs, device=self.device)
        target = poses[rows, self.cup_with_ball_number.long(), :3]
        obj_to_goal_pos = target - self.read_tcp_pose()[:, :3]
        in_action = self.in_action_phase()
        shift = torch.linalg.norm(poses[..., :2] - self.final_positions[..., :2], dim=-1).max(dim=-1).values
        mug_max_displacement = torch.where(in_action, shift, torch.zeros_like(shift))
        is_obj_placed = torch.linalg.norm(obj_to_goal_pos, dim=-1) <= self.GOAL_THRESH
        is_robot_static = self.is_robot_static()
        is_mug_displacement_ok = mug_max_displacement <= self.MUG_DISPLACEMENT_SUCCESS_THRESH
        self._target_mug_pose = poses[rows, self.cup_with_ball_number.long()]
        return dict(
            obj_to_goal_pos=obj_to_goal_pos,
            is_obj_placed=is_obj_placed,
            is_robot_static=is_robot_static,
            mug_max_displacement=mug_max_displacement,
            is_mug_displacement_ok=is_mug_displacement_ok,
            success=is_obj_placed & is_robot_static & is_mug_displacement_ok & in_action,
        )

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self._tcp_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs["obj_pose"] = self._target_mug_pose
            obs["ball_pose"] = self.ball_pose()
            obs["oracle_info"] = self.oracle_info
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """(reaching + static·placed + still·placed − shift penalty) in the action phase; 3 on success."""
        penalty = self.MUG_DISPLACEMENT_PENALTY_COEF * torch.tanh(10 * info["mug_max_displacement"])
        reward, terms = self.touch_reward(info, penalty)
        self._reward_dict = {
            **terms,
            "mug_max_displacement": info["mug_max_displacement"],
            "mug_shift_penalty": penalty,
            "is_mug_displacement_ok": info["is_mug_displacement_ok"],
            "is_obj_placed": info["is_obj_placed"],
        }
        return reward


class RedBallMixin:
    """The red ball of Touch, Push, Pick and Shuffle, hidden under mug t
    (``cup_with_ball_number``, drawn per episode); ``oracle_info`` is the slot mug t stands
    in during the action phase."""

    BALL_RGBA: ClassVar[tuple[int, int, int, int]] = (255, 0, 0, 255)
    TASK_STATE = ("cup_with_ball_number",)

    def _load_task_objects(self) -> None:
        self.red_ball = build_ball(self.scene, "red_ball", self.BALL_RGBA, self.BALL_RADIUS)
        self.cup_with_ball_number = torch.zeros(self.num_envs, dtype=torch.uint8, device=self.device)

    def _sample_answer(self, env_idx: torch.Tensor) -> None:
        self.cup_with_ball_number[env_idx] = self._draw_slot_choice(env_idx).to(torch.uint8)

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        rows = torch.arange(self.num_envs, device=self.device)
        self.oracle_info = self.final_slot_of_mug[rows, self.cup_with_ball_number.long()].to(torch.uint8)
        super()._on_episode_start(env_idx)

    def target_mug_pose(self) -> torch.Tensor:
        """(B, 7) raw pose of mug t, the one hiding the ball."""
        if not self.gpu_sim_enabled:
            return self.actor_raw_poses([self.mugs[int(self.cup_with_ball_number[0])]])[:, 0]
        rows = torch.arange(self.num_envs, device=self.device)
        return self.actor_raw_poses(self.mugs)[rows, self.cup_with_ball_number.long()]

    def ball_pose(self) -> torch.Tensor:
        """(B, 7) raw pose of the red ball."""
        return self.actor_raw_poses([self.red_ball])[:, 0]


class GoalSiteMixin:
    """An invisible-to-the-policy goal sphere (human renders only), placed at episode start."""

    GOAL_SITE_RADIUS: ClassVar[float]
    GOAL_SITE_RGBA: ClassVar[tuple[int, int, int, int]] = (0, 255, 0, 255)
    TASK_STATE = ("goal_pos",)

    def _build_goal_site(self) -> None:
        self.goal_site = actor_builders.build_sphere(
            self.scene,
            radius=self.GOAL_SITE_RADIUS,
            color=list(rgba01(self.GOAL_SITE_RGBA)),
            name="goal_site",
            body_type="kinematic",
            add_collision=False,
            initial_pose=sapien.Pose(p=[0, 0, HIDE_OFFSET_Z]),
        )
        # ManiSkill hides these from the sensor cameras and shows them in human renders.
        self._hidden_objects.append(self.goal_site)
        self.goal_pos = torch.zeros(self.num_envs, 3, device=self.device)

    def _place_goal_site(self, env_idx: torch.Tensor, positions: torch.Tensor) -> None:
        self.goal_pos[env_idx] = positions
        poses = torch.zeros(self.num_envs, 1, 7, device=self.device)
        poses[:, 0, :3] = self.goal_pos
        poses[:, 0, 3] = 1.0
        mask = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        mask[env_idx] = True
        self._write_poses([self.goal_site], mask, poses, zero_velocity=False)

