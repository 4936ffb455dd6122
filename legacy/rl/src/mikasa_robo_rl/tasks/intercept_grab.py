"""InterceptGrab{Slow,Medium,Fast}-v0: catch a rolling ball with the gripper and hold still.

The VLA family unchanged but for the horizon (90 steps instead of 60) and the view: the ball
stays in view every frame, as published (``BallInView``).
"""

from __future__ import annotations

from mikasa_envs.tasks.intercept_grab import (
    InterceptGrabFastVLAEnv,
    InterceptGrabMediumVLAEnv,
    InterceptGrabSlowVLAEnv,
)

from mikasa_robo_rl.registration import register_rl_task
from mikasa_robo_rl.tasks.intercept import BallInView


@register_rl_task("InterceptGrabSlow-v0")
class InterceptGrabSlowEnv(BallInView, InterceptGrabSlowVLAEnv):
    """InterceptGrab (RL), ball speeds 0.25-0.5 m/s. Horizon 90, divisor 300."""


@register_rl_task("InterceptGrabMedium-v0")
class InterceptGrabMediumEnv(BallInView, InterceptGrabMediumVLAEnv):
    """InterceptGrab (RL), ball speeds 0.5-0.75 m/s. Horizon 90, divisor 300."""


@register_rl_task("InterceptGrabFast-v0")
class InterceptGrabFastEnv(BallInView, InterceptGrabFastVLAEnv):
    """InterceptGrab (RL), ball speeds 0.75-1 m/s. Horizon 90, divisor 300."""


__all__ = ["InterceptGrabSlowEnv", "InterceptGrabMediumEnv", "InterceptGrabFastEnv"]
