"""ShellGamePush: see where the ball is, then push the mug that hides it forward (+x)."""

from __future__ import annotations

from typing import Any, ClassVar

import torch

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._shell_game import (
    RL_SHELL_GAME_TIMING,
    GoalSiteMixin,
    HiddenBallShellGameVLABaseEnv,
    shell_game_chance,
)

FAMILY = TaskFamily(
    "shell_game_push",
    hidden="which mug hides the ball: the ball is in view during the cue, under a mug from then on",
    overlays="shell_game",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(1, 1),
    chance=shell_game_chance,
    rl_variants=(
        RLVariant(
            number=2, env_id="ShellGamePush-v0", vla_env_id="ShellGamePush-VLA-v0",
            group="ShellGame", memory_type="Object", max_episode_steps=90, reward_divisor=4.0,
            oracle_info="cup_with_ball_number", overrides=RL_SHELL_GAME_TIMING,
        ),
    ),
)



@register_task(FAMILY, "ShellGamePush-VLA-v0", number=2, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=30)
class ShellGamePushVLAEnv(GoalSiteMixin, HiddenBallShellGameVLABaseEnv):
    """**Task Description:** a red ball lies on the table at one of three places; then three
    upside-down mugs appear over the three places and one of them hides the ball. Push that
    mug forward (away from the robot, +x) toward an invisible goal 10 cm beyond its slot, and
    hold still.

    **Randomizations:** the ball's slot (Left / Center / Right); the slot row's position
    (±0.1 m in x and y); the cue length (1-5 steps); arm joint noise.

    **Success Conditions:** in the action phase, the ball mug's centre is within 0.096 m
    (1.6 × 0.06) of the goal (slot + (0.1, 0, 0), at z = 0.05) and every arm joint moves
    slower than 0.3 rad/s. The episode terminates at the first success.
    """

    LANGUAGE_INSTRUCTION = "Observe which cup hides the ball, wait, then push that cup forward."
    GOAL_THRESH = 0.06
    GOAL_SITE_RADIUS = 0.06
    # The goal is 10 cm beyond the ball's start, 3 cm above the ball's centre.
    GOAL_OFFSET: ClassVar[tuple[float, float, float]] = (0.10, 0.0, 0.03)
    PLACED_THRESH_SCALE: ClassVar[float] = 1.6
    REACHED_THRESH: ClassVar[float] = 0.08
    STATIC_QVEL_THRESH = 0.3
    DENSE_REWARD_MAX = 4.0
    TASK_STATE = ("_target_mug_pose",)

    def _load_task_objects(self) -> None:
        super()._load_task_objects()
        self._build_goal_site()

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        super()._on_episode_start(env_idx)
        goal = self.slot_positions[env_idx, self.cup_with_ball_number[env_idx].long()].clone()
        goal[:, 2] = self.BALL_ON_TABLE_Z
        goal += torch.tensor(self.GOAL_OFFSET, device=self.device)
        self._place_goal_site(env_idx, goal)

    def evaluate(self) -> dict:
        """Ball mug near the goal, robot static (0.3 rad/s), in the action phase."""
        self._target_mug_pose = self.target_mug_pose()
        self.read_tcp_pose()
        obj_to_goal_pos = self.goal_pos - self._target_mug_pose[:, :3]
        is_obj_placed = torch.linalg.norm(obj_to_goal_pos, dim=-1) <= self.PLACED_THRESH_SCALE * self.GOAL_THRESH
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
            obs["goal_pos"] = self.goal_pos
            obs["obj_pose"] = self._target_mug_pose
            obs["ball_pose"] = self.ball_pose()
            obs["oracle_info"] = self.oracle_info
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """reaching + 2·place·reached + 0.2·(static + still)·placed in the action phase; 4 on success."""
        tcp_to_obj = torch.linalg.norm(self._target_mug_pose[:, :3] - self._tcp_pose[:, :3], dim=-1)
        obj_to_goal = torch.linalg.norm(info["obj_to_goal_pos"], dim=-1)
        reaching = 1 - torch.tanh(10 * tcp_to_obj)
        place = 1 - torch.tanh(5 * obj_to_goal)
        static = self.static_reward()
        reached = (tcp_to_obj <= self.REACHED_THRESH).float()
        placed = info["is_obj_placed"].float()
        still = info["is_robot_static"].float()
        reward = reaching + 2 * place * reached + 0.2 * static * placed + 0.2 * still * placed
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        reward = reward * self.in_action_phase().float()
        self._reward_dict = {
            "reaching_reward": reaching,
            "static_reward": static,
            "is_robot_static": info["is_robot_static"],
            "place_reward": place,
            "tcp_to_obj_dist": tcp_to_obj,
            "obj_to_goal_dist": obj_to_goal,
            "is_obj_placed": info["is_obj_placed"],
            "reached_status": reached,
        }
        return reward
