"""MIKASA-Robo wrappers: the canonical VLA wrapper chain, its wrappers and render overlays.

Typical use::

    import gymnasium as gym
    import mikasa_envs  # registers the tasks
    from mikasa_wrappers import apply_mikasa_vla_wrappers

    env = gym.make("RememberColor3-VLA-v0", obs_mode="rgb", control_mode="pd_ee_delta_pose")
    env = apply_mikasa_vla_wrappers(env)
    obs, info = env.reset(seed=0)  # obs["proprio"]: (B, 7), obs["rgb"]: (B, 128, 128, 6)
"""

# Each module's __all__ is its public API; the package re-exports all three.
from . import apply_wrappers, overlays, wrappers
from .apply_wrappers import *  # noqa: F403
from .overlays import *  # noqa: F403
from .wrappers import *  # noqa: F403

__version__ = "0.2.0"

__all__ = [*apply_wrappers.__all__, *wrappers.__all__, *overlays.__all__, "__version__"]
