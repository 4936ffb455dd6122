"""Registration of the RL envs: horizons come from the RL manifest."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from mani_skill.utils.registration import register_env

from mikasa_robo_rl.manifest import get_rl_task

T = TypeVar("T")


def register_rl_task(env_id: str) -> Callable[[T], T]:
    """Register an RL task class with ManiSkill and Gymnasium under ``env_id``.

    ``max_episode_steps`` is the RL manifest's horizon, so the two can never disagree.
    (Upstream also declared ``asset_download_ids=["ycb"]`` for the shell games; the
    procedural mug needs no download.)
    """
    return register_env(env_id, max_episode_steps=get_rl_task(env_id).max_episode_steps)
