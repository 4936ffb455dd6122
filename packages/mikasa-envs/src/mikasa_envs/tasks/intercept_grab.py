"""InterceptGrab: catch a rolling ball with the gripper and hold still."""

from __future__ import annotations

from typing import Any, ClassVar

import torch

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._intercept import RL_BALL_IN_VIEW, InterceptBallVLABaseEnv, intercept_chance

FAMILY = TaskFamily(
    "intercept_grab",
    hidden=(
        "the ball's path: in view for its first 10 frames, then unseen until the robot "
        "touches it"
    ),
    overlays="intercept",
    wrapper_table_rank=(8, 8),
    chance=intercept_chance,
    rl_variants=(
        RLVariant(
            number=7, env_id="InterceptGrabSlow-v0", vla_env_id="InterceptGrabSlow-VLA-v0",
            group="InterceptGrab", memory_type="Spatial", max_episode_steps=90,
            reward_divisor=300.0, oracle_info="initial_velocity", overrides=RL_BALL_IN_VIEW,
        ),
        RLVariant(
            number=8, env_id="InterceptGrabMedium-v0", vla_env_id="InterceptGrabMedium-VLA-v0",
            group="InterceptGrab", memory_type="Spatial", max_episode_steps=90,
            reward_divisor=300.0, oracle_info="initial_velocity", overrides=RL_BALL_IN_VIEW,
        ),
        RLVariant(
            number=9, env_id="InterceptGrabFast-v0", vla_env_id="InterceptGrabFast-VLA-v0",
            group="InterceptGrab", memory_type="Spatial", max_episode_steps=90,
            reward_divisor=300.0, oracle_info="initial_velocity", overrides=RL_BALL_IN_VIEW,
        ),
    ),
)



class InterceptGrabVLABaseEnv(InterceptBallVLABaseEnv):
    """**Task Description:** a red ball is launched rolling along +y across the table.
    Intercept it, close the gripper on it and come to rest while holding it. The cameras
    show the ball for its first 10 frames, then not until the robot touches it: its speed
    and heading must be measured from those frames and its path remembered (DEVIATIONS.md,
    Fixed #35).

    **Randomizations:** the ball's start on the table (x ∈ [−0.35, −0.05),
    y ∈ [−0.90, −0.65)); its launch velocity (vx ∈ [0, 0.05), vy in the variant's range);
    arm joint noise.

    **Success Conditions:** both finger pads press on the ball (ManiSkill's Panda grasp
    test: ≥ 0.5 N each, within 85° of the closing direction) and every arm joint moves
    slower than 0.2 rad/s, at any step (not latched).
    """

    LANGUAGE_INSTRUCTION = "Intercept the rolling ball and grasp it to stop it."
    BALL_START_Z = 0.02  # resting on the table
    STATIC_QVEL_THRESH: ClassVar[float] = 0.2
    DENSE_REWARD_MAX = 300.0

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self._finger_entities = {
            body.entity for link in (self.agent.finger1_link, self.agent.finger2_link) for body in link._bodies
        }

    def is_ball_grasped(self) -> torch.Tensor:
        """(B,) ManiSkill's Panda grasp test on the ball."""
        if not self.gpu_sim_enabled and not self._ball_touches_cpu(self._finger_entities):
            # The test needs both fingers pressing on the ball: skip it (and its pose
            # algebra, ~1/3 of a step) while neither touches the ball at all.
            return torch.zeros(1, dtype=torch.bool, device=self.device)
        return self.agent.is_grasping(self.ball)

    def evaluate(self) -> dict:
        """Grasped (both fingers press on the ball) and the arm static."""
        is_ball_grasped = self.is_ball_grasped()
        is_robot_static = self.arm_qvel.abs().max(dim=-1).values <= self.STATIC_QVEL_THRESH
        return dict(
            success=is_ball_grasped & is_robot_static,
            is_ball_grasped=is_ball_grasped,
            is_robot_static=is_robot_static,
        )

    def gripper_width(self) -> torch.Tensor:
        """(B,) sum of the two finger joint positions (0 … 0.08)."""
        return self.agent.robot.get_qpos()[:, -2:].sum(dim=-1)

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            ball_state = self._ball_state_obs()
            obs["ball_pose"] = ball_state["ball_pose"]
            obs["oracle_info"] = ball_state["oracle_info"]
            obs["is_ball_grasped"] = info["is_ball_grasped"][:, None]
            obs["ball_linear_vel"] = ball_state["ball_linear_vel"]
            obs["ball_angular_vel"] = ball_state["ball_angular_vel"]
            obs["tcp_to_ball_pos"] = self.ball.pose.p - self.agent.tcp.pose.p
            obs["gripper_width"] = self.gripper_width()[:, None]
            obs["relative_velocity"] = ball_state["ball_linear_vel"] - self.agent.tcp.linear_velocity
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reach, enclose, close on and hold the ball; 300 on success (``intercept_grab.md``)."""
        tcp_to_ball = self.ball.pose.p - self.agent.tcp.pose.p
        distance = torch.linalg.norm(tcp_to_ball, dim=-1)
        dx, dy, dz = tcp_to_ball.abs().unbind(-1)
        width = self.gripper_width()
        in_gripper = (dx <= 0.04) & (dy <= 0.04) & (dz <= 0.03) & (distance <= 0.04) & (width >= 0.04)
        very_close = distance <= 0.025
        reward = 10 * (1 - torch.tanh(3 * distance))
        reward = reward + 10 * in_gripper.float()
        reward = reward + torch.where(very_close, 30 * (1 - distance / 0.06), torch.zeros_like(reward))
        width_fit = 90 * torch.exp(-5 * ((width - 0.04).abs() - 0.02).clamp_min(0))
        reward = reward + torch.where(in_gripper, width_fit, torch.zeros_like(reward))
        reward = reward + 90 * (in_gripper & (width <= 0.06)).float()
        reward = reward + 200 * info["is_ball_grasped"].float()
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        # Computed upstream for debugging but not part of the reward.
        ball_speed = torch.linalg.norm(self.ball.linear_velocity, dim=-1)
        ball_spin = torch.linalg.norm(self.ball.angular_velocity, dim=-1)
        self._reward_dict = {
            "tcp_to_obj_dist": distance,
            "is_grasped_reward": info["is_ball_grasped"].float(),
            "ball_in_gripper": in_gripper,
            "dist_tcp_to_ball_x": dx,
            "dist_tcp_to_ball_y": dy,
            "dist_tcp_to_ball_z": dz,
            "current_gripper_width": width,
            "very_close_mask": very_close,
            "static_reward": 1 - torch.tanh(10 * ball_speed + ball_spin),
            "robot_static_reward": info["is_robot_static"].float(),
            "success": info["success"],
        }
        return reward


@register_task(FAMILY, "InterceptGrabSlow-VLA-v0", number=6, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=60)
class InterceptGrabSlowVLAEnv(InterceptGrabVLABaseEnv):
    """InterceptGrab with a launch speed vy ∈ [0.25, 0.50) m/s."""

    VELOCITY_RANGE = (0.25, 0.50)


@register_task(FAMILY, "InterceptGrabMedium-VLA-v0", number=7, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=60)
class InterceptGrabMediumVLAEnv(InterceptGrabVLABaseEnv):
    """InterceptGrab with a launch speed vy ∈ [0.50, 0.75) m/s."""

    VELOCITY_RANGE = (0.50, 0.75)


@register_task(FAMILY, "InterceptGrabFast-VLA-v0", number=8, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=60)
class InterceptGrabFastVLAEnv(InterceptGrabVLABaseEnv):
    """InterceptGrab with a launch speed vy ∈ [0.75, 1.00) m/s."""

    VELOCITY_RANGE = (0.75, 1.00)
