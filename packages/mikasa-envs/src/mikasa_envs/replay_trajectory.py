"""ManiSkill's trajectory replay for MIKASA-Robo envs.

``python -m mikasa_envs.replay_trajectory --traj-path X.h5 --use-env-states`` takes exactly
the arguments of ``python -m mani_skill.trajectory.replay_trajectory`` and runs that tool,
unchanged. ManiSkill's own entry point makes the env with ``gym.make(env_id)`` in an
interpreter that has imported only ``mani_skill.envs``, where no MIKASA id is registered
(it stops with "No registered env with id: ..."): this module registers them first, the VLA
ids and those of every installed plugin. The registration runs at module level so that the
worker processes ManiSkill spawns for ``--num-envs`` > 1 register them too.

A plugin is an installed distribution that declares an entry point in the group
``mikasa_envs.plugins`` naming a module whose import registers its env ids; mikasa-robo-rl
declares ``rl = "mikasa_robo_rl"`` (the RL release's ids)::

    [project.entry-points."mikasa_envs.plugins"]
    rl = "mikasa_robo_rl"

(ManiSkill's entry point also works on a trajectory whose .json names the env as
``"mikasa_envs:<id>"``: Gymnasium imports the module before it looks the id up.)
"""

from __future__ import annotations

import multiprocessing as mp
import warnings
from importlib.metadata import entry_points

from mani_skill.trajectory import replay_trajectory

import mikasa_envs  # noqa: F401  (registers the VLA ids)

PLUGIN_GROUP = "mikasa_envs.plugins"


def load_plugins() -> list[str]:
    """Import the module of every entry point in :data:`PLUGIN_GROUP` (registering its env
    ids); returns the names of those loaded. A plugin that fails to load is skipped with a
    warning, so that the VLA ids still replay."""
    loaded = []
    for entry_point in entry_points(group=PLUGIN_GROUP):
        try:
            entry_point.load()
        except Exception as exc:  # a broken plugin must not stop the replay of other ids
            warnings.warn(f"mikasa_envs plugin {entry_point.name!r} ({entry_point.value}) "
                          f"failed to load: {exc}", stacklevel=2)
        else:
            loaded.append(entry_point.name)
    return loaded


load_plugins()


def main(argv: list[str] | None = None) -> None:
    """Parse ManiSkill's replay arguments (``argv``, default ``sys.argv``) and replay."""
    replay_trajectory.main(replay_trajectory.parse_args(argv))


if __name__ == "__main__":
    mp.set_start_method("spawn")  # as ManiSkill's entry point does
    main()
