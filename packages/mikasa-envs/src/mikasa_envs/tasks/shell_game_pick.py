"""ShellGamePick (registered extra variant): see where the ball is, then lift that mug by its handle."""

from __future__ import annotations

from typing import Any, ClassVar

import torch

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._shell_game import (
    MUG_QUAT_HANDLE_TOWARD_ROBOT,
    RL_SHELL_GAME_TIMING,
    GoalSiteMixin,
    HiddenBallShellGameVLABaseEnv,
    shell_game_chance,
)

FAMILY = TaskFamily(
    "shell_game_pick",
    hidden="which mug hides the ball: the ball is in view during the cue, under a mug from then on",
    chance=shell_game_chance,
    rl_variants=(
        RLVariant(
            number=3, env_id="ShellGamePick-v0", vla_env_id="ShellGamePick-VLA-v0",
            group="ShellGame", memory_type="Object", max_episode_steps=90, reward_divisor=75.0,
            oracle_info="cup_with_ball_number", overrides=RL_SHELL_GAME_TIMING,
        ),
    ),
)


@register_task(FAMILY, "ShellGamePick-VLA-v0", number=97, memory_type="Spatial",
               max_episode_steps=30)
class ShellGamePickVLAEnv(GoalSiteMixin, HiddenBallShellGameVLABaseEnv):
    """**Task Description:** a red ball lies on the table at one of three places; then three
    upside-down mugs appear over the three places, handles toward the robot, and one of
    them hides the ball. Pick that mug up by its handle and lift it toward an invisible goal
    9 cm above its rest position.

    **Randomizations:** the ball's slot (Left / Center / Right); the slot row's position
    (±0.1 m in x and y); the cue length (1-5 steps); arm joint noise.

    **Success Conditions:** in the action phase, the ball mug's centre is within 0.08 m
    (1.6 × 0.05) of the goal (above its slot at z = 0.145) and every arm joint moves slower
    than 0.2 rad/s; a grasp is not required. The episode terminates at the first success.
    """

    LANGUAGE_INSTRUCTION = "Observe which cup hides the ball, wait, then pick up that cup and lift it."
    MUG_QUAT = MUG_QUAT_HANDLE_TOWARD_ROBOT
    GOAL_THRESH = 0.05
    GOAL_SITE_RADIUS = 0.05
    # The goal's height: ball centre (0.02) + 0.10 + 0.025.
    GOAL_Z: ClassVar[float] = 0.145
    PLACED_THRESH_SCALE: ClassVar[float] = 1.6
    # Handle point: a fixed world offset from the ball mug's centre (reference; 0.062 m long).
    HANDLE_OFFSET_X: ClassVar[float] = 0.045
    HANDLE_OFFSET_Y: ClassVar[float] = 0.043
    HANDLE_REACHED_THRESH: ClassVar[float] = 0.04
    # Sum of both finger joints when fully open.
    GRIPPER_OPEN_WIDTH: ClassVar[float] = 0.08
    DENSE_REWARD_MAX = 75.0
    TASK_STATE = ("_target_mug_pose",)

    def _load_task_objects(self) -> None:
        super()._load_task_objects()
        self._build_goal_site()

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        super()._on_episode_start(env_idx)
        goal = self.slot_positions[env_idx, self.cup_with_ball_number[env_idx].long()].clone()
        goal[:, 2] = self.GOAL_Z
        self._place_goal_site(env_idx, goal)

    def handle_position(self, mug_position: torch.Tensor) -> torch.Tensor:
        """(B, 3) handle point of a mug centred at ``mug_position`` (fixed world offset)."""
        offset = torch.tensor([-self.HANDLE_OFFSET_X, self.HANDLE_OFFSET_Y, 0.0], device=self.device)
        return mug_position + offset

    def is_grasping_ball_mug(self) -> torch.Tensor:
        """(B,) ManiSkill's Panda grasp test on mug t."""
        if not self.gpu_sim_enabled:
            return self.agent.is_grasping(self.mugs[int(self.cup_with_ball_number[0])])
        grasped = torch.stack([self.agent.is_grasping(mug) for mug in self.mugs], dim=1)
        return grasped[torch.arange(self.num_envs, device=self.device), self.cup_with_ball_number.long()]

    def evaluate(self) -> dict:
        """Ball mug near the goal, robot static, in the action phase (no grasp needed)."""
        self._target_mug_pose = self.target_mug_pose()
        self.read_tcp_pose()
        obj_to_goal_pos = self.goal_pos - self._target_mug_pose[:, :3]
        is_obj_placed = torch.linalg.norm(obj_to_goal_pos, dim=-1) <= self.PLACED_THRESH_SCALE * self.GOAL_THRESH
        is_robot_static = self.is_robot_static()
        return dict(
            is_grasped=self.is_grasping_ball_mug(),
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
            obs["handle_pos"] = self.handle_position(self._target_mug_pose[:, :3])
            obs["ball_pose"] = self.ball_pose()
            obs["oracle_info"] = self.oracle_info
            obs["is_grasped"] = info["is_grasped"]
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reach the handle, open, grasp, lift toward the goal, hold still; 75 on success."""
        tcp = self._tcp_pose[:, :3]
        mug = self._target_mug_pose[:, :3]
        handle_delta = self.handle_position(mug) - tcp
        tcp_to_handle = torch.linalg.norm(handle_delta, dim=-1)
        obj_to_goal = torch.linalg.norm(info["obj_to_goal_pos"], dim=-1)
        width = self.agent.robot.get_qpos()[:, -2:].sum(dim=-1)
        grasped = info["is_grasped"].float()
        reaching = 1 - torch.tanh(10 * tcp_to_handle)
        place = 1 - torch.tanh(5 * obj_to_goal)
        static = self.static_reward()
        reached = (tcp_to_handle <= self.HANDLE_REACHED_THRESH).float()
        open_bonus = (width / self.GRIPPER_OPEN_WIDTH) * (1 - reached)
        grasp = grasped * reached
        placed = info["is_obj_placed"].float()
        still = info["is_robot_static"].float()
        reward = (
            3 * reaching
            + 1.5 * open_bonus
            + 2 * reached
            + 10 * grasp
            + 30 * place * grasped
            + 5 * static * placed * grasped
            + 5 * still * placed * grasped
        )
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        reward = reward * self.in_action_phase().float()
        self._reward_dict = {
            "reaching_reward": reaching,
            "open_gripper_reward": open_bonus,
            "grasp_reward": grasp,
            "reached_status": reached,
            "is_grasped": info["is_grasped"],
            "place_reward": place,
            "static_reward": static,
            "tcp_to_handle_dist": tcp_to_handle,
            "tcp_to_obj_dist": torch.linalg.norm(mug - tcp, dim=-1),
            "obj_to_goal_dist": obj_to_goal,
            "is_obj_placed": info["is_obj_placed"],
            "gripper_width": width,
            "dx_handle": handle_delta[:, 0],
            "dy_handle": handle_delta[:, 1],
            "dz_handle": handle_delta[:, 2],
        }
        return reward
