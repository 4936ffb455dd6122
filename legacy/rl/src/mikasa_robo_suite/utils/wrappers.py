"""Old path of the RL wrappers (0.0.5): the wrapper classes and ``env_info``."""

from mikasa_robo_rl.wrappers import *  # noqa: F403
