"""ChainOfColors{3,5,7}-v0: touch the cubes in the order they were shown, then press the button."""

from __future__ import annotations

from mikasa_envs.tasks.chain_of_colors import (
    ChainOfColors3VLAEnv,
    ChainOfColors5VLAEnv,
    ChainOfColors7VLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks._timing import FixedColorSequenceTiming


@register_rl_task("ChainOfColors3-v0")
class ChainOfColors3Env(FixedColorSequenceTiming, ChainOfColors3VLAEnv):
    """ChainOfColors (RL), 3 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


@register_rl_task("ChainOfColors5-v0")
class ChainOfColors5Env(FixedColorSequenceTiming, ChainOfColors5VLAEnv):
    """ChainOfColors (RL), 5 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


@register_rl_task("ChainOfColors7-v0")
class ChainOfColors7Env(FixedColorSequenceTiming, ChainOfColors7VLAEnv):
    """ChainOfColors (RL), 7 of 9 cubes: 5-step cues, 5-step delay, horizon 120, divisor 100."""


__all__ = ["ChainOfColors3Env", "ChainOfColors5Env", "ChainOfColors7Env"]
