"""Scripted oracles for the 32 RL tasks: the VLA family oracles, acting in joint deltas.

Each RL task is a VLA family with other timing, so the family's scripted oracle
(``mikasa_oracles``) solves it as it is: it reads privileged state (object poses, the phase
clock) but learns the hidden answer from what the cue showed. The RL release acts in
``pd_joint_delta_pos`` (8-D); ``JointDeltaOracle`` turns the oracle's end-effector intent
into joint deltas. Needs the ``collect`` extra (``pip install "mikasa-robo-rl[collect]"``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from mikasa_robo_rl.manifest import get_rl_task

RL_CONTROL_MODE = "pd_joint_delta_pos"
# Converter options per family (EEDeltaToJointDelta). The ball families turn the hand
# little and need every bit of arm speed: weighting rotation low when the joint-delta
# bound bites lets the TCP keep pace (measured over 10 seeds on the RL ids: InterceptFast
# 6 -> 9, InterceptGrabFast 9 -> 10 successes); the default suits the other families.
CONVERTER_OPTIONS: dict[str, dict[str, Any]] = {
    "intercept": {"rot_weights": (0.05,)},
    "intercept_grab": {"rot_weights": (0.05,)},
}


def make_rl_oracle(env: gym.Env, **kwargs: Any) -> Any:
    """The scripted oracle of the RL task ``env`` (made with ``gym.make``, wrapped or not).

    Follows the bench policy protocol (``chunk_size``, ``reset()``, ``forward(obs)``) and
    returns 8-D ``pd_joint_delta_pos`` actions; one env (``num_envs == 1``) per oracle.
    ``kwargs`` go to the family oracle (e.g. ``gain``).
    """
    try:
        from mikasa_oracles import ORACLES
        from mikasa_oracles.joint_delta import JointDeltaOracle
    except ImportError as err:
        raise ImportError(
            "the RL oracles need mikasa-oracles: pip install \"mikasa-robo-rl[collect]\""
        ) from err
    base = env.unwrapped
    env_id = base.spec.id if base.spec is not None else env.spec.id
    task = get_rl_task(env_id)
    if base.control_mode != RL_CONTROL_MODE:
        raise ValueError(
            f"the RL oracles act in control_mode={RL_CONTROL_MODE!r}; {env_id} was made with "
            f"{base.control_mode!r}"
        )
    options = CONVERTER_OPTIONS.get(task.family, {})
    return JointDeltaOracle(ORACLES[task.family](env, **kwargs), **options)
