"""RotateLenient{Pos,PosNeg}-v0: turn the peg by the target angle (``task_cue``)."""

from __future__ import annotations

import torch
from mikasa_envs.tasks.rotate_lenient import RotateLenientPosNegVLAEnv, RotateLenientPosVLAEnv

from mikasa_robo_rl.registration import register_rl_task


class RotateLenientRL:
    """The RL release's RotateLenient: success counts only once ``elapsed_steps > 5`` (a
    peg that starts near the target is not a free success). (The release normalises the
    dense reward by 25 instead of 60, while a success step still earns 60: the manifest's
    divisor, set at registration.)"""

    SUCCESS_AFTER_STEP = 5

    def _extra_evaluation(self, info: dict) -> torch.Tensor:
        return super()._extra_evaluation(info) & (self.elapsed_steps > self.SUCCESS_AFTER_STEP)


@register_rl_task("RotateLenientPos-v0")
class RotateLenientPosEnv(RotateLenientRL, RotateLenientPosVLAEnv):
    """RotateLenient (RL) with counter-clockwise targets of 0.1 to π/2 rad. Horizon 90."""


@register_rl_task("RotateLenientPosNeg-v0")
class RotateLenientPosNegEnv(RotateLenientRL, RotateLenientPosNegVLAEnv):
    """RotateLenient (RL) with targets of ±(0.1 to π/4) rad. Horizon 90."""


__all__ = ["RotateLenientPosEnv", "RotateLenientPosNegEnv"]
