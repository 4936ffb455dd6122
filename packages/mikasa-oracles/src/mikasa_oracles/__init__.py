"""MIKASA-Robo oracles: privileged-state scripted solvers for the VLA tasks."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from mikasa_oracles import families  # noqa: F401  (imported: registers the built-in oracles)
from mikasa_oracles.families.selection import SelectionOracle
from mikasa_oracles.joint_delta import EEDeltaToJointDelta, JointDeltaOracle
from mikasa_oracles.registry import (
    MEMORYLESS_ORACLES,
    ORACLES,
    DuplicateOracleError,
    UnknownFamilyError,
    load_entry_point_oracles,
    oracle_class,
    register_oracle,
)
from mikasa_oracles.rollout import Rollout, ZeroActions, rollout

__version__ = "0.2.0"


def has_oracle(env_id: str) -> bool:
    """Whether an oracle exists for ``env_id``'s family."""
    from mikasa_envs.manifest import get_task

    return get_task(env_id).family in ORACLES


def make_oracle(env: gym.Env, memoryless: bool = False, **kwargs) -> Any:
    """The oracle for the task of ``env`` (made with ``gym.make``), wrapped or not.

    ``memoryless=True`` builds its memoryless variant: the same controller, but whatever it
    remembers about the hidden answer is wiped before every step, and it guesses (seeded
    by the episode seed given to ``reset(seed)``) where the current frame does not show the
    answer. ``kwargs`` go to the oracle class. Raises `UnknownFamilyError` (a ``ValueError``)
    if no oracle is registered for the task's family (`register_oracle`).
    """
    from mikasa_envs.manifest import get_task

    env_id = env.spec.id if env.spec is not None else env.unwrapped.spec.id
    family = get_task(env_id).family
    return oracle_class(family, memoryless, env_id=env_id)(env, **kwargs)


__all__ = [
    "ZeroActions",
    "MEMORYLESS_ORACLES",
    "ORACLES",
    "DuplicateOracleError",
    "EEDeltaToJointDelta",
    "JointDeltaOracle",
    "Rollout",
    "SelectionOracle",
    "UnknownFamilyError",
    "has_oracle",
    "make_oracle",
    "oracle_class",
    "register_oracle",
    "rollout",
    "__version__",
]

# Last: the registering modules of other distributions may import anything above.
load_entry_point_oracles()
