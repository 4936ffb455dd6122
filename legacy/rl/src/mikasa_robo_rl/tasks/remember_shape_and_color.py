"""RememberShapeAndColor{3x2,3x3,5x3}-v0: remember a (shape, colour) pair, then touch the matching object."""

from __future__ import annotations

from mikasa_envs.tasks.remember_shape_and_color import (
    RememberShapeAndColor3x2VLAEnv,
    RememberShapeAndColor3x3VLAEnv,
    RememberShapeAndColor5x3VLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks._timing import FixedCueAndDelay


@register_rl_task("RememberShapeAndColor3x2-v0")
class RememberShapeAndColor3x2Env(FixedCueAndDelay, RememberShapeAndColor3x2VLAEnv):
    """RememberShapeAndColor (RL), 3x2: 5-step cue, 5-step delay, horizon 60, divisor 3."""


@register_rl_task("RememberShapeAndColor3x3-v0")
class RememberShapeAndColor3x3Env(FixedCueAndDelay, RememberShapeAndColor3x3VLAEnv):
    """RememberShapeAndColor (RL), 3x3: 5-step cue, 5-step delay, horizon 60, divisor 3."""


@register_rl_task("RememberShapeAndColor5x3-v0")
class RememberShapeAndColor5x3Env(FixedCueAndDelay, RememberShapeAndColor5x3VLAEnv):
    """RememberShapeAndColor (RL), 5x3: 5-step cue, 5-step delay, horizon 60, divisor 3."""


__all__ = ["RememberShapeAndColor3x2Env", "RememberShapeAndColor3x3Env", "RememberShapeAndColor5x3Env"]
