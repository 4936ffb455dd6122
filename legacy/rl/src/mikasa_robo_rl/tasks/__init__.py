"""The 32 RL tasks; importing this package registers every id.

Each RL task is the env class of its MIKASA-Robo-VLA id with the release's parameters (fixed
phase timing, the ball kept in view, the reward divisor), as the family declares them in its
env module (``TaskFamily.rl_variants``): the scene, randomisation, success and reward code is
the VLA family's. The classes carry the release's names (``RememberColor3Env``, ...).
"""

import mikasa_envs.tasks  # noqa: F401  (the families declare the variants)

from mikasa_robo_rl.registration import register_rl_tasks

RL_CLASSES: dict[str, type] = register_rl_tasks()
"""Class name -> env class of the 32 RL ids, in the release's order."""

globals().update(RL_CLASSES)

__all__ = ["RL_CLASSES", *RL_CLASSES]
