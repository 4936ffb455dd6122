"""MIKASA-Robo-VLA environments: memory-intensive manipulation tasks on ManiSkill3.

Importing the package registers every env id with ManiSkill and Gymnasium::

    import gymnasium as gym
    import mikasa_envs

    env = gym.make("RememberColor3-VLA-v0", obs_mode="rgb", control_mode="pd_ee_delta_pose")
"""

from typing import Any

import gymnasium as gym

from mikasa_envs import tasks  # noqa: F401  (registers the envs)
from mikasa_envs.manifest import (
    TaskSpec,
    UnknownEnvIdError,
    canonical_env_ids,
    families,
    get_task,
    list_tasks,
    unknown_env_id_message,
)

__version__ = "0.2.0"


def registered_env_ids() -> list[str]:
    """Every MIKASA-Robo-VLA env id registered in this installation, in manifest order."""
    return [t.env_id for t in list_tasks(include_extra=True) if t.env_id in gym.registry]


def make(env_id: str, **kwargs: Any) -> gym.Env:
    """``gym.make`` for MIKASA-Robo ids, with an error that names close matches for a typo."""
    if env_id not in gym.registry or env_id not in registered_env_ids():
        raise UnknownEnvIdError(unknown_env_id_message(env_id, registered_env_ids()))
    return gym.make(env_id, **kwargs)


__all__ = [
    "TaskSpec",
    "UnknownEnvIdError",
    "__version__",
    "canonical_env_ids",
    "families",
    "get_task",
    "list_tasks",
    "make",
    "registered_env_ids",
]
