"""Observation and action wrappers of the canonical MIKASA-Robo VLA chain.

All wrappers work on batched torch tensors (B = ``num_envs``) on the env device and never
round-trip through numpy on the step path. They follow gymnasium >= 1.0 semantics: the base
env is reached through ``env.unwrapped`` (no attribute forwarding). Observation spaces are
derived from the wrapped env's own ``observation_space`` (no reset at construction), and
every observation wrapper also sets ``single_observation_space`` (the unbatched space) so
that ManiSkill's vector wrapper sees the true space.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from ._drawing import frames_to_uint8, restore_batching

__all__ = [
    "MISSING_VALUE_SENTINEL",
    "StateOnlyTensorToDictWrapper",
    "CurriculumPhaseNoopActionWrapper",
    "CurriculumPhaseNoopActionWrapperPdJointPos",
    "InitialZeroActionWrapper",
    "CameraShutdownWrapper",
    "FlattenRGBDObservationWrapper",
    "ConvertJointsToEEFXyzRpyGripperWrapper",
]

MISSING_VALUE_SENTINEL = 4242424242
"""Fill value of the ``task_cue`` / ``oracle_info`` entries when the env attribute is ``None``.

`StateOnlyTensorToDictWrapper` writes it; `FlattenRGBDObservationWrapper` drops every entry
that contains it. (Unrelated to the benchmark's start seed, which is the same number.)
"""

# Finger-joint target range of the Panda gripper under pd_joint_pos: [-0.01, 0.04] maps to
# the normalised gripper command [-1, 1].
_FINGER_CENTER = 0.015
_FINGER_HALF_RANGE = 0.025


# ----------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------


def _num_envs(env: gym.Env) -> int:
    return int(getattr(env.unwrapped, "num_envs", 1) or 1)


def _env_device(env: gym.Env) -> torch.device:
    dev = getattr(env.unwrapped, "device", None)
    try:
        return torch.device(dev) if dev is not None else torch.device("cpu")
    except (TypeError, RuntimeError):
        return torch.device("cpu")


def _sentinel_space(num_envs: int) -> spaces.Box:
    # A constant box: exactly the set of values the placeholder can take. The flatten
    # wrapper recognises it to drop the entry from its space as it drops it from the obs.
    return spaces.Box(MISSING_VALUE_SENTINEL, MISSING_VALUE_SENTINEL, (num_envs, 1), np.float32)


def _is_sentinel_space(space: gym.Space | None) -> bool:
    return (
        isinstance(space, spaces.Box)
        and space.dtype == np.float32
        and bool(np.all(space.low == np.float32(MISSING_VALUE_SENTINEL)))
        and bool(np.all(space.high == np.float32(MISSING_VALUE_SENTINEL)))
    )


def _box_for(shape: tuple[int, ...], dtype: Any) -> spaces.Box:
    """An unbounded Box of the given shape/dtype (integer dtypes use their full range)."""
    dtype = np.dtype(dtype)
    if dtype == np.bool_:
        return spaces.Box(0, 1, shape, np.bool_)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        return spaces.Box(info.min, info.max, shape, dtype)
    return spaces.Box(-np.inf, np.inf, shape, dtype)


def _torch_to_numpy_dtype(dtype: torch.dtype) -> np.dtype:
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


def _flat_dim(space: gym.Space) -> int:
    """Per-env width of ManiSkill's ``flatten_state_dict`` applied to a batched space."""
    if isinstance(space, spaces.Dict):
        return sum(_flat_dim(s) for s in space.spaces.values())
    if isinstance(space, spaces.Box):
        return int(np.prod(space.shape[1:])) if len(space.shape) > 1 else 1
    raise TypeError(f"cannot flatten observation space {space}")


def _set_spaces(wrapper: gym.Wrapper, space: gym.Space) -> None:
    wrapper.observation_space = space
    # ManiSkillVectorEnv reads single_observation_space via get_wrapper_attr, which finds
    # this attribute on the outermost wrapper before the stale one of the base env.
    wrapper.single_observation_space = _unbatch_space(space)


def _contains_sentinel(x: Any) -> bool:
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


def _elapsed_from_info(info: Any) -> Any:
    if isinstance(info, dict):
        return info.get("elapsed_steps")
    return None


def _as_step_tensor(steps: Any, device: torch.device | None = None) -> torch.Tensor:
    t = steps if isinstance(steps, torch.Tensor) else torch.as_tensor(np.asarray(steps))
    if device is not None and t.device != device:
        t = t.to(device)
    return t.reshape(-1)


# ----------------------------------------------------------------------------------------
# StateOnlyTensorToDictWrapper
# ----------------------------------------------------------------------------------------


class StateOnlyTensorToDictWrapper(gym.ObservationWrapper):
    """Make every observation a dict and add ``task_cue`` and ``oracle_info`` entries.

    A flat (state-mode) observation becomes ``{"state": obs}``; a dict observation is
    shallow-copied. The entries come from ``env.unwrapped.task_cue`` / ``oracle_info``: a 1-D
    tensor is reshaped to (B, 1), higher ranks are kept, and ``None`` becomes a (B, 1)
    float32 tensor filled with `MISSING_VALUE_SENTINEL`.

    The declared space keeps the input entries at the top level (matching the actual
    observation) and derives the two extra entries from the attribute values the env holds
    after its construction-time reset; pass ``task_cue_space`` / ``oracle_info_space`` to
    override.
    """

    def __init__(
        self,
        env: gym.Env,
        *,
        task_cue_space: gym.Space | None = None,
        oracle_info_space: gym.Space | None = None,
    ) -> None:
        super().__init__(env)
        base_space = env.observation_space
        n = _num_envs(env)
        entries: OrderedDict[str, gym.Space] = OrderedDict()
        if isinstance(base_space, spaces.Dict):
            entries.update(base_space.spaces)
        else:
            entries["state"] = base_space
        base = env.unwrapped
        for key, given in (("task_cue", task_cue_space), ("oracle_info", oracle_info_space)):
            entries[key] = (
                given if given is not None else self._space_of(getattr(base, key, None), n)
            )
        _set_spaces(self, spaces.Dict(entries))

    @staticmethod
    def _space_of(value: Any, n: int) -> spaces.Box:
        if value is None:
            return _sentinel_space(n)
        if isinstance(value, torch.Tensor):
            dtype = _torch_to_numpy_dtype(value.dtype)
            shape = tuple(value.shape)
        else:
            arr = np.asarray(value)
            dtype, shape = arr.dtype, arr.shape
        per_env = (1,) if len(shape) <= 1 else shape[1:]
        return _box_for((n, *per_env), dtype)

    @staticmethod
    def _sentinel(batch: int, device: torch.device) -> torch.Tensor:
        # A fresh tensor each time (not a cached one) so that a consumer writing into it
        # cannot change later observations; the allocation is negligible.
        return torch.full(
            (batch, 1), float(MISSING_VALUE_SENTINEL), dtype=torch.float32, device=device
        )

    def _entry(self, value: Any, batch: int, device: torch.device) -> Any:
        if value is None:
            return self._sentinel(batch, device)
        if not isinstance(value, torch.Tensor):
            value = torch.as_tensor(np.asarray(value), device=device)
        if value.ndim == 0:
            return value.reshape(1, 1).expand(batch, 1)
        if value.ndim == 1:
            return value.reshape(-1, 1)
        return value

    def observation(self, observation: Any) -> dict:
        """Return the dict observation with ``task_cue`` and ``oracle_info`` added."""
        if isinstance(observation, dict):
            obs = dict(observation)
            try:
                ref = observation["agent"]["qpos"]
            except (KeyError, TypeError):
                ref = next((v for v in observation.values() if isinstance(v, torch.Tensor)), None)
        else:
            obs = {"state": observation}
            ref = observation
        if isinstance(ref, torch.Tensor):
            batch, device = int(ref.shape[0]), ref.device
        else:
            batch, device = _num_envs(self.env), _env_device(self.env)
        base = self.env.unwrapped
        obs["task_cue"] = self._entry(getattr(base, "task_cue", None), batch, device)
        obs["oracle_info"] = self._entry(getattr(base, "oracle_info", None), batch, device)
        return obs


# ----------------------------------------------------------------------------------------
# action wrappers
# ----------------------------------------------------------------------------------------


class _StepGatedActionWrapper(gym.ActionWrapper):
    """Base for action wrappers that replace the rows of some envs depending on the step.

    Remembers ``info["elapsed_steps"]`` of the latest reset/step; subclasses say which envs
    are frozen (`_frozen_mask`) and what their rows become (`_frozen_rows`).
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.current_steps: Any = None

    def reset(self, **kwargs: Any):
        """Reset the env and remember ``info["elapsed_steps"]``."""
        obs, info = self.env.reset(**kwargs)
        self.current_steps = _elapsed_from_info(info)
        return obs, info

    def step(self, action: Any):
        """Step with the (possibly replaced) action and remember ``info["elapsed_steps"]``."""
        obs, reward, terminated, truncated, info = self.env.step(self.action(action))
        self.current_steps = _elapsed_from_info(info)
        return obs, reward, terminated, truncated, info

    def _frozen_mask(self) -> torch.Tensor | None:
        raise NotImplementedError

    def _frozen_rows(self, action: Any, mask: Any) -> Any:
        """Return `action` (already a private (B, dim) copy) with the masked rows replaced."""
        action[mask] = 0
        return action

    def action(self, action: Any) -> Any:
        """Return the action unchanged, or a copy with the rows of frozen envs replaced."""
        mask = self._frozen_mask()
        if mask is None or not bool(mask.any()):
            return action
        batch = int(mask.shape[0])
        if isinstance(action, torch.Tensor):
            out = action.reshape(1, -1).expand(batch, -1) if action.ndim == 1 else action
            out = out.clone()
            return self._frozen_rows(out, mask.to(out.device))
        arr = np.asarray(action)
        if arr.ndim == 1:
            arr = np.broadcast_to(arr, (batch, arr.shape[0]))
        return self._frozen_rows(np.array(arr, copy=True), mask.cpu().numpy())


class CurriculumPhaseNoopActionWrapper(_StepGatedActionWrapper):
    """Zero the whole action row of every env still in its cue or empty phase.

    Env i is frozen while ``elapsed_steps[i] < cue_steps_per_env[i] + empty_steps_per_env[i]``
    (the empty term is skipped if the env has no such attribute). Nothing happens before the
    first reset or if the env has no ``cue_steps_per_env``. If no env is frozen the action
    object is passed through unchanged; otherwise a copy is made (a 1-D action is broadcast
    to (B, dim) first) and torch stays torch, numpy stays numpy.
    """

    def _frozen_mask(self) -> torch.Tensor | None:
        if self.current_steps is None:
            return None
        base = self.env.unwrapped
        cue = getattr(base, "cue_steps_per_env", None)
        if cue is None:
            return None
        cue = torch.as_tensor(cue)
        limit = cue
        empty = getattr(base, "empty_steps_per_env", None)
        if empty is not None:
            limit = cue + torch.as_tensor(empty, device=cue.device)
        steps = _as_step_tensor(self.current_steps, limit.device)
        # The per-env attributes may be longer than B (allocated for the max num_envs).
        return steps < limit.reshape(-1)[: steps.shape[0]]


class CurriculumPhaseNoopActionWrapperPdJointPos(CurriculumPhaseNoopActionWrapper):
    """`CurriculumPhaseNoopActionWrapper` for ``pd_joint_pos``: frozen envs hold their pose.

    Under ``pd_joint_pos`` a zero action would drive every joint to 0, so the frozen rows
    become the current arm joint positions plus the gripper command that keeps the fingers
    where they are: ``clip((q_finger - 0.015) / 0.025, -1, 1)`` (Panda finger range
    -0.01 ... 0.04).
    """

    def _frozen_rows(self, action: Any, mask: Any) -> Any:
        qpos = self.env.unwrapped.agent.robot.get_qpos()
        arm_dim = action.shape[-1] - 1
        if isinstance(action, torch.Tensor):
            qpos = qpos.to(device=action.device, dtype=action.dtype)
            grip = ((qpos[:, -1] - _FINGER_CENTER) / _FINGER_HALF_RANGE).clamp(-1.0, 1.0)
            hold = torch.cat([qpos[:, :arm_dim], grip[:, None]], dim=-1)
        else:
            q = qpos.detach().cpu().numpy().astype(action.dtype, copy=False)
            grip = np.clip((q[:, -1] - _FINGER_CENTER) / _FINGER_HALF_RANGE, -1.0, 1.0)
            hold = np.concatenate([q[:, :arm_dim], grip[:, None]], axis=-1)
        action[mask] = hold[mask]
        return action


class InitialZeroActionWrapper(_StepGatedActionWrapper):
    """Zero the action rows of every env whose ``elapsed_steps`` is below ``n_initial_steps``."""

    def __init__(self, env: gym.Env, n_initial_steps: int = 1) -> None:
        super().__init__(env)
        self.n_initial_steps = int(n_initial_steps)

    def _frozen_mask(self) -> torch.Tensor | None:
        if self.current_steps is None:
            return None
        return _as_step_tensor(self.current_steps) < self.n_initial_steps


# ----------------------------------------------------------------------------------------
# CameraShutdownWrapper
# ----------------------------------------------------------------------------------------


class CameraShutdownWrapper(gym.Wrapper):
    """Black out the cameras once any env is past ``n_initial_steps`` steps.

    From then on every tensor under ``sensor_data/base_camera`` and
    ``sensor_data/hand_camera`` is multiplied by 0, and rendered frames are blanked to the
    right of the human-render camera's width (the sensor tiles of ``render_mode="all"``).
    """

    CAMERAS = ("base_camera", "hand_camera")

    def __init__(self, env: gym.Env, n_initial_steps: int = 19) -> None:
        super().__init__(env)
        self.n_initial_steps = int(n_initial_steps)
        self.current_steps: Any = None

    @property
    def shutdown_active(self) -> bool:
        """Whether any env is past ``n_initial_steps`` (cameras are off)."""
        if self.current_steps is None:
            return False
        return bool((_as_step_tensor(self.current_steps) > self.n_initial_steps).any())

    def _observation(self, obs: Any) -> Any:
        if not self.shutdown_active or not isinstance(obs, dict):
            return obs
        sensor_data = obs.get("sensor_data")
        if not isinstance(sensor_data, dict):
            return obs
        obs = dict(obs)
        # New dicts/tensors: the env may still own the originals.
        sensor_data = dict(sensor_data)
        for cam in self.CAMERAS:
            if isinstance(sensor_data.get(cam), dict):
                sensor_data[cam] = {k: v * 0 for k, v in sensor_data[cam].items()}
        obs["sensor_data"] = sensor_data
        return obs

    def reset(self, **kwargs: Any):
        """Reset and remember ``elapsed_steps``."""
        obs, info = self.env.reset(**kwargs)
        self.current_steps = _elapsed_from_info(info)
        return self._observation(obs), info

    def step(self, action: Any):
        """Step, remember ``elapsed_steps`` and black out the cameras if past the limit."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.current_steps = _elapsed_from_info(info)
        return self._observation(obs), reward, terminated, truncated, info

    def _render_width(self) -> int | None:
        configs = getattr(self.env.unwrapped, "_human_render_camera_configs", None)
        if isinstance(configs, dict) and configs:
            width = getattr(next(iter(configs.values())), "width", None)
            return int(width) if width is not None else None
        return None

    def render(self):
        """Render; once the cameras are off, blank everything right of the render camera."""
        frames = self.env.render()
        width = self._render_width()
        if (
            not isinstance(frames, (torch.Tensor, np.ndarray))
            or not self.shutdown_active
            or width is None
        ):
            return frames
        arr, batched = frames_to_uint8(frames)
        arr[:, :, width:] = 0
        return restore_batching(arr, batched)


# ----------------------------------------------------------------------------------------
# FlattenRGBDObservationWrapper
# ----------------------------------------------------------------------------------------


class FlattenRGBDObservationWrapper(gym.ObservationWrapper):
    """Flatten the dict observation of `StateOnlyTensorToDictWrapper` for policies.

    * ``rgb`` / ``depth``: concatenate each camera's ``rgb`` (and/or ``depth``) along the
      last axis, cameras in ``sensor_data`` order -> ``rgb`` (B, H, W, 3·n_cams), ``depth``,
      or with both ``rgbd`` (all rgb channels, then all depth channels).
    * ``joints``: ``proprio`` = ManiSkill's ``flatten_state_dict`` of ``{"extra", "agent"}``
      (rgb mode: [tcp_pose (7), qpos (9), qvel (9)]).
    * ``state``: ``state`` = the flattened remaining entries (a state-mode ``state`` tensor
      is kept as is).
    * ``oracle``: keep ``oracle_info``. ``task_cue`` is always kept. Either is dropped if it
      contains `MISSING_VALUE_SENTINEL`.

    Output key order: ``state``, ``proprio``, image key, ``task_cue``, ``oracle_info``. The
    canonical chain uses rgb=True, depth=False, state=False, oracle=False, joints=True and
    gets ``{"proprio": (B, 25), "rgb": (B, 128, 128, 6)}``. Unlike the reference this wrapper
    neither resets the env nor rewrites the base env's space: its space is derived from the
    wrapped env's ``observation_space``.
    """

    def __init__(
        self,
        env: gym.Env,
        rgb: bool = True,
        depth: bool = True,
        state: bool = True,
        oracle: bool = False,
        joints: bool = False,
    ) -> None:
        super().__init__(env)
        self.include_rgb = bool(rgb)
        self.include_depth = bool(depth)
        self.include_state = bool(state)
        self.include_oracle = bool(oracle)
        self.include_joints = bool(joints)
        from mani_skill.utils.common import flatten_state_dict

        self._flatten_state_dict = flatten_state_dict
        self._device = _env_device(env)
        _set_spaces(self, self._derive_space(env.observation_space))

    @property
    def _image_key(self) -> str | None:
        if self.include_rgb and self.include_depth:
            return "rgbd"
        if self.include_rgb:
            return "rgb"
        if self.include_depth:
            return "depth"
        return None

    def _derive_space(self, space: gym.Space) -> spaces.Dict:
        if not isinstance(space, spaces.Dict):
            raise TypeError(
                "FlattenRGBDObservationWrapper expects a Dict observation space; wrap the env "
                "with StateOnlyTensorToDictWrapper first"
            )
        entries = OrderedDict(space.spaces)
        cue_space = entries.pop("task_cue", None)
        oracle_space = entries.pop("oracle_info", None)
        sensor_space = entries.pop("sensor_data", None)
        entries.pop("sensor_param", None)
        n = _num_envs(self.env)
        out: OrderedDict[str, gym.Space] = OrderedDict()

        proprio_space = None
        if self.include_joints:
            parts = [entries.pop(k) for k in ("extra", "agent") if k in entries]
            dim = sum(_flat_dim(p) for p in parts)
            proprio_space = spaces.Box(-np.inf, np.inf, (n, dim), np.float32)
        if self.include_state:
            if list(entries) == ["state"] and isinstance(entries["state"], spaces.Box):
                out["state"] = entries["state"]
            else:
                dim = sum(_flat_dim(s) for s in entries.values())
                out["state"] = spaces.Box(-np.inf, np.inf, (n, dim), np.float32)
        if proprio_space is not None:
            out["proprio"] = proprio_space

        key = self._image_key
        if key is not None:
            if not isinstance(sensor_space, spaces.Dict) or not sensor_space.spaces:
                raise ValueError(
                    "FlattenRGBDObservationWrapper(rgb/depth=True) needs camera data in the "
                    "observation; create the env with obs_mode='rgb'"
                )
            channels, hw, dtypes = 0, None, []
            for kind in (["rgb"] if self.include_rgb else []) + (
                ["depth"] if self.include_depth else []
            ):
                for cam, cam_space in sensor_space.spaces.items():
                    if kind not in cam_space.spaces:
                        raise ValueError(
                            f"camera {cam!r} has no {kind!r} data; create the env with an "
                            f"obs_mode that includes {kind}"
                        )
                    box = cam_space.spaces[kind]
                    hw = hw or box.shape[1:3]
                    channels += box.shape[-1]
                    dtypes.append(box.dtype)
            dtype = np.result_type(*dtypes)
            if key == "rgb":
                out[key] = spaces.Box(0, 255, (n, *hw, channels), np.uint8)
            else:
                out[key] = _box_for((n, *hw, channels), dtype)

        if cue_space is not None and not _is_sentinel_space(cue_space):
            out["task_cue"] = cue_space
        if (
            self.include_oracle
            and oracle_space is not None
            and not _is_sentinel_space(oracle_space)
        ):
            out["oracle_info"] = oracle_space
        return spaces.Dict(out)

    def _flatten(self, d: dict) -> torch.Tensor:
        return self._flatten_state_dict(d, use_torch=True, device=self._device)

    def observation(self, observation: dict) -> dict:
        """Return the flattened observation (see the class docstring for the keys)."""
        obs = dict(observation)
        oracle = obs.pop("oracle_info", None)
        cue = obs.pop("task_cue", None)
        sensor_data = obs.pop("sensor_data", None)
        obs.pop("sensor_param", None)
        out: dict[str, Any] = {}

        proprio = None
        if self.include_joints:
            parts = {k: obs.pop(k) for k in ("extra", "agent") if k in obs}
            proprio = self._flatten(parts)
        if self.include_state:
            if list(obs) == ["state"] and isinstance(obs["state"], torch.Tensor):
                out["state"] = obs["state"]
            else:
                out["state"] = self._flatten(obs)
        if proprio is not None:
            out["proprio"] = proprio

        key = self._image_key
        if key is not None:
            if sensor_data is None:
                raise ValueError(
                    "FlattenRGBDObservationWrapper(rgb/depth=True) needs camera data in the "
                    "observation; create the env with obs_mode='rgb'"
                )
            images = []
            if self.include_rgb:
                images += [cam["rgb"] for cam in sensor_data.values()]
            if self.include_depth:
                images += [cam["depth"] for cam in sensor_data.values()]
            out[key] = images[0] if len(images) == 1 else _concat_last_dim(images)

        if cue is not None and not _contains_sentinel(cue):
            out["task_cue"] = cue
        if self.include_oracle and oracle is not None and not _contains_sentinel(oracle):
            out["oracle_info"] = oracle
        return out


def _concat_last_dim(tensors: list[torch.Tensor]) -> torch.Tensor:
    """``torch.cat(tensors, dim=-1)``; for CPU tensors through numpy, in this thread: torch
    hands copies of this size (100k values) to its thread pool, whose threads then spin
    between steps (one env kept all 16 cores of a GPU machine busy and ran 20% slower)."""
    if all(t.device.type == "cpu" and not t.requires_grad for t in tensors):
        return torch.from_numpy(np.concatenate([t.numpy() for t in tensors], axis=-1))
    return torch.cat(tensors, dim=-1)


# ----------------------------------------------------------------------------------------
# ConvertJointsToEEFXyzRpyGripperWrapper
# ----------------------------------------------------------------------------------------


def _quat_wxyz_to_rpy_torch(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    w, x, y, z = q.unbind(-1)
    roll = torch.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = torch.asin((2 * (w * y - z * x)).clamp(-1.0, 1.0))
    yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return torch.stack([roll, pitch, yaw], dim=-1)


def _quat_wxyz_to_rpy_numpy(q: np.ndarray) -> np.ndarray:
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-8)
    w, x, y, z = (q[..., i] for i in range(4))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1).astype(np.float32)


class ConvertJointsToEEFXyzRpyGripperWrapper(gym.ObservationWrapper):
    """Turn ``proprio`` = [tcp_pose (7), qpos (n), qvel (n), ...] into 7 values.

    Output: [x, y, z, roll, pitch, yaw, gripper] float32: TCP position (world frame),
    fixed-axes x-y-z Euler angles of the normalised wxyz quaternion (R = Rz(yaw)·Ry(pitch)
    ·Rx(roll), same as ``transforms3d.euler.quat2euler(q, "sxyz")``), and the sum of the
    last ``gripper_finger_dims`` qpos entries (Panda: finger opening in metres).

    ``qpos_dim`` defaults to the robot's qpos length (9 for the Panda), else it is inferred
    from the vector length. Non-dict observations, dicts without ``proprio`` and proprio
    vectors that already have 7 values pass through. Torch stays torch, numpy stays numpy.
    """

    def __init__(
        self, env: gym.Env, qpos_dim: int | None = None, gripper_finger_dims: int = 2
    ) -> None:
        super().__init__(env)
        if gripper_finger_dims <= 0:
            raise ValueError(f"gripper_finger_dims must be positive, got {gripper_finger_dims}")
        self.gripper_finger_dims = int(gripper_finger_dims)
        if qpos_dim is None:
            try:
                qpos_dim = int(env.unwrapped.agent.robot.get_qpos().shape[-1])
            except Exception:  # no ManiSkill agent (e.g. a test double): infer per call
                qpos_dim = None
        self.qpos_dim = qpos_dim
        space = env.observation_space
        if isinstance(space, spaces.Dict) and isinstance(space.spaces.get("proprio"), spaces.Box):
            entries = OrderedDict(space.spaces)
            lead = entries["proprio"].shape[:-1]
            entries["proprio"] = spaces.Box(-np.inf, np.inf, (*lead, 7), np.float32)
            _set_spaces(self, spaces.Dict(entries))

    def _qpos_len(self, dim: int) -> int:
        if dim < 7:
            raise RuntimeError(f"proprio has {dim} values; expected [tcp_pose(7), qpos, qvel]")
        rest = dim - 7
        if self.qpos_dim is not None:
            if 7 + self.qpos_dim > dim:
                raise RuntimeError(
                    f"proprio has {dim} values, too few for tcp_pose (7) + qpos ({self.qpos_dim})"
                )
            n = self.qpos_dim
        else:
            n = rest // 2 if rest % 2 == 0 else rest
        if n < 1:
            raise RuntimeError(f"proprio of {dim} values has no qpos entries")
        return n

    def convert(self, proprio: Any) -> Any:
        """Convert one proprio tensor/array (any leading dims) to the 7-value layout."""
        if isinstance(proprio, torch.Tensor):
            p = proprio if proprio.dtype == torch.float32 else proprio.float()
            if p.shape[-1] == 7:
                return p
            n = self._qpos_len(p.shape[-1])
            k = min(self.gripper_finger_dims, n)
            grip = p[..., 7 + n - k : 7 + n].sum(dim=-1, keepdim=True)
            return torch.cat([p[..., :3], _quat_wxyz_to_rpy_torch(p[..., 3:7]), grip], dim=-1)
        p = np.asarray(proprio, dtype=np.float32)
        if p.shape[-1] == 7:
            return p
        n = self._qpos_len(p.shape[-1])
        k = min(self.gripper_finger_dims, n)
        grip = p[..., 7 + n - k : 7 + n].sum(axis=-1, keepdims=True)
        return np.concatenate([p[..., :3], _quat_wxyz_to_rpy_numpy(p[..., 3:7]), grip], axis=-1)

    def observation(self, observation: Any) -> Any:
        """Replace ``proprio`` by its 7-value form; anything else passes through."""
        if not isinstance(observation, dict) or "proprio" not in observation:
            return observation
        obs = dict(observation)
        obs["proprio"] = self.convert(obs["proprio"])
        return obs
