"""Old path of the RL envs (0.0.5): importing it registers the 32 ids."""

from mikasa_robo_rl import *  # noqa: F403
from mikasa_robo_rl.tasks.bunch_of_colors import *  # noqa: F403
from mikasa_robo_rl.tasks.chain_of_colors import *  # noqa: F403
from mikasa_robo_rl.tasks.intercept import *  # noqa: F403
from mikasa_robo_rl.tasks.intercept_grab import *  # noqa: F403
from mikasa_robo_rl.tasks.remember_color import *  # noqa: F403
from mikasa_robo_rl.tasks.remember_shape import *  # noqa: F403
from mikasa_robo_rl.tasks.remember_shape_and_color import *  # noqa: F403
from mikasa_robo_rl.tasks.rotate_lenient import *  # noqa: F403
from mikasa_robo_rl.tasks.rotate_strict import *  # noqa: F403
from mikasa_robo_rl.tasks.seq_of_colors import *  # noqa: F403
from mikasa_robo_rl.tasks.shell_game import *  # noqa: F403
from mikasa_robo_rl.tasks.take_it_back import *  # noqa: F403

# Upstream implemented RememberShape5-v0 by a class named RememberShape6Env.
RememberShape6Env = RememberShape5Env  # noqa: F405
