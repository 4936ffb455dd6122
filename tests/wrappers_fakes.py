"""Small batched gym envs that mimic a ManiSkill VLA env, for the mikasa-wrappers tests.

They return torch tensors shaped like ManiSkill's ``obs_mode="rgb"`` observation and
expose the attributes the wrappers read (``task_cue``, ``oracle_info``,
``cue_steps_per_env``, ...), without any simulation. Also the assertion helpers that
several of the wrapper test files share (`_ref_rpy`, `_changed`).
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec
from transforms3d.euler import quat2euler

CAM = 16  # camera resolution of the fake (small: the wrappers do not care)
RENDER_HW = (480, 640)


class FakeVLAEnv(gym.Env):
    """A batched env with ManiSkill's rgb-mode observation layout.

    ``tcp_pose`` and ``qpos`` can be set through attributes before reset/step; camera
    ``base_camera`` is filled with 10 and ``hand_camera`` with 200 so the channel order of
    the flattened ``rgb`` can be checked. Every action handed to ``step`` is recorded.
    """

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(
        self,
        num_envs: int = 3,
        env_id: str | None = "RememberColor3-VLA-v0",
        obs_mode: str = "rgb",
        max_episode_steps: int | None = 25,
        cameras: tuple[str, ...] = ("base_camera", "hand_camera"),
        render_dtype: str = "uint8",
    ) -> None:
        self.num_envs = num_envs
        self.device = torch.device("cpu")
        self.obs_mode = obs_mode
        self.control_mode = "pd_ee_delta_pose"
        self.render_mode = "rgb_array"
        self.cameras = cameras
        self.render_dtype = render_dtype
        self.spec = (
            EnvSpec(env_id, entry_point=None, max_episode_steps=max_episode_steps)
            if env_id
            else None
        )
        b = num_envs
        self.action_space = spaces.Box(-1, 1, (b, 7), np.float32)
        self.single_action_space = spaces.Box(-1, 1, (7,), np.float32)
        if obs_mode == "state":
            self.observation_space = spaces.Box(-np.inf, np.inf, (b, 25), np.float32)
        else:
            f = lambda *s: spaces.Box(-np.inf, np.inf, (b, *s), np.float32)  # noqa: E731
            self.observation_space = spaces.Dict(
                {
                    "agent": spaces.Dict({"qpos": f(9), "qvel": f(9)}),
                    "extra": spaces.Dict({"tcp_pose": f(7)}),
                    "sensor_param": spaces.Dict(
                        {c: spaces.Dict({"intrinsic_cv": f(3, 3)}) for c in cameras}
                    ),
                    "sensor_data": spaces.Dict(
                        {
                            c: spaces.Dict({"rgb": spaces.Box(0, 255, (b, CAM, CAM, 3), np.uint8)})
                            for c in cameras
                        }
                    ),
                }
            )
        # Attributes the wrappers read.
        self.task_cue: Any = None
        self.oracle_info: Any = torch.arange(b, dtype=torch.uint8)
        self.cue_steps_per_env: Any = None
        self.empty_steps_per_env: Any = None
        # Controllable state.
        self.tcp_pose = torch.tensor([[0.1, -0.2, 0.3, 0.0, 1.0, 0.0, 0.0]]).repeat(b, 1)
        self.qpos = torch.tensor([[0.0, 0.1, 0.2, -2.0, 0.0, 2.0, 0.8, 0.03, 0.025]]).repeat(b, 1)
        self.elapsed = torch.zeros(b, dtype=torch.int32)
        self.actions: list[Any] = []
        self.reset_calls = 0
        self.info_extra: dict[str, Any] = {}
        self.reward_value = torch.full((b,), 0.25)
        self.agent = SimpleNamespace(robot=SimpleNamespace(get_qpos=lambda: self.qpos.clone()))

    def _obs(self) -> Any:
        b = self.num_envs
        if self.obs_mode == "state":
            return torch.cat([self.qpos, self.qpos * 0, self.tcp_pose], dim=-1)
        fills = {"base_camera": 10, "hand_camera": 200}
        return {
            "agent": {"qpos": self.qpos.clone(), "qvel": torch.zeros(b, 9)},
            "extra": {"tcp_pose": self.tcp_pose.clone()},
            "sensor_param": {
                c: {"intrinsic_cv": torch.eye(3).repeat(b, 1, 1)} for c in self.cameras
            },
            "sensor_data": {
                c: {"rgb": torch.full((b, CAM, CAM, 3), fills.get(c, 50), dtype=torch.uint8)}
                for c in self.cameras
            },
        }

    def _info(self) -> dict:
        info = {
            "elapsed_steps": self.elapsed.clone(),
            "success": torch.zeros(self.num_envs, dtype=torch.bool),
            "task_cue": self.task_cue,
            "oracle_info": self.oracle_info,
            "language_instruction": "do the thing",
        }
        info.update(self.info_extra)
        return info

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.reset_calls += 1
        self.elapsed = torch.zeros(self.num_envs, dtype=torch.int32)
        return self._obs(), self._info()

    def step(self, action: Any):
        self.actions.append(action)
        self.elapsed = self.elapsed + 1
        b = self.num_envs
        return (
            self._obs(),
            self.reward_value.clone(),
            torch.zeros(b, dtype=torch.bool),
            torch.zeros(b, dtype=torch.bool),
            self._info(),
        )

    def render(self):
        frames = torch.full((self.num_envs, *RENDER_HW, 3), 100, dtype=torch.uint8)
        if self.render_dtype == "float":
            return frames.float() / 255.0
        return frames


# ----------------------------------------------------------------------------------------
# assertion helpers shared by the wrapper test files
# ----------------------------------------------------------------------------------------


def _ref_rpy(q_wxyz):
    return np.array(quat2euler(np.asarray(q_wxyz, np.float64), "sxyz"))


def _changed(raw, out, env_index=0, region=None):
    a, b = raw[env_index], out[env_index]
    if region is not None:
        (y0, y1), (x0, x1) = region
        a, b = a[y0:y1, x0:x1], b[y0:y1, x0:x1]
    return bool((a != b).any())
