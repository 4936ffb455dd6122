"""ShellGameTouch: see where the ball is, then touch the mug that hides it."""

from __future__ import annotations

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._shell_game import (
    RL_SHELL_GAME_TIMING,
    HiddenBallShellGameVLABaseEnv,
    TouchMugMixin,
    shell_game_chance,
)

FAMILY = TaskFamily(
    "shell_game_touch",
    hidden="which mug hides the ball: the ball is in view during the cue, under a mug from then on",
    overlays="shell_game",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(0, 0),
    chance=shell_game_chance,
    rl_variants=(
        RLVariant(
            number=1, env_id="ShellGameTouch-v0", vla_env_id="ShellGameTouch-VLA-v0",
            group="ShellGame", memory_type="Object", max_episode_steps=90, reward_divisor=3.0,
            oracle_info="cup_with_ball_number", overrides=RL_SHELL_GAME_TIMING,
        ),
    ),
)



@register_task(FAMILY, "ShellGameTouch-VLA-v0", number=1, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=30)
class ShellGameTouchVLAEnv(TouchMugMixin, HiddenBallShellGameVLABaseEnv):
    """**Task Description:** a red ball lies on the table at one of three places; then three
    upside-down mugs appear over the three places and one of them hides the ball. Touch
    that mug (TCP within 8 cm of its centre) and hold still, without moving any mug more
    than 5 cm.

    **Randomizations:** the ball's slot (Left / Center / Right); the slot row's position
    (±0.1 m in x and y); the cue length (1-5 steps); arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 0.08 m of the ball mug's
    centre, every arm joint moves slower than 0.2 rad/s, and no mug is more than 0.05 m (xy)
    from its slot. The episode terminates at the first success.
    """

    LANGUAGE_INSTRUCTION = "Observe which cup hides the ball, wait, then touch that cup."
