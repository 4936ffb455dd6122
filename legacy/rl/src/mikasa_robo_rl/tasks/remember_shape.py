"""RememberShape{3,5,9}-v0: remember one object's shape, then touch the object of that shape."""

from __future__ import annotations

from mikasa_envs.tasks.remember_shape import (
    RememberShape3VLAEnv,
    RememberShape5VLAEnv,
    RememberShape9VLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks._timing import FixedCueAndDelay


@register_rl_task("RememberShape3-v0")
class RememberShape3Env(FixedCueAndDelay, RememberShape3VLAEnv):
    """RememberShape (RL), 3: 5-step cue, 5-step delay, horizon 60, divisor 3."""


@register_rl_task("RememberShape5-v0")
class RememberShape5Env(FixedCueAndDelay, RememberShape5VLAEnv):
    """RememberShape (RL), 5: 5-step cue, 5-step delay, horizon 60, divisor 3."""


@register_rl_task("RememberShape9-v0")
class RememberShape9Env(FixedCueAndDelay, RememberShape9VLAEnv):
    """RememberShape (RL), 9: 5-step cue, 5-step delay, horizon 60, divisor 3."""


__all__ = ["RememberShape3Env", "RememberShape5Env", "RememberShape9Env"]
