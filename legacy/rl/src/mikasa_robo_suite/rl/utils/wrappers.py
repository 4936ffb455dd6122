"""Old path of the RL wrappers (1.0.0 wheel): the wrapper classes and ``env_info``."""

from mikasa_robo_rl.wrappers import *  # noqa: F403
