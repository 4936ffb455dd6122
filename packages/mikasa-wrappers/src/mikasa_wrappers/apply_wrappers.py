"""The canonical VLA wrapper chain and its per-task configuration table."""

from __future__ import annotations

import difflib
import warnings
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from mikasa_envs.manifest import list_tasks

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


# Table order of the reference (wrappers.md §5): (family, which ids, overlay chain,
# curriculum for these ids). "short" = ids without "-Long-", "long" = with, "all" = both.
# The curriculum wrapper is on exactly for the short shell games and the short selection
# tasks, whose short training data was collected with frozen cue/empty phases.
_FAMILY_TABLE: tuple[tuple[str, str, tuple[type[gym.Wrapper], ...], bool], ...] = (
    ("shell_game_touch", "all", ov.SHELL_GAME, True),
    ("shell_game_push", "all", ov.SHELL_GAME, True),
    ("shell_game_shuffle_touch", "short", ov.SHELL_GAME, True),
    ("shell_game_shuffle_color_lamp_touch", "short", ov.SHELL_GAME, True),
    ("shell_game_color_lamp_touch", "all", ov.SHELL_GAME, True),
    ("shell_game_shuffle_touch", "long", ov.SHELL_GAME, False),
    ("shell_game_shuffle_color_lamp_touch", "long", ov.SHELL_GAME, False),
    ("intercept", "all", ov.INTERCEPT, False),
    ("intercept_grab", "all", ov.INTERCEPT, False),
    ("rotate_lenient", "all", ov.ROTATE, False),
    ("rotate_strict", "all", ov.ROTATE, False),
    ("take_it_back", "all", ov.INTERCEPT, False),
    ("remember_color", "short", ov.COLOR_MEMORY, True),
    ("remember_color", "long", ov.COLOR_MEMORY, False),
    ("remember_shape", "short", ov.SHAPE_MEMORY, True),
    ("remember_shape", "long", ov.SHAPE_MEMORY, False),
    ("remember_shape_and_color", "short", ov.SHAPE_COLOR_MEMORY, True),
    ("remember_shape_and_color", "long", ov.SHAPE_COLOR_MEMORY, False),
    ("find_imposter_color", "all", ov.COLOR_MEMORY, True),
    ("find_imposter_shape", "all", ov.SHAPE_MEMORY, True),
    ("find_imposter_shape_and_color", "all", ov.SHAPE_COLOR_MEMORY, True),
    ("bunch_of_colors", "short", ov.MEMORY_CAPACITY, False),
    ("bunch_of_colors", "long", ov.MEMORY_CAPACITY, False),
    ("seq_of_colors", "short", ov.MEMORY_CAPACITY, False),
    ("seq_of_colors", "long", ov.MEMORY_CAPACITY, False),
    ("chain_of_colors", "short", ov.MEMORY_CAPACITY, False),
    ("chain_of_colors", "long", ov.MEMORY_CAPACITY, False),
    ("batteries_checker_easy", "all", ov.BATTERIES_CHECKER, False),
    ("batteries_checker_hard", "all", ov.BATTERIES_CHECKER, False),
    ("blink_count_button_press", "short", ov.BLINK_COUNT, False),
    ("blink_count_button_press", "long", ov.BLINK_COUNT, False),
    ("trace_shape", "all", ov.TRACE_SHAPE, False),
    ("trace_shape_seq", "all", ov.TRACE_SHAPE, False),
    ("timed_transfer", "short", ov.TIMED_TRANSFER, False),
    ("timed_transfer", "long", ov.TIMED_TRANSFER, False),
    ("gather_and_recall", "all", ov.STEP_REWARD, False),
)


def _is_long(env_id: str) -> bool:
    return "-Long-" in env_id


def _build_configs() -> dict[str, VLAWrapperConfig]:
    configs: dict[str, VLAWrapperConfig] = {}
    for family, which, chain, curriculum in _FAMILY_TABLE:
        for task in list_tasks(family=family):
            if (which == "short" and _is_long(task.env_id)) or (
                which == "long" and not _is_long(task.env_id)
            ):
                continue
            if task.env_id in configs:
                raise RuntimeError(f"{task.env_id} is listed twice in the wrapper table")
            # The curriculum is never used for -Long- ids, whatever the family row says.
            use_curriculum = curriculum and not _is_long(task.env_id)
            configs[task.env_id] = VLAWrapperConfig(
                overlays=chain,
                curriculum_wrapper=CurriculumPhaseNoopActionWrapper if use_curriculum else None,
            )
    missing = [t.env_id for t in list_tasks() if t.env_id not in configs]
    if missing:
        raise RuntimeError(f"canonical tasks without a wrapper configuration: {missing}")
    return configs


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
