"""Intercept{Slow,Medium,Fast}-v0: deflect a rolling ball over the target.

The VLA family unchanged but for the horizon (90 steps instead of 60): the ball's start and
velocity are the hidden state; no cue phase.
"""

from __future__ import annotations

from mikasa_envs.tasks.intercept import (
    InterceptFastVLAEnv,
    InterceptMediumVLAEnv,
    InterceptSlowVLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task


@register_rl_task("InterceptSlow-v0")
class InterceptSlowEnv(InterceptSlowVLAEnv):
    """Intercept (RL) with ball speeds of 0.25-0.5 m/s. Horizon 90, divisor 30."""


@register_rl_task("InterceptMedium-v0")
class InterceptMediumEnv(InterceptMediumVLAEnv):
    """Intercept (RL) with ball speeds of 0.5-0.75 m/s. Horizon 90, divisor 30."""


@register_rl_task("InterceptFast-v0")
class InterceptFastEnv(InterceptFastVLAEnv):
    """Intercept (RL) with ball speeds of 0.75-1 m/s. Horizon 90, divisor 30."""


__all__ = ["InterceptSlowEnv", "InterceptMediumEnv", "InterceptFastEnv"]
