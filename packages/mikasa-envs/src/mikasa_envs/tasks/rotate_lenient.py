"""RotateLenient: turn the peg by the instructed angle; where it ends up does not matter."""

from __future__ import annotations

from typing import Any

import torch

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._rotate import MODE_POS, MODE_POS_NEG, RotatePegVLABaseEnv, rotate_chance

FAMILY = TaskFamily(
    "rotate_lenient",
    hidden=(
        "how far the peg has turned: its start heading is seen only at the start, and it "
        "looks the same after a half turn"
    ),
    overlays="rotate",
    wrapper_table_rank=(9, 9),
    chance=rotate_chance,
    rl_variants=(
        RLVariant(
            number=10, env_id="RotateLenientPos-v0", vla_env_id="RotateLenientPos-VLA-v0",
            group="RotateLenient", memory_type="Spatial", max_episode_steps=90,
            reward_divisor=25.0, oracle_info="y_angle_diff", task_cue="target_angle",
            overrides={"SUCCESS_AFTER_STEP": 5},
        ),
        RLVariant(
            number=11, env_id="RotateLenientPosNeg-v0", vla_env_id="RotateLenientPosNeg-VLA-v0",
            group="RotateLenient", memory_type="Spatial", max_episode_steps=90,
            reward_divisor=25.0, oracle_info="y_angle_diff", task_cue="target_angle",
            overrides={"SUCCESS_AFTER_STEP": 5},
        ),
    ),
)



class RotateLenientVLABaseEnv(RotatePegVLABaseEnv):
    """**Task Description:** a blue peg (0.24 x 0.05 x 0.05 m, one colour, so it looks the
    same after a half turn) lies flat on the table. Turn it about the vertical axis by the
    number of degrees the instruction gives (positive = counter-clockwise seen from above),
    relative to the heading it started with, and hold still. Sliding the peg is allowed.

    **Randomizations:** the peg centre (x, y ~ U[−0.1, 0.1)), its start heading (U[0, 2π)),
    the target angle (``MODE``: ``pos_angle`` [0.1, π/2) rad; ``pos_neg_angle`` −[0.1,
    0.44] or +(0.44, π/4] rad); arm joint noise.

    **Success Conditions:** the peg's turn from its start heading is within
    ``angle_threshold`` (0.1 rad) of the target and every arm joint moves slower than
    0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = "Rotate the peg by {angle_deg} degrees to match the target angle."
    DENSE_REWARD_MAX = 60.0

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """exp(−5d) + 15·exp(−1.5|err|)·[d < 0.1] + 5·correct + 2·correct·still; 60 on success."""
        terms = self._reward_inputs(action, info)
        smoothness = terms["smoothness"]
        reaching = torch.exp(-5 * terms["distance"])
        angle_reward = torch.exp(-1.5 * terms["abs_error"])
        reached = terms["distance"] < 0.1
        correct = terms["correct"].float()
        reward = (
            reaching
            - smoothness["smooth_penalty"]
            + 15 * angle_reward * reached
            + 5 * correct
            + 2 * correct * terms["still"]
        )
        reward_dict = dict(
            to_grip_dist=terms["distance"],
            reaching_reward=reaching,
            reached_status=reached,
            y_angle_reward=angle_reward,
            correct_angle=terms["correct"],
            angle_diff_deg=torch.rad2deg(terms["abs_error"]),
            agent_is_static=terms["still"],
            success=terms["success"],
            **smoothness,
        )
        return self._finish_reward(reward, reward_dict)


@register_task(FAMILY, "RotateLenientPos-VLA-v0", number=9, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=60)
class RotateLenientPosVLAEnv(RotateLenientVLABaseEnv):
    """RotateLenient with counter-clockwise targets of 0.1 to π/2 rad."""

    MODE = MODE_POS


@register_task(FAMILY, "RotateLenientPosNeg-VLA-v0", number=10, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=60)
class RotateLenientPosNegVLAEnv(RotateLenientVLABaseEnv):
    """RotateLenient with targets of −0.44 to −0.1 or 0.44 to π/4 rad."""

    MODE = MODE_POS_NEG
