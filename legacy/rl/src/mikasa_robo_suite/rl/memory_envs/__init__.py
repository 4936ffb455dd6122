"""Old path of the RL envs (1.0.0 wheel): importing it registers the 32 ids."""

from mikasa_robo_suite.memory_envs import *  # noqa: F403
