"""RememberColor{3,5,9}-v0: remember one cube's colour, then touch the cube of that colour."""

from __future__ import annotations

from mikasa_envs.tasks.remember_color import (
    RememberColor3VLAEnv,
    RememberColor5VLAEnv,
    RememberColor9VLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks._timing import FixedCueAndDelay


@register_rl_task("RememberColor3-v0")
class RememberColor3Env(FixedCueAndDelay, RememberColor3VLAEnv):
    """RememberColor (RL), 3: 5-step cue, 5-step delay, horizon 60, divisor 3."""


@register_rl_task("RememberColor5-v0")
class RememberColor5Env(FixedCueAndDelay, RememberColor5VLAEnv):
    """RememberColor (RL), 5: 5-step cue, 5-step delay, horizon 60, divisor 3."""


@register_rl_task("RememberColor9-v0")
class RememberColor9Env(FixedCueAndDelay, RememberColor9VLAEnv):
    """RememberColor (RL), 9: 5-step cue, 5-step delay, horizon 60, divisor 3."""


__all__ = ["RememberColor3Env", "RememberColor5Env", "RememberColor9Env"]
