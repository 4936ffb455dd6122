"""MIKASA-Robo oracles: privileged-state scripted solvers for the VLA tasks."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from mikasa_oracles.families import ALL_MEMORYLESS_ORACLES, ALL_ORACLES
from mikasa_oracles.families.selection import SelectionOracle
from mikasa_oracles.joint_delta import EEDeltaToJointDelta, JointDeltaOracle
from mikasa_oracles.rollout import Rollout, ZeroActions, rollout

__version__ = "0.1.0"

# Task family (manifest) -> oracle class.
ORACLES: dict[str, type] = ALL_ORACLES
# Task family -> the oracle's memoryless variant (`mikasa_oracles.scripted.Memoryless`).
MEMORYLESS_ORACLES: dict[str, type] = ALL_MEMORYLESS_ORACLES


def has_oracle(env_id: str) -> bool:
    """Whether an oracle exists for ``env_id``'s family."""
    from mikasa_envs.manifest import get_task

    return get_task(env_id).family in ORACLES


def make_oracle(env: gym.Env, memoryless: bool = False, **kwargs) -> Any:
    """The oracle for the task of ``env`` (made with ``gym.make``), wrapped or not.

    ``memoryless=True`` builds its memoryless variant: the same controller, but whatever it
    remembers about the hidden answer is wiped before every step, and it guesses (seeded
    by the episode seed given to ``reset(seed)``) where the current frame does not show the
    answer. ``kwargs`` go to the oracle class.
    """
    from mikasa_envs.manifest import get_task

    env_id = env.spec.id if env.spec is not None else env.unwrapped.spec.id
    family = get_task(env_id).family
    table = MEMORYLESS_ORACLES if memoryless else ORACLES
    if family not in table:
        raise ValueError(
            f"no {'memoryless ' if memoryless else ''}oracle for {env_id!r} (family {family!r}); "
            f"they exist for: {', '.join(sorted(table))}"
        )
    return table[family](env, **kwargs)


__all__ = [
    "ZeroActions",
    "MEMORYLESS_ORACLES",
    "ORACLES",
    "EEDeltaToJointDelta",
    "JointDeltaOracle",
    "Rollout",
    "SelectionOracle",
    "has_oracle",
    "make_oracle",
    "rollout",
    "__version__",
]
