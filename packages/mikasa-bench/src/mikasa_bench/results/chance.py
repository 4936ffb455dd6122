"""Chance success rate per task: what a policy without memory can get by guessing.

The validity check (``mikasa-bench validity``) compares the memoryless oracle and the random
policy with this figure: a task where either does significantly better than chance shows its
answer without memory (a leak).

Each task family declares its chance rule with its env module (`mikasa_envs.family.TaskFamily`,
``chance=``), reading the variant's parameters from its env class:

* Tasks with a discrete answer: the success of a uniform guess among the candidates the
  agent sees when it must act (1/N objects, mugs, buttons or counts; 1/C(9, L) colour sets,
  1/P(9, L) colour sequences). For TakeItBack the candidates are the three start rows.
* Tasks without a discrete answer, each justified in its reason: Intercept* (a continuous
  start and velocity, out of view when the ball must be met: chance 0, any success is a
  leak), TraceShape* and TraceShapeSeq* (contours guessed from the task's prior, traced from
  checkpoint 0 without straying from the true ones, close them at a Monte Carlo rate),
  Rotate* (a continuous start heading: the success window's share of it), TimedTransfer* (a
  time: the best a policy without a clock gets by descending with a constant probability per
  step), BatteriesChecker* (a checklist: the chance that uniformly drawn check cycles cover
  every battery within the horizon).
"""

from __future__ import annotations

from collections.abc import Iterable

from mikasa_envs import family
from mikasa_envs.family import Chance
from mikasa_envs.manifest import get_task

__all__ = ["Chance", "task_chance", "chance_table"]


def task_chance(env_id: str) -> Chance:
    """The chance success rate of ``env_id`` and its one-line reason (its family's rule)."""
    get_task(env_id)  # an unknown id raises UnknownEnvIdError naming close matches
    return family.task_chance(env_id)


def chance_table(env_ids: Iterable[str]) -> dict[str, Chance]:
    """`task_chance` of every id."""
    return {env_id: task_chance(env_id) for env_id in env_ids}
