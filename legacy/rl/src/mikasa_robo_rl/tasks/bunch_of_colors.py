"""BunchOfColors{3,5,7}-v0: remember which cubes were shown together, touch all of them, press the button."""

from __future__ import annotations

from mikasa_envs.tasks.bunch_of_colors import (
    BunchOfColors3VLAEnv,
    BunchOfColors5VLAEnv,
    BunchOfColors7VLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks._timing import FixedColorSequenceTiming


@register_rl_task("BunchOfColors3-v0")
class BunchOfColors3Env(FixedColorSequenceTiming, BunchOfColors3VLAEnv):
    """BunchOfColors (RL), 3 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


@register_rl_task("BunchOfColors5-v0")
class BunchOfColors5Env(FixedColorSequenceTiming, BunchOfColors5VLAEnv):
    """BunchOfColors (RL), 5 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


@register_rl_task("BunchOfColors7-v0")
class BunchOfColors7Env(FixedColorSequenceTiming, BunchOfColors7VLAEnv):
    """BunchOfColors (RL), 7 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


__all__ = ["BunchOfColors3Env", "BunchOfColors5Env", "BunchOfColors7Env"]
