"""Observation wrappers of the chain: `StateOnlyTensorToDictWrapper` (dict obs with
``task_cue`` / ``oracle_info``), `FlattenRGBDObservationWrapper` (policy-ready keys) and
`ConvertJointsToEEFXyzRpyGripperWrapper` (7-value proprio).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from ._wrapper_helpers import (
    MISSING_VALUE_SENTINEL,
    box_for,
    contains_sentinel,
    env_device,
    flat_dim,
    is_sentinel_space,
    num_envs_of,
    sentinel_space,
    set_observation_spaces,
    torch_to_numpy_dtype,
)

__all__ = [
    "StateOnlyTensorToDictWrapper",
    "FlattenRGBDObservationWrapper",
    "ConvertJointsToEEFXyzRpyGripperWrapper",
]


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
        n = num_envs_of(env)
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
        set_observation_spaces(self, spaces.Dict(entries))

    @staticmethod
    def _space_of(value: Any, n: int) -> spaces.Box:
        if value is None:
            return sentinel_space(n)
        if isinstance(value, torch.Tensor):
            dtype = torch_to_numpy_dtype(value.dtype)
            shape = tuple(value.shape)
        else:
            arr = np.asarray(value)
            dtype, shape = arr.dtype, arr.shape
        per_env = (1,) if len(shape) <= 1 else shape[1:]
        return box_for((n, *per_env), dtype)

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
            batch, device = num_envs_of(self.env), env_device(self.env)
        base = self.env.unwrapped
        obs["task_cue"] = self._entry(getattr(base, "task_cue", None), batch, device)
        obs["oracle_info"] = self._entry(getattr(base, "oracle_info", None), batch, device)
        return obs


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
        self._device = env_device(env)
        set_observation_spaces(self, self._derive_space(env.observation_space))

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
        n = num_envs_of(self.env)
        out: OrderedDict[str, gym.Space] = OrderedDict()

        proprio_space = None
        if self.include_joints:
            parts = [entries.pop(k) for k in ("extra", "agent") if k in entries]
            dim = sum(flat_dim(p) for p in parts)
            proprio_space = spaces.Box(-np.inf, np.inf, (n, dim), np.float32)
        if self.include_state:
            if list(entries) == ["state"] and isinstance(entries["state"], spaces.Box):
                out["state"] = entries["state"]
            else:
                dim = sum(flat_dim(s) for s in entries.values())
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
                out[key] = box_for((n, *hw, channels), dtype)

        if cue_space is not None and not is_sentinel_space(cue_space):
            out["task_cue"] = cue_space
        if self.include_oracle and oracle_space is not None and not is_sentinel_space(oracle_space):
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

        if cue is not None and not contains_sentinel(cue):
            out["task_cue"] = cue
        if self.include_oracle and oracle is not None and not contains_sentinel(oracle):
            out["oracle_info"] = oracle
        return out


def _concat_last_dim(tensors: list[torch.Tensor]) -> torch.Tensor:
    """``torch.cat(tensors, dim=-1)``; for CPU tensors through numpy, in this thread: torch
    hands copies of this size (100k values) to its thread pool, whose threads then spin
    between steps (one env kept all 16 cores of a machine with a GPU busy and ran 20% slower)."""
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
            set_observation_spaces(self, spaces.Dict(entries))

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
