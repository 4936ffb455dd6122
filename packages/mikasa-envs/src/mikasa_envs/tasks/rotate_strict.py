"""RotateStrict: turn the peg by the instructed angle while its centre stays in place."""

from __future__ import annotations

from typing import Any, ClassVar

import torch

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._rotate import MODE_POS, MODE_POS_NEG, RotatePegVLABaseEnv, rotate_chance

FAMILY = TaskFamily(
    "rotate_strict",
    hidden=(
        "how far the peg has turned: its start heading is seen only at the start, and it "
        "looks the same after a half turn"
    ),
    overlays="rotate",
    wrapper_table_rank=(10, 10),
    chance=rotate_chance,
    rl_variants=(
        RLVariant(
            number=12, env_id="RotateStrictPos-v0", vla_env_id="RotateStrictPos-VLA-v0",
            group="RotateStrict", memory_type="Object", max_episode_steps=90, reward_divisor=100.0,
            oracle_info="y_angle_diff", task_cue="target_angle",
        ),
        RLVariant(
            number=13, env_id="RotateStrictPosNeg-v0", vla_env_id="RotateStrictPosNeg-VLA-v0",
            group="RotateStrict", memory_type="Object", max_episode_steps=90, reward_divisor=100.0,
            oracle_info="y_angle_diff", task_cue="target_angle",
        ),
    ),
)



class RotateStrictVLABaseEnv(RotatePegVLABaseEnv):
    """**Task Description:** as RotateLenient: turn the flat blue peg about the vertical axis
    by the instructed number of degrees (positive = counter-clockwise seen from above),
    relative to its start heading, and hold still; in addition the peg's centre must stay
    within 5 cm (per axis) of where it started.

    **Randomizations:** the peg centre (x, y ~ U[−0.1, 0.1)), its start heading (U[0, 2π)),
    the target angle (``MODE``: ``pos_angle`` [0.1, π/2) rad; ``pos_neg_angle`` −[0.1,
    0.44] or +(0.44, π/4] rad); arm joint noise.

    **Success Conditions:** the turn is within ``angle_threshold`` (0.1 rad) of the target,
    |x − x0| < 0.05 and |y − y0| < 0.05 for the peg centre (a square, not a circle), and
    every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = (
        "Rotate the peg by {angle_deg} degrees to match the target angle while keeping the center of the peg in place."
    )
    DENSE_REWARD_MAX = 100.0
    # Per-axis tolerance on the peg centre's displacement.
    POSITION_TOLERANCE: ClassVar[float] = 0.05

    def _extra_evaluation(self, info: dict) -> torch.Tensor:
        offset = self.peg.pose.p[:, :2] - self.initial_peg_position[:, :2]
        info["x_pos_error"] = offset[:, 0]
        info["y_pos_error"] = offset[:, 1]
        return (offset.abs() < self.POSITION_TOLERANCE).all(dim=-1)

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """0.5·exp(−3d), then gated: position (d < 0.04), angle (+ centre in place), correct,
        still; 100 on success."""
        terms = self._reward_inputs(action, info)
        reaching = torch.exp(-3 * terms["distance"])
        reached = terms["distance"] < 0.04
        x_error, y_error = info["x_pos_error"], info["y_pos_error"]
        x_reward, y_reward = torch.exp(-5 * x_error.abs()), torch.exp(-5 * y_error.abs())
        angle_reward = torch.exp(-terms["abs_error"])
        position_ok = (x_error.abs() < self.POSITION_TOLERANCE) & (y_error.abs() < self.POSITION_TOLERANCE)
        placed = reached & position_ok
        correct = placed & terms["correct"]
        reward = 0.5 * reaching - terms["smoothness"]["smooth_penalty"]
        reward = reward + reached * (5 * x_reward + 5 * y_reward)
        reward = reward + placed * 35 * angle_reward + correct * 10.0
        reward = reward + (correct & terms["still"]) * 5.0
        reward_dict = dict(
            to_grip_dist=terms["distance"],
            reaching_reward=reaching,
            reached_status=reached,
            y_angle_reward=angle_reward,
            correct_angle=terms["correct"],
            y_angle_diff_deg=torch.rad2deg(terms["abs_error"]),
            agent_is_static=terms["still"],
            success=terms["success"],
            x_pos_error=x_error,
            y_pos_error=y_error,
            x_pos_reward=x_reward,
            y_pos_reward=y_reward,
            position_ok=position_ok,
            **terms["smoothness"],
        )
        return self._finish_reward(reward, reward_dict)


@register_task(FAMILY, "RotateStrictPos-VLA-v0", number=11, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=90)
class RotateStrictPosVLAEnv(RotateStrictVLABaseEnv):
    """RotateStrict with counter-clockwise targets of 0.1 to π/2 rad."""

    MODE = MODE_POS


@register_task(FAMILY, "RotateStrictPosNeg-VLA-v0", number=12, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=90)
class RotateStrictPosNegVLAEnv(RotateStrictVLABaseEnv):
    """RotateStrict with targets of −0.44 to −0.1 or 0.44 to π/4 rad."""

    MODE = MODE_POS_NEG
