"""The manifest of the 32 RL tasks (the original MIKASA-Robo RL release).

Each MIKASA-Robo-VLA family declares its RL variants with its env module
(`mikasa_envs.family.RLVariant`); this module lists them: the id, its group and the family it
is built on, the RL paper's memory type (4-type taxonomy), the horizon, the privileged
``oracle_info`` and ``task_cue`` names of the paper's Table 1, the divisor of the normalised
dense reward and the VLA env it is a variant of.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from functools import cache

from mikasa_envs.family import declared_rl_variants
from mikasa_envs.manifest import UnknownEnvIdError, get_task, list_tasks

MEMORY_TYPES: tuple[str, ...] = ("Object", "Spatial", "Sequential", "Capacity")


@dataclass(frozen=True)
class RLTaskSpec:
    """One RL manifest row; ``task_cue`` is ``None`` for tasks without a cue vector."""

    env_id: str
    group: str
    family: str
    memory_type: str
    max_episode_steps: int
    oracle_info: str
    task_cue: str | None
    reward_divisor: float
    vla_env_id: str


@cache
def _all_tasks() -> tuple[RLTaskSpec, ...]:
    import mikasa_envs.tasks  # noqa: F401  (the families declare the variants)

    return tuple(
        RLTaskSpec(
            env_id=variant.env_id,
            group=variant.group,
            family=family.name,
            memory_type=variant.memory_type,
            max_episode_steps=variant.max_episode_steps,
            oracle_info=variant.oracle_info,
            task_cue=variant.task_cue,
            reward_divisor=variant.reward_divisor,
            vla_env_id=variant.vla_env_id,
        )
        for family, variant in declared_rl_variants()
    )


@cache
def _by_id() -> dict[str, RLTaskSpec]:
    return {t.env_id: t for t in _all_tasks()}


def rl_env_ids() -> tuple[str, ...]:
    """The 32 RL env ids in the release's order."""
    return tuple(t.env_id for t in _all_tasks())


def groups() -> tuple[str, ...]:
    """The 12 task groups, in manifest order."""
    return tuple(dict.fromkeys(t.group for t in _all_tasks()))


def list_rl_tasks(group: str | None = None, memory_type: str | None = None) -> list[RLTaskSpec]:
    """RL tasks in manifest order, filtered by ``group`` and/or ``memory_type``."""
    for name, value, accepted in (("group", group, groups()), ("memory type", memory_type, MEMORY_TYPES)):
        if value is not None and value not in accepted:
            raise ValueError(f"unknown {name} {value!r}; accepted values: {', '.join(accepted)}")
    return [
        t
        for t in _all_tasks()
        if (group is None or t.group == group) and (memory_type is None or t.memory_type == memory_type)
    ]


def unknown_rl_env_message(env_id: str) -> str:
    """The release's "Unknown environment" message, naming the closest RL ids."""
    close = difflib.get_close_matches(str(env_id), rl_env_ids(), n=3, cutoff=0.6)
    hint = f" Did you mean: {', '.join(close)}?" if close else ""
    return (
        f"Unknown environment: {env_id!r}.{hint} The RL release has {len(rl_env_ids())} ids "
        "(mikasa_robo_rl.rl_env_ids()); VLA ids (<Name>-VLA-v0) belong to mikasa_envs."
    )


def get_rl_task(env_id: str) -> RLTaskSpec:
    """The manifest row of ``env_id``; ``UnknownEnvIdError`` (a ValueError) naming close
    matches if unknown."""
    try:
        return _by_id()[env_id]
    except (KeyError, TypeError):
        raise UnknownEnvIdError(unknown_rl_env_message(env_id)) from None


def trainable_horizon(env_id: str) -> int:
    """The horizon of an id the PPO trainers accept: one of the 32 RL ids or any
    ``mikasa_envs`` (VLA) id. ``UnknownEnvIdError`` naming close ids of both otherwise."""
    if env_id in _by_id():
        return _by_id()[env_id].max_episode_steps
    try:
        return get_task(env_id).max_episode_steps
    except UnknownEnvIdError:
        known = [*rl_env_ids(), *(t.env_id for t in list_tasks())]
        close = difflib.get_close_matches(str(env_id), known, n=3, cutoff=0.6)
        hint = f" Did you mean: {', '.join(close)}?" if close else ""
        raise UnknownEnvIdError(
            f"Unknown environment: {env_id!r}.{hint} The trainers take the {len(rl_env_ids())} RL ids "
            "(mikasa_robo_rl.rl_env_ids()) and the VLA ids (mikasa_envs.list_tasks())."
        ) from None
