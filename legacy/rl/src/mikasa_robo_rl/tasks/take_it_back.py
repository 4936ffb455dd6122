"""TakeItBack-v0: push the cube onto the target, then back to where it started."""

from __future__ import annotations

from mikasa_envs.tasks.take_it_back import TakeItBackVLAEnv

from mikasa_robo_rl.registration import register_rl_task


@register_rl_task("TakeItBack-v0")
class TakeItBackEnv(TakeItBackVLAEnv):
    """TakeItBack (RL): the VLA family with a 180-step horizon (60 in the VLA release)."""


__all__ = ["TakeItBackEnv"]
