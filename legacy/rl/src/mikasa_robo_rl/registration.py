"""Registration of the RL envs: horizons and reward divisors come from the RL manifest."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from mani_skill.utils.registration import register_env

from mikasa_robo_rl.manifest import get_rl_task

T = TypeVar("T")


def register_rl_task(env_id: str) -> Callable[[T], T]:
    """Register an RL task class with ManiSkill and Gymnasium under ``env_id``.

    ``max_episode_steps`` is the RL manifest's horizon and ``NORMALIZED_DENSE_DIVISOR`` its
    reward divisor, so neither can disagree with it. The divisor is the success step's dense
    reward except for RotateLenient (25 against 60) and Bunch/Seq/ChainOfColors (100 against
    400), whose success step keeps its family's value. (Upstream also declared
    ``asset_download_ids=["ycb"]`` for the shell games; the procedural mug needs no download.)
    """
    task = get_rl_task(env_id)
    register = register_env(env_id, max_episode_steps=task.max_episode_steps)

    def decorate(cls: T) -> T:
        cls.NORMALIZED_DENSE_DIVISOR = task.reward_divisor
        return register(cls)

    return decorate
