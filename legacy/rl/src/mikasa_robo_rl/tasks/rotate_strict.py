"""RotateStrict{Pos,PosNeg}-v0: turn the peg by the target angle and keep it in place.

The VLA family unchanged but for the horizon (90, as the VLA release).
"""

from __future__ import annotations

from mikasa_envs.tasks.rotate_strict import RotateStrictPosNegVLAEnv, RotateStrictPosVLAEnv

from mikasa_robo_rl.registration import register_rl_task


@register_rl_task("RotateStrictPos-v0")
class RotateStrictPosEnv(RotateStrictPosVLAEnv):
    """RotateStrict (RL), counter-clockwise targets. Horizon 90, divisor 100."""


@register_rl_task("RotateStrictPosNeg-v0")
class RotateStrictPosNegEnv(RotateStrictPosNegVLAEnv):
    """RotateStrict (RL), targets of either sign. Horizon 90, divisor 100."""


__all__ = ["RotateStrictPosEnv", "RotateStrictPosNegEnv"]
