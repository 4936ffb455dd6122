"""ShellGameColorLampTouch: see which colour lies at each place, then touch the cup the lamp's colour names."""

from __future__ import annotations

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._shell_game import ColorLampShellGameVLABaseEnv, shell_game_chance

FAMILY = TaskFamily(
    "shell_game_color_lamp_touch",
    hidden=(
        "which coloured ball lay at which place: in view during the cue, under the mugs when "
        "the lamp lights"
    ),
    overlays="shell_game",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(4, 4),
    chance=shell_game_chance,
)



@register_task(FAMILY, "ShellGameColorLampTouch-VLA-v0", number=34, split="short",
               data_source="PPO", memory_type="Spatial", max_episode_steps=30)
class ShellGameColorLampTouchVLAEnv(ColorLampShellGameVLABaseEnv):
    """**Task Description:** a red, a green and a blue ball lie on the table at three places
    (always red Left, green Center, blue Right); then the balls disappear, three
    upside-down mugs stand over the three places and a lamp behind them lights up in one of
    the three colours. Touch the mug over the ball of the lamp's colour and hold still.

    **Randomizations:** the lamp colour; the slot row's position (±0.1 m in x and y); the
    cue length (1-5 steps); arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 0.08 m of the answer
    slot's centre and every arm joint moves slower than 0.2 rad/s. Success does not end the
    episode.
    """

    LANGUAGE_INSTRUCTION = "Observe which color is under each cup, then touch the cup matching the lamp color."
