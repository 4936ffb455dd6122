"""Registration of MIKASA-Robo-VLA envs: horizons come from the task manifest."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from mani_skill.utils.registration import register_env

from mikasa_envs.manifest import get_task

T = TypeVar("T")


def register_task(env_id: str) -> Callable[[T], T]:
    """Register a task class with ManiSkill and Gymnasium under ``env_id``.

    ``max_episode_steps`` is the manifest's horizon, so the two can never disagree.
    """
    return register_env(env_id, max_episode_steps=get_task(env_id).max_episode_steps)
