"""ManiSkill's trajectory replay for MIKASA-Robo envs.

``python -m mikasa_envs.replay_trajectory --traj-path X.h5 --use-env-states`` takes exactly
the arguments of ``python -m mani_skill.trajectory.replay_trajectory`` and runs that tool,
unchanged. ManiSkill's own entry point makes the env with ``gym.make(env_id)`` in an
interpreter that has imported only ``mani_skill.envs``, where no MIKASA id is registered
(it stops with "No registered env with id: ..."): this module registers them first, the VLA
ids and, where mikasa-robo-rl is installed, the RL ids. The imports run at module level so
that the worker processes ManiSkill spawns for ``--num-envs`` > 1 register them too.

(ManiSkill's entry point also works on a trajectory whose .json names the env as
``"mikasa_envs:<id>"``: Gymnasium imports the module before it looks the id up.)
"""

from __future__ import annotations

import multiprocessing as mp

import mikasa_envs  # noqa: F401  (registers the VLA ids)

try:
    import mikasa_robo_rl  # noqa: F401  (registers the RL ids)
except ImportError:  # mikasa-robo-rl is a separate package
    pass

from mani_skill.trajectory import replay_trajectory


def main(argv: list[str] | None = None) -> None:
    """Parse ManiSkill's replay arguments (``argv``, default ``sys.argv``) and replay."""
    replay_trajectory.main(replay_trajectory.parse_args(argv))


if __name__ == "__main__":
    mp.set_start_method("spawn")  # as ManiSkill's entry point does
    main()
