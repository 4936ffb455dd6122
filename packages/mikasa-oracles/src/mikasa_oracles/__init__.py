"""MIKASA-Robo oracles: privileged-state scripted solvers for the VLA tasks."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from mikasa_oracles.families import ALL_ORACLES
from mikasa_oracles.families.selection import SelectionOracle
from mikasa_oracles.joint_delta import EEDeltaToJointDelta, JointDeltaOracle
from mikasa_oracles.rollout import Rollout, ZeroActions, rollout

__version__ = "0.1.0"

# Task family (manifest) -> oracle class.
ORACLES: dict[str, type] = ALL_ORACLES


def has_oracle(env_id: str) -> bool:
    """Whether an oracle exists for ``env_id``'s family."""
    from mikasa_envs.manifest import get_task

    return get_task(env_id).family in ORACLES


def make_oracle(env: gym.Env, **kwargs) -> Any:
    """The oracle for the task of ``env`` (made with ``gym.make``), wrapped or not."""
    from mikasa_envs.manifest import get_task

    env_id = env.spec.id if env.spec is not None else env.unwrapped.spec.id
    family = get_task(env_id).family
    if family not in ORACLES:
        raise ValueError(
            f"no oracle for {env_id!r} (family {family!r}); oracles exist for: "
            f"{', '.join(sorted(ORACLES))}"
        )
    return ORACLES[family](env, **kwargs)


__all__ = [
    "ZeroActions",
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
