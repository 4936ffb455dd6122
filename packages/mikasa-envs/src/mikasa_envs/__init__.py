"""MIKASA-Robo-VLA environments: memory-intensive manipulation tasks on ManiSkill3.

Importing the package registers every env id with ManiSkill and Gymnasium::

    import gymnasium as gym
    import mikasa_envs

    env = gym.make("RememberColor3-VLA-v0", obs_mode="rgb", control_mode="pd_ee_delta_pose")
"""

from mikasa_envs import tasks  # noqa: F401  (registers the envs)
from mikasa_envs.manifest import (
    TaskSpec,
    canonical_env_ids,
    families,
    get_task,
    list_tasks,
)

__version__ = "0.1.0"

__all__ = ["TaskSpec", "canonical_env_ids", "families", "get_task", "list_tasks", "__version__"]
