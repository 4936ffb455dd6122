"""Intercept{Slow,Medium,Fast}-v0: deflect a rolling ball over the target.

The VLA family unchanged but for the horizon (90 steps instead of 60) and the view: as
published, the ball stays in view every frame (the VLA ids hide it after its first 10 frames
until the robot touches it; ``gym.make(id, ball_shown_steps=10)`` does that here too). The
ball's start and velocity are the hidden state; no cue phase.
"""

from __future__ import annotations

from mikasa_envs.tasks.intercept import (
    InterceptFastVLAEnv,
    InterceptMediumVLAEnv,
    InterceptSlowVLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task


class BallInView:
    """The release's view: the cameras show the ball in every frame (``BALL_SHOWN_STEPS``)."""

    BALL_SHOWN_STEPS = None


@register_rl_task("InterceptSlow-v0")
class InterceptSlowEnv(BallInView, InterceptSlowVLAEnv):
    """Intercept (RL) with ball speeds of 0.25-0.5 m/s. Horizon 90, divisor 30."""


@register_rl_task("InterceptMedium-v0")
class InterceptMediumEnv(BallInView, InterceptMediumVLAEnv):
    """Intercept (RL) with ball speeds of 0.5-0.75 m/s. Horizon 90, divisor 30."""


@register_rl_task("InterceptFast-v0")
class InterceptFastEnv(BallInView, InterceptFastVLAEnv):
    """Intercept (RL) with ball speeds of 0.75-1 m/s. Horizon 90, divisor 30."""


__all__ = ["BallInView", "InterceptSlowEnv", "InterceptMediumEnv", "InterceptFastEnv"]
