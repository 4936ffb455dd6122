"""Registration of MIKASA-Robo-VLA envs: each env id with its manifest row."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from mani_skill.utils.registration import register_env

from mikasa_envs.family import TaskFamily, TaskSpec, add_task

T = TypeVar("T", bound=type)


def register_task(
    family: TaskFamily,
    env_id: str,
    *,
    memory_type: str,
    max_episode_steps: int,
    split: str | None = None,
    data_source: str | None = None,
    number: int | None = None,
) -> Callable[[T], T]:
    """Register a task class of ``family`` with ManiSkill and Gymnasium under ``env_id``, and
    its manifest row.

    ``split`` (``short`` / ``medium`` / ``long``) puts the id in the benchmark; without it
    the id is a registered variant outside every split. ``number`` is the row's place in
    the published manifest. The language instruction is the class's
    ``LANGUAGE_INSTRUCTION``; ``max_episode_steps`` is both the row's and the registered
    horizon, so the two can never disagree.
    """

    def decorate(cls: T) -> T:
        spec = TaskSpec(
            env_id=env_id,
            family=family.name,
            split=split,
            memory_type=memory_type,
            max_episode_steps=max_episode_steps,
            data_source=data_source,
            language_instruction=cls.LANGUAGE_INSTRUCTION,
            canonical=split is not None,
        )
        add_task(family, spec, cls, number)
        return register_env(env_id, max_episode_steps=max_episode_steps)(cls)

    return decorate
