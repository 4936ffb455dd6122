"""ShellGameShuffleColorLampTouch: remember the colour under each cup, follow all three cups through a
shuffle, then touch the cup the lamp's colour names."""

from __future__ import annotations

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._shell_game import (
    SHUFFLE_TASK_STATE,
    ColorLampShellGameVLABaseEnv,
    shell_game_chance,
)

FAMILY = TaskFamily(
    "shell_game_shuffle_color_lamp_touch",
    hidden=(
        "where each coloured ball lay: in view during the cue, tracked through the shuffle; "
        "the lamp's colour comes only after it"
    ),
    overlays="shell_game",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(3, 6),
    chance=shell_game_chance,
)



class ShellGameShuffleColorLampTouchVLABaseEnv(ColorLampShellGameVLABaseEnv):
    """**Task Description:** a red, a green and a blue ball lie on the table at three places
    (always red Left, green Center, blue Right); then the balls disappear and three
    upside-down mugs appear over the three places and swap places several times. After the
    shuffle a lamp behind them lights up in one of the three colours: touch the mug that
    started over the ball of that colour and hold still. The colour is shown only after the
    shuffle, so all three mugs must be tracked.

    **Randomizations:** the lamp colour; the slot row's position (±0.1 m in x and y); the
    cue length, shuffle length and number of swaps, and which slots each swap exchanges;
    arm joint noise.

    **Success Conditions:** in the action phase (after the shuffle), the TCP is within
    0.08 m of the slot where the answer mug ended up and every arm joint moves slower than
    0.2 rad/s. Success does not end the episode.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe which color is under each cup, track the cups as they shuffle, "
        "then touch the cup matching the lamp color."
    )
    SHUFFLE_STEPS = (20, 35)
    NUM_SWAPS = (2, 4)
    TASK_STATE = SHUFFLE_TASK_STATE
    # Upstream declares it but never uses it (the lamp is the colour-switch lamp).
    LAMP_RADIUS = 0.018


@register_task(FAMILY, "ShellGameShuffleColorLampTouch-VLA-v0", number=33, split="short",
               data_source="PPO", memory_type="Tracking", max_episode_steps=60)
class ShellGameShuffleColorLampTouchVLAEnv(ShellGameShuffleColorLampTouchVLABaseEnv):
    """ShellGameShuffleColorLampTouch: 1-5 cue steps, a 20-35 step shuffle of 2-4 swaps."""

    CUE_PHASE_STEPS = (1, 5)


@register_task(FAMILY, "ShellGameShuffleColorLampTouch-Long-VLA-v0", number=70, split="medium",
               data_source="MP", memory_type="Tracking", max_episode_steps=600)
class ShellGameShuffleColorLampTouchLongVLAEnv(ShellGameShuffleColorLampTouchVLABaseEnv):
    """ShellGameShuffleColorLampTouch: 10-100 cue steps, a 100-400 step shuffle of 5-15 swaps."""

    CUE_PHASE_STEPS = (10, 100)
    SHUFFLE_STEPS = (100, 400)
    NUM_SWAPS = (5, 15)
