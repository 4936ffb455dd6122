"""MIKASA-Robo RL: the original 32-task RL release, on the MIKASA-Robo-VLA task families.

Importing the package registers the 32 ids (``ShellGameTouch-v0`` ... ``ChainOfColors7-v0``)
with ManiSkill and Gymnasium::

    import gymnasium as gym
    import mikasa_robo_rl
    from mikasa_robo_rl.wrappers import env_info

    env = gym.make("RememberColor3-v0", obs_mode="state", control_mode="pd_joint_delta_pos",
                   reward_mode="normalized_dense")
    wrappers, timeout = env_info("RememberColor3-v0")
    for wrapper, kwargs in wrappers:
        env = wrapper(env, **kwargs)

The old import paths (``mikasa_robo_suite.memory_envs``, ``mikasa_robo_suite.rl.memory_envs``,
``mikasa_robo_suite.utils.wrappers``, ...) are aliases of this package.
"""

from typing import Any

import gymnasium as gym

from mikasa_robo_rl import tasks  # noqa: F401  (registers the envs)
from mikasa_robo_rl.manifest import (
    MEMORY_TYPES,
    RLTaskSpec,
    get_rl_task,
    groups,
    list_rl_tasks,
    rl_env_ids,
)

__version__ = "0.2.0"


def make(env_id: str, **kwargs: Any) -> gym.Env:
    """``gym.make`` for the RL ids, with an error that names close matches for a typo."""
    get_rl_task(env_id)
    return gym.make(env_id, **kwargs)


__all__ = [
    "MEMORY_TYPES",
    "RLTaskSpec",
    "__version__",
    "get_rl_task",
    "groups",
    "list_rl_tasks",
    "make",
    "rl_env_ids",
]
