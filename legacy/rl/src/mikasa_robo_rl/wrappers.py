"""The RL release's wrappers (``rl/utils/wrappers.py``), ``env_info`` and the RL chain.

The wrapper classes are MIKASA-Robo's own (``mikasa_wrappers``): the RL release used the
same ``StateOnlyTensorToDictWrapper`` / ``InitialZeroActionWrapper`` /
``FlattenRGBDObservationWrapper`` and render overlays as the VLA chain, so they are
re-exported here under their old names rather than copied. What is RL-specific is the
per-task list of ``env_info`` and the observation modes of the PPO baselines
(``apply_rl_wrappers``).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from mikasa_wrappers import (
    MISSING_VALUE_SENTINEL,
    VLA_WRAPPER_CONFIGS,
    CameraShutdownWrapper,
    DebugRewardWrapper,
    FlattenRGBDObservationWrapper,
    InitialZeroActionWrapper,
    MemoryCapacityInfoWrapper,
    RememberColorInfoWrapper,
    RememberShapeAndColorInfoWrapper,
    RememberShapeInfoWrapper,
    RenderRewardInfoWrapper,
    RenderStepInfoWrapper,
    RotateRenderAngleInfoWrapper,
    ShellGameRenderCupInfoWrapper,
    StateOnlyTensorToDictWrapper,
    apply_mikasa_vla_state_wrappers,
    apply_mikasa_vla_wrappers,
)

from mikasa_robo_rl.manifest import UnknownEnvIdError, get_rl_task, unknown_rl_env_message

WrapperList = list[tuple[type[gym.Wrapper], dict[str, Any]]]

# Per group, the wrappers after StateOnlyTensorToDict and InitialZeroAction, inner to outer
# (legacy_rl.md §4). The overlays draw on render() frames only.
_STEP_REWARD = (RenderStepInfoWrapper, RenderRewardInfoWrapper, DebugRewardWrapper)
_SHELL_GAME = (RenderStepInfoWrapper, ShellGameRenderCupInfoWrapper, RenderRewardInfoWrapper, DebugRewardWrapper)
_ROTATE = (RenderStepInfoWrapper, RenderRewardInfoWrapper, RotateRenderAngleInfoWrapper, DebugRewardWrapper)
_GROUP_OVERLAYS: dict[str, tuple[type[gym.Wrapper], ...]] = {
    "ShellGame": _SHELL_GAME,
    "Intercept": _STEP_REWARD,
    "InterceptGrab": _STEP_REWARD,
    "RotateLenient": _ROTATE,
    "RotateStrict": _ROTATE,
    "TakeItBack": _STEP_REWARD,
    "RememberColor": (RememberColorInfoWrapper, *_STEP_REWARD),
    "RememberShape": (RememberShapeInfoWrapper, *_STEP_REWARD),
    "RememberShapeAndColor": (RememberShapeAndColorInfoWrapper, *_STEP_REWARD),
    "BunchOfColors": (MemoryCapacityInfoWrapper, *_STEP_REWARD),
    "SeqOfColors": (MemoryCapacityInfoWrapper, *_STEP_REWARD),
    "ChainOfColors": (MemoryCapacityInfoWrapper, *_STEP_REWARD),
}
# Upstream's env_info also knows two camera-shutdown tasks that the release never registered.
_CAMERA_SHUTDOWN_IDS = ("CameraShutdownPush-v0", "CameraShutdownPick-v0")
CAMERA_SHUTDOWN_STEPS = 19


def env_info(env_id: str, noop_steps: int = 1) -> tuple[WrapperList, int]:
    """``(wrappers, episode_timeout)`` of the RL release for ``env_id``.

    ``wrappers`` is a list of ``(WrapperClass, kwargs)`` to apply in order, starting with
    ``StateOnlyTensorToDictWrapper``; ``InitialZeroActionWrapper`` gets
    ``n_initial_steps=noop_steps - 1`` (the default 1 disables it, as upstream). Unknown ids
    raise ``ValueError("Unknown environment: ...")`` naming close matches.
    """
    if noop_steps < 1:
        raise ValueError(f"noop_steps must be >= 1 (1 = no no-op steps), got {noop_steps}")
    head: WrapperList = [
        (StateOnlyTensorToDictWrapper, {}),
        (InitialZeroActionWrapper, {"n_initial_steps": noop_steps - 1}),
    ]
    if env_id in _CAMERA_SHUTDOWN_IDS:
        tail = [(CameraShutdownWrapper, {"n_initial_steps": CAMERA_SHUTDOWN_STEPS})]
        tail += [(w, {}) for w in (RenderStepInfoWrapper, RenderRewardInfoWrapper)]
        return head + tail, 90
    try:
        task = get_rl_task(env_id)
    except UnknownEnvIdError:
        raise ValueError(unknown_rl_env_message(env_id)) from None
    return head + [(w, {}) for w in _GROUP_OVERLAYS[task.group]], task.max_episode_steps


# The observation modes of the PPO baselines (ppo_baselines.md §3.1): MODE -> the
# FlattenRGBDObservationWrapper flags (rgb, state, oracle, joints) and the env obs_mode.
OBS_MODES: dict[str, dict[str, bool]] = {
    "state": dict(rgb=False, state=True, oracle=False, joints=False),
    "rgb": dict(rgb=True, state=False, oracle=False, joints=False),
    "rgb_oracle": dict(rgb=True, state=False, oracle=True, joints=False),
    "rgb_joints": dict(rgb=True, state=False, oracle=False, joints=True),
    "rgb_joints_oracle": dict(rgb=True, state=False, oracle=True, joints=True),
}


def env_obs_mode(mode: str) -> str:
    """The ManiSkill ``obs_mode`` an RL observation ``mode`` needs (``state`` or ``rgb``)."""
    _check_mode(mode)
    return "state" if mode == "state" else "rgb"


def _check_mode(mode: str) -> None:
    if mode not in OBS_MODES:
        raise ValueError(f"unknown RL observation mode {mode!r}; accepted values: {', '.join(OBS_MODES)}")


# Online RL on the VLA ids (beyond the release): the canonical chain's observations.
VLA_OBS_MODES: tuple[str, ...] = ("state", "rgb", "rgb_joints")
RL_CONTROL_MODE = "pd_joint_delta_pos"
VLA_CONTROL_MODE = "pd_ee_delta_pose"


def is_vla_env_id(env_id: str) -> bool:
    """Whether ``env_id`` is a MIKASA-Robo VLA id (one with a canonical wrapper chain)."""
    return env_id in VLA_WRAPPER_CONFIGS


def default_control_mode(env_id: str) -> str:
    """The control mode an id is trained with: the VLA chain's end-effector deltas for VLA
    ids, the release's joint deltas for the RL ids."""
    return VLA_CONTROL_MODE if is_vla_env_id(env_id) else RL_CONTROL_MODE


def apply_vla_rl_wrappers(env: gym.Env, mode: str = "rgb_joints") -> gym.Env:
    """The VLA wrapper chain in an RL observation ``mode`` (``VLA_OBS_MODES``).

    ``rgb_joints`` is the canonical chain (``{"proprio": (B, 7), "rgb": (B, 128, 128, 6)}``
    + ``task_cue``); ``rgb`` the same without ``proprio``; ``state`` the privileged-state
    chain (``{"proprio", "state"}`` + ``task_cue``). VLA ids have no ``oracle_info``.
    """
    if mode not in VLA_OBS_MODES:
        raise ValueError(f"RL mode {mode!r} is not available for VLA ids (they have no oracle_info); "
                         f"accepted values: {', '.join(VLA_OBS_MODES)}")
    if mode == "state":
        return apply_mikasa_vla_state_wrappers(env)
    env = apply_mikasa_vla_wrappers(env)
    if mode == "rgb":
        max_episode_steps = env.max_episode_steps
        env = gym.wrappers.FilterObservation(env, [k for k in env.observation_space.spaces if k != "proprio"])
        env.max_episode_steps = max_episode_steps
    return env


def apply_rl_wrappers(env: gym.Env, mode: str = "rgb_joints", noop_steps: int = 1) -> gym.Env:
    """The RL release's wrapper chain for an env made with ``gym.make(<RL id>, ...)``.

    ``StateOnlyTensorToDictWrapper``, the ``env_info`` list, then
    ``FlattenRGBDObservationWrapper`` for ``mode``: ``state`` gives ``{"state", ["task_cue"]}``;
    ``rgb_joints`` gives ``{"proprio": (B, 25), "rgb": (B, 128, 128, 6)}`` (+ ``task_cue``
    on Rotate); ``*_oracle`` modes add ``oracle_info``. The env's ``obs_mode`` must be
    ``env_obs_mode(mode)``.
    """
    _check_mode(mode)
    env_id = env.unwrapped.spec.id if env.unwrapped.spec is not None else env.spec.id
    wanted, actual = env_obs_mode(mode), env.unwrapped.obs_mode
    if actual != wanted:
        raise ValueError(f"RL mode {mode!r} needs an env made with obs_mode={wanted!r}, got {actual!r}")
    wrappers, _ = env_info(env_id, noop_steps=noop_steps)
    for wrapper, kwargs in wrappers:
        env = wrapper(env, **kwargs)
    return FlattenRGBDObservationWrapper(env, depth=False, **OBS_MODES[mode])


__all__ = [
    "CAMERA_SHUTDOWN_STEPS",
    "MISSING_VALUE_SENTINEL",
    "OBS_MODES",
    "CameraShutdownWrapper",
    "DebugRewardWrapper",
    "FlattenRGBDObservationWrapper",
    "InitialZeroActionWrapper",
    "MemoryCapacityInfoWrapper",
    "RememberColorInfoWrapper",
    "RememberShapeAndColorInfoWrapper",
    "RememberShapeInfoWrapper",
    "RenderRewardInfoWrapper",
    "RenderStepInfoWrapper",
    "RotateRenderAngleInfoWrapper",
    "ShellGameRenderCupInfoWrapper",
    "StateOnlyTensorToDictWrapper",
    "RL_CONTROL_MODE",
    "VLA_CONTROL_MODE",
    "VLA_OBS_MODES",
    "apply_rl_wrappers",
    "apply_vla_rl_wrappers",
    "default_control_mode",
    "is_vla_env_id",
    "env_info",
    "env_obs_mode",
]
