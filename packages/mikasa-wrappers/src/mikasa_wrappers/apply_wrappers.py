"""The canonical VLA wrapper chain and its per-task configuration table."""

from __future__ import annotations

import difflib
import warnings
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from mikasa_envs.family import TaskSpec, get_family
from mikasa_envs.manifest import get_task, list_tasks

from . import overlays as ov
from .wrappers import (
    ConvertJointsToEEFXyzRpyGripperWrapper,
    CurriculumPhaseNoopActionWrapper,
    FlattenRGBDObservationWrapper,
    StateOnlyTensorToDictWrapper,
)

__all__ = [
    "VLAWrapperConfig",
    "VLA_WRAPPER_CONFIGS",
    "MIKASA_VLA_ENV_IDS",
    "apply_mikasa_vla_wrappers",
    "apply_mikasa_vla_state_wrappers",
    "apply_chain_head",
    "family_wrapper_config",
    "REQUIRED_OBS_MODE",
]

REQUIRED_OBS_MODE = "rgb"
"""The only ``obs_mode`` the chain accepts (the flatten step needs camera images)."""


@dataclass(frozen=True)
class VLAWrapperConfig:
    """Per-task wrapper configuration.

    ``overlays``: render-overlay classes, inner to outer (applied only with
    ``include_overlays=True``). ``curriculum_wrapper``: action wrapper that freezes the
    robot during the cue/empty phases, or None. ``expected_control_mode``: if set and the
    env uses another control mode, a ``RuntimeWarning`` is emitted (unused by the table).
    """

    overlays: tuple[type[gym.Wrapper], ...] = ()
    curriculum_wrapper: type[gym.Wrapper] | None = None
    expected_control_mode: str | None = None


def _is_long(env_id: str) -> bool:
    return "-Long-" in env_id


def family_wrapper_config(env_id: str) -> VLAWrapperConfig:
    """The wrapper configuration of ``env_id`` from its family's declaration
    (`mikasa_envs.family.TaskFamily`): its overlay chain and, for its ids without
    ``-Long-``, the curriculum wrapper if the family freezes the robot during the cue."""
    family = get_family(get_task(env_id).family)
    if family.overlays not in ov.OVERLAY_CHAINS:
        raise ValueError(
            f"family {family.name!r} names overlay chain {family.overlays!r}; accepted values: "
            f"{', '.join(ov.OVERLAY_CHAINS)}"
        )
    curriculum = family.frozen_cue_on_short_ids and not _is_long(env_id)
    return VLAWrapperConfig(
        overlays=ov.OVERLAY_CHAINS[family.overlays],
        curriculum_wrapper=CurriculumPhaseNoopActionWrapper if curriculum else None,
    )


def _table_position(task: TaskSpec) -> float:
    """Where ``task`` stands in the reference's wrapper table: by its family's rank for
    short or ``-Long-`` ids, then in manifest order; families outside the table last."""
    rank = get_family(task.family).wrapper_table_rank
    if rank is None:
        return float("inf")
    return rank[1] if _is_long(task.env_id) else rank[0]


def _build_configs() -> dict[str, VLAWrapperConfig]:
    # sorted() is stable: within one rank the ids keep their manifest order.
    tasks = sorted(list_tasks(), key=_table_position)
    return {task.env_id: family_wrapper_config(task.env_id) for task in tasks}


VLA_WRAPPER_CONFIGS: dict[str, VLAWrapperConfig] = _build_configs()
"""Env id -> `VLAWrapperConfig` for the 90 canonical tasks, in the reference's table order."""

MIKASA_VLA_ENV_IDS: tuple[str, ...] = tuple(VLA_WRAPPER_CONFIGS)
"""The supported env ids (keys of `VLA_WRAPPER_CONFIGS`, in order)."""


def _env_id(env: gym.Env) -> str:
    spec = getattr(env, "spec", None) or getattr(env.unwrapped, "spec", None)
    env_id = getattr(spec, "id", None)
    if not env_id:
        raise ValueError(
            "cannot tell which task this env is: it has no spec id. Create it with "
            "gym.make('<TaskName>-VLA-v0', obs_mode='rgb', ...) before wrapping it."
        )
    return env_id


def _unknown_id_error(env_id: str) -> ValueError:
    close = difflib.get_close_matches(env_id, MIKASA_VLA_ENV_IDS, n=3, cutoff=0.6)
    hint = f" Did you mean: {', '.join(close)}?" if close else ""
    extra = {t.env_id for t in list_tasks(include_extra=True) if not t.canonical}
    note = (
        " It is a registered variant outside the canonical benchmark, which has no wrapper "
        "configuration."
        if env_id in extra
        else ""
    )
    return ValueError(
        f"apply_mikasa_vla_wrappers does not support env id {env_id!r}.{note}{hint} "
        f"{len(MIKASA_VLA_ENV_IDS)} env ids are supported (see MIKASA_VLA_ENV_IDS)."
    )


def _find_max_episode_steps(env: gym.Env) -> int | None:
    from mani_skill.utils.gym_utils import find_max_episode_steps_value

    value = find_max_episode_steps_value(env)
    return int(value) if value is not None else None


def apply_chain_head(
    env: gym.Env, config: VLAWrapperConfig, *, include_overlays: bool = False
) -> gym.Env:
    """The first links of the canonical chain: observation dict, the task's action
    (curriculum) wrapper and, with ``include_overlays``, its render overlays. Chains that
    flatten observations differently (e.g. mikasa-bench's state-mode chain) start here."""
    wrapped: gym.Env = StateOnlyTensorToDictWrapper(env)
    if config.curriculum_wrapper is not None:
        wrapped = config.curriculum_wrapper(wrapped)
    if include_overlays:
        for overlay in config.overlays:
            wrapped = overlay(wrapped)
    return wrapped


def _apply_config(
    env: gym.Env,
    config: VLAWrapperConfig,
    *,
    include_overlays: bool = False,
) -> gym.Wrapper:
    """Wrap ``env`` with the canonical chain described by ``config`` (no id lookup).

    Used by `apply_mikasa_vla_wrappers` and by tests on non-MIKASA ManiSkill envs.
    """
    obs_mode = getattr(env.unwrapped, "obs_mode", None)
    if obs_mode != REQUIRED_OBS_MODE:
        raise ValueError(
            f"the MIKASA VLA wrapper chain needs obs_mode={REQUIRED_OBS_MODE!r} (camera images "
            f"for the 'rgb' observation), but this env was made with obs_mode={obs_mode!r}. "
            f"Create it with gym.make(..., obs_mode={REQUIRED_OBS_MODE!r})."
        )
    # Read before wrapping: honours a max_episode_steps= override given to gym.make.
    max_episode_steps = _find_max_episode_steps(env)
    expected = config.expected_control_mode
    actual = getattr(env.unwrapped, "control_mode", None)
    if expected is not None and expected != actual:
        warnings.warn(
            f"this task expects control_mode={expected!r}, the env uses {actual!r}",
            RuntimeWarning,
            stacklevel=3,
        )

    wrapped = apply_chain_head(env, config, include_overlays=include_overlays)
    wrapped = FlattenRGBDObservationWrapper(
        wrapped, rgb=True, depth=False, state=False, oracle=False, joints=True
    )
    wrapped = ConvertJointsToEEFXyzRpyGripperWrapper(wrapped)
    wrapped.max_episode_steps = max_episode_steps
    return wrapped


def apply_mikasa_vla_wrappers(env: gym.Env, *, include_overlays: bool = False) -> gym.Wrapper:
    """Wrap a MIKASA-Robo VLA env (made with ``gym.make(<id>, obs_mode="rgb", ...)``).

    Chain, inner to outer: `StateOnlyTensorToDictWrapper`, the task's curriculum wrapper
    (if any), the task's render overlays (only with ``include_overlays=True``),
    `FlattenRGBDObservationWrapper` (rgb + joints) and
    `ConvertJointsToEEFXyzRpyGripperWrapper`. The result observes
    ``{"proprio": (B, 7) float32, "rgb": (B, 128, 128, 6) uint8}`` (+ ``task_cue`` for
    families that set one) and has a ``max_episode_steps`` attribute.

    Raises ``ValueError`` for an env without a spec id, an id outside
    `MIKASA_VLA_ENV_IDS`, or an ``obs_mode`` other than ``"rgb"``.
    """
    env_id = _env_id(env)
    config = VLA_WRAPPER_CONFIGS.get(env_id)
    if config is None:
        raise _unknown_id_error(env_id)
    return _apply_config(env, config, include_overlays=include_overlays)


class _ProprioFromAgent(gym.ObservationWrapper):
    """Add ``proprio`` = [tcp_pose, qpos, qvel] (the rgb chain's layout before its
    conversion to 7 values) in front of a state-mode observation."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        base = env.unwrapped
        n = int(getattr(base, "num_envs", 1))
        dim = 7 + 2 * int(base.agent.robot.get_qpos().shape[-1])
        entries = {"proprio": spaces.Box(-np.inf, np.inf, (n, dim), np.float32)}
        entries.update(env.observation_space.spaces)
        self.observation_space = spaces.Dict(entries)

    def observation(self, obs: dict) -> dict:
        base = self.env.unwrapped
        robot = base.agent.robot
        proprio = torch.cat([base.agent.tcp.pose.raw_pose, robot.get_qpos(), robot.get_qvel()], dim=-1)
        return {"proprio": proprio.to(torch.float32), **obs}


def apply_mikasa_vla_state_wrappers(env: gym.Env, *, include_overlays: bool = False) -> gym.Wrapper:
    """The privileged-state counterpart of `apply_mikasa_vla_wrappers` (not the published
    contract: for RL in the MDP view, and the bench's ``obs_mode="state"``).

    For a VLA env made with ``obs_mode="state"``: the same action path (the task's
    curriculum wrapper) and the same 7-value ``proprio``, with the flat privileged ``state``
    vector in place of the images. The result observes ``{"proprio": (B, 7), "state":
    (B, D)}`` (+ ``task_cue`` where the family sets one) and has ``max_episode_steps``.
    ``include_overlays`` adds the task's render overlays (videos). Raises ``ValueError``
    for an id outside `MIKASA_VLA_ENV_IDS` or an ``obs_mode`` other than ``"state"``.
    """
    env_id = _env_id(env)
    config = VLA_WRAPPER_CONFIGS.get(env_id)
    if config is None:
        raise _unknown_id_error(env_id)
    obs_mode = getattr(env.unwrapped, "obs_mode", None)
    if obs_mode != "state":
        raise ValueError(f"the MIKASA VLA state chain needs obs_mode='state', but this env was made with "
                         f"obs_mode={obs_mode!r}")
    max_episode_steps = _find_max_episode_steps(env)
    wrapped = apply_chain_head(env, config, include_overlays=include_overlays)
    wrapped = FlattenRGBDObservationWrapper(wrapped, rgb=False, depth=False, state=True, oracle=False, joints=False)
    wrapped = ConvertJointsToEEFXyzRpyGripperWrapper(_ProprioFromAgent(wrapped))
    wrapped.max_episode_steps = max_episode_steps
    return wrapped
