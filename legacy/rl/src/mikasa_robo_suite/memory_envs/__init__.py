"""Old path of the RL envs (0.0.5): importing it registers the 32 ids."""

from mikasa_robo_rl import *  # noqa: F403
from mikasa_robo_rl.tasks import *  # noqa: F403

# Upstream implemented RememberShape5-v0 by a class named RememberShape6Env.
RememberShape6Env = RememberShape5Env  # noqa: F405
