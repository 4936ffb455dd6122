"""Shared helpers of the wrappers: the missing-value sentinel, batch/device lookup, and
space and step-count utilities (see `mikasa_wrappers.wrappers`).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

MISSING_VALUE_SENTINEL = 4242424242
"""Fill value of the ``task_cue`` / ``oracle_info`` entries when the env attribute is ``None``.

`StateOnlyTensorToDictWrapper` writes it; `FlattenRGBDObservationWrapper` drops every entry
that contains it. (Unrelated to the benchmark's start seed, which is the same number.)
"""


# ----------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------


def num_envs_of(env: gym.Env) -> int:
    """The batch size B of the base env (``num_envs``; 1 if it has none)."""
    return int(getattr(env.unwrapped, "num_envs", 1) or 1)


def env_device(env: gym.Env) -> torch.device:
    """The torch device of the base env (CPU if it has none or an unreadable one)."""
    dev = getattr(env.unwrapped, "device", None)
    try:
        return torch.device(dev) if dev is not None else torch.device("cpu")
    except (TypeError, RuntimeError):
        return torch.device("cpu")


def sentinel_space(num_envs: int) -> spaces.Box:
    """The (num_envs, 1) float32 space of an entry filled with `MISSING_VALUE_SENTINEL`."""
    # A constant box: exactly the set of values the placeholder can take. The flatten
    # wrapper recognises it to drop the entry from its space as it drops it from the obs.
    return spaces.Box(MISSING_VALUE_SENTINEL, MISSING_VALUE_SENTINEL, (num_envs, 1), np.float32)


def is_sentinel_space(space: gym.Space | None) -> bool:
    """Whether `space` is a `sentinel_space` (an entry that only holds the placeholder)."""
    return (
        isinstance(space, spaces.Box)
        and space.dtype == np.float32
        and bool(np.all(space.low == np.float32(MISSING_VALUE_SENTINEL)))
        and bool(np.all(space.high == np.float32(MISSING_VALUE_SENTINEL)))
    )


def box_for(shape: tuple[int, ...], dtype: Any) -> spaces.Box:
    """An unbounded Box of the given shape/dtype (integer dtypes use their full range)."""
    dtype = np.dtype(dtype)
    if dtype == np.bool_:
        return spaces.Box(0, 1, shape, np.bool_)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        return spaces.Box(info.min, info.max, shape, dtype)
    return spaces.Box(-np.inf, np.inf, shape, dtype)


def torch_to_numpy_dtype(dtype: torch.dtype) -> np.dtype:
    """The numpy dtype that a torch tensor of `dtype` converts to."""
    return torch.empty((), dtype=dtype).numpy().dtype


def _unbatch_space(space: gym.Space) -> gym.Space:
    """Drop the leading batch axis of every Box in a (nested) Dict space."""
    if isinstance(space, spaces.Dict):
        return spaces.Dict(OrderedDict((k, _unbatch_space(v)) for k, v in space.spaces.items()))
    if isinstance(space, spaces.Box) and len(space.shape) >= 1:
        return spaces.Box(
            np.array(space.low[0]), np.array(space.high[0]), space.shape[1:], space.dtype
        )
    return space


def flat_dim(space: gym.Space) -> int:
    """Per-env width of ManiSkill's ``flatten_state_dict`` applied to a batched space."""
    if isinstance(space, spaces.Dict):
        return sum(flat_dim(s) for s in space.spaces.values())
    if isinstance(space, spaces.Box):
        return int(np.prod(space.shape[1:])) if len(space.shape) > 1 else 1
    raise TypeError(f"cannot flatten observation space {space}")


def set_observation_spaces(wrapper: gym.Wrapper, space: gym.Space) -> None:
    """Set a wrapper's batched ``observation_space`` and unbatched ``single_observation_space``."""
    wrapper.observation_space = space
    # ManiSkillVectorEnv reads single_observation_space via get_wrapper_attr, which finds
    # this attribute on the outermost wrapper before the stale one of the base env.
    wrapper.single_observation_space = _unbatch_space(space)


def contains_sentinel(x: Any) -> bool:
    """Whether a tensor or array holds `MISSING_VALUE_SENTINEL` anywhere (other types: False)."""
    if isinstance(x, torch.Tensor):
        # Only dtypes that can represent the value are compared (comparing a uint8 tensor
        # with it would be meaningless); the placeholder itself is float32.
        if x.dtype.is_floating_point or x.dtype == torch.int64:
            return bool((x == MISSING_VALUE_SENTINEL).any())
        return False
    if isinstance(x, np.ndarray):
        if np.issubdtype(x.dtype, np.floating) or x.dtype == np.int64:
            return bool(np.any(x == MISSING_VALUE_SENTINEL))
        return False
    return False


def elapsed_from_info(info: Any) -> Any:
    """``info["elapsed_steps"]``, or None if `info` is not a dict or lacks it."""
    if isinstance(info, dict):
        return info.get("elapsed_steps")
    return None


def as_step_tensor(steps: Any, device: torch.device | None = None) -> torch.Tensor:
    """Step counts (tensor, array or number) as a 1-D tensor, moved to `device` if given."""
    t = steps if isinstance(steps, torch.Tensor) else torch.as_tensor(np.asarray(steps))
    if device is not None and t.device != device:
        t = t.to(device)
    return t.reshape(-1)
