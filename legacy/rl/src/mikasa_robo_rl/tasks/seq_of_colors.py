"""SeqOfColors{3,5,7}-v0: remember cubes shown one after another, touch them in that order, press the button."""

from __future__ import annotations

from mikasa_envs.tasks.seq_of_colors import (
    SeqOfColors3VLAEnv,
    SeqOfColors5VLAEnv,
    SeqOfColors7VLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks._timing import FixedColorSequenceTiming


@register_rl_task("SeqOfColors3-v0")
class SeqOfColors3Env(FixedColorSequenceTiming, SeqOfColors3VLAEnv):
    """SeqOfColors (RL), 3 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


@register_rl_task("SeqOfColors5-v0")
class SeqOfColors5Env(FixedColorSequenceTiming, SeqOfColors5VLAEnv):
    """SeqOfColors (RL), 5 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


@register_rl_task("SeqOfColors7-v0")
class SeqOfColors7Env(FixedColorSequenceTiming, SeqOfColors7VLAEnv):
    """SeqOfColors (RL), 7 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


__all__ = ["SeqOfColors3Env", "SeqOfColors5Env", "SeqOfColors7Env"]
