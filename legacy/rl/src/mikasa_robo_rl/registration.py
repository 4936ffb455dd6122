"""Registration of the RL envs: each is the env class of its VLA id with the variant's
parameters, as its family declares them (`mikasa_envs.family.RLVariant`)."""

from __future__ import annotations

from mani_skill.utils.registration import register_env
from mikasa_envs.family import RLVariant, declared_rl_variants, env_class

TASKS_MODULE = "mikasa_robo_rl.tasks"
"""The module the RL classes live in (their pickling path)."""


def rl_class_name(env_id: str) -> str:
    """The release's class name of an RL id: ``RememberColor3-v0`` -> ``RememberColor3Env``."""
    return env_id.removesuffix("-v0") + "Env"


def build_rl_class(variant: RLVariant) -> type:
    """The env class of ``variant``: its VLA id's class with the variant's class constants
    (``overrides``) and reward divisor.

    ``NORMALIZED_DENSE_DIVISOR`` is the variant's divisor; it is the success step's dense
    reward except for RotateLenient (25 against 60) and Bunch/Seq/ChainOfColors (100 against
    400), whose success step keeps its family's value.
    """
    changes = ", ".join(f"{k} = {v!r}" for k, v in variant.overrides.items()) or "no other constants"
    doc = (
        f"{variant.group} of the RL release: {variant.vla_env_id} with {changes}; horizon "
        f"{variant.max_episode_steps}, reward divisor {variant.reward_divisor:g}."
    )
    attrs = {
        **variant.overrides,
        "NORMALIZED_DENSE_DIVISOR": variant.reward_divisor,
        "__doc__": doc,
        "__module__": TASKS_MODULE,
    }
    return type(rl_class_name(variant.env_id), (env_class(variant.vla_env_id),), attrs)


def register_rl_tasks() -> dict[str, type]:
    """Build and register (ManiSkill and Gymnasium, at the variant's horizon) the class of
    every declared RL variant; returns class name -> class, in the release's order."""
    classes = {}
    for _family, variant in declared_rl_variants():
        cls = build_rl_class(variant)
        register_env(variant.env_id, max_episode_steps=variant.max_episode_steps)(cls)
        classes[cls.__name__] = cls
    return classes
