"""Old path of the RL dataset collector (``python -m ...get_mikasa_robo_datasets``).

Same flags as ``mikasa-rl-collect``; also exports ``env_info`` as the old module did.
"""

from mikasa_robo_rl.collect import *  # noqa: F403
from mikasa_robo_rl.collect import main
from mikasa_robo_rl.wrappers import env_info  # noqa: F401

if __name__ == "__main__":
    raise SystemExit(main())
