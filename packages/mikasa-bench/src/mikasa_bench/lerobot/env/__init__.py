"""``lerobot-eval`` on MIKASA tasks: the ``mikasa`` env type for lerobot 0.4.x.

lerobot 0.4.4's ``lerobot-eval`` builds its envs with ``lerobot.envs.factory.make_env``.
Of the ways it offers to add an env, this one works offline with a local install:

* an ``EnvConfig`` subclass registered as ``mikasa`` (`MikasaEnv`), found through
  lerobot's plugin discovery ``--env.discover_packages_path=mikasa_bench.lerobot.env``
  (``lerobot.configs.parser.load_plugin`` imports a *package* and its submodules, hence
  this package). ``make_env`` then imports `MikasaEnv.package_name` (this package) and
  calls ``gym.make(MikasaEnv.gym_id, **MikasaEnv.gym_kwargs)`` per vector-env slot.
* Not EnvHub: ``make_env(<hub id>, trust_remote_code=True)`` and `HubEnvConfig` fetch
  ``env.py`` with ``hf_hub_download``, which needs a Hub repo id (no local directory), and
  ``lerobot-eval`` parses ``--env`` into an ``EnvConfig`` only.

The gym id `GYM_ID` is registered without ``OrderEnforcing``/``TimeLimit`` wrappers, so the
vector env's slots are `MikasaLeRobotEnv` itself: lerobot's ``add_envs_task`` looks for
``task_description`` on ``env.envs[0]`` (attributes are not forwarded through gymnasium 1.x
wrappers) and its rollout reads ``_max_episode_steps`` through ``env.call``.

`MikasaLeRobotEnv` builds the task with `mikasa_bench.make_benchmark_env` (the protocol's
``gym.make`` arguments and the canonical wrapper chain) and gives what lerobot's rollout
expects of a single (non-vector) env::

    observation  {"pixels": {"top": uint8 (128, 128, 3), "wrist": uint8 (128, 128, 3)},
                  "agent_pos": float32 (7,)}      -> preprocess_observation ->
                 observation.images.top / observation.images.wrist / observation.state
    info         {"is_success": bool (the success latch of the episode so far), "success": bool}
    task_description / task   the language instruction / the env id
    render()     the two cameras side by side, (128, 256, 3) uint8 (lerobot-eval's videos)

Usage (see packages/mikasa-bench/README.md, "LeRobot policies and lerobot-eval")::

    lerobot-eval --env.discover_packages_path=mikasa_bench.lerobot.env --env.type=mikasa \\
        --env.task=RememberColor3-VLA-v0 --policy.path=DIR --eval.n_episodes=50 \\
        --eval.batch_size=1 --seed=4242424242
    python -m mikasa_bench.lerobot.env ...   # the same, after checking the policy's features
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.lerobot.policy import (
    ACTION_KEY,
    IMAGE_SIZE,
    STATE_KEY,
    TOP_KEY,
    WRIST_KEY,
    import_lerobot,
    load_policy_config,
    task_instruction,
)
from mikasa_bench.media.render import apply_environment, check_render_device, worker_environment
from mikasa_bench.protocol import RENDER_DEVICES, BenchmarkConfig
from mikasa_bench.runners.episode import first_value, make_benchmark_env

import_lerobot()  # before lerobot's first import: offline, torchvision importable

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium import spaces  # noqa: E402
from lerobot.configs.types import FeatureType, PolicyFeature  # noqa: E402
from lerobot.envs.configs import EnvConfig  # noqa: E402

__all__ = ["ENV_TYPE", "GYM_ID", "MikasaEnv", "MikasaLeRobotEnv", "main"]

ENV_TYPE = "mikasa"
"""``--env.type`` of the MIKASA tasks."""
GYM_ID = "mikasa_bench/MikasaLeRobot-v0"
"""The gym id `MikasaEnv.gym_id` names (one id for every task: the task is a kwarg)."""
DEFAULT_TASK = "RememberColor3-VLA-v0"
FPS = 10
"""The control rate of the MIKASA datasets (LeRobot ``fps``; spec §7.1)."""


def _image_feature() -> PolicyFeature:
    return PolicyFeature(type=FeatureType.VISUAL, shape=(IMAGE_SIZE, IMAGE_SIZE, 3))


@EnvConfig.register_subclass(ENV_TYPE)
@dataclass
class MikasaEnv(EnvConfig):
    """A MIKASA-Robo-VLA task for ``lerobot-eval`` (``--env.type=mikasa``).

    ``task``: a MIKASA VLA env id. ``episode_length``: defaults to the task's
    ``max_episode_steps`` (it may only be shortened). ``sim_backend``: ManiSkill's physics
    backend (``cpu``, as mikasa-bench's workers). ``render_device``: ``auto``, ``cpu`` or
    ``gpu`` (mikasa-bench's ``--render-device``).
    """

    task: str | None = DEFAULT_TASK
    fps: int = FPS
    episode_length: int | None = None
    sim_backend: str = "cpu"
    render_device: str = "auto"
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {
            ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(7,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(7,)),
            "pixels/top": _image_feature(),
            "pixels/wrist": _image_feature(),
        }
    )
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION_KEY: ACTION_KEY,
            "agent_pos": STATE_KEY,
            "pixels/top": TOP_KEY,
            "pixels/wrist": WRIST_KEY,
        }
    )

    def __post_init__(self) -> None:
        import mikasa_envs

        if not self.task:
            raise ValueError(f"--env.task is required: a MIKASA VLA env id such as {DEFAULT_TASK}")
        try:
            horizon = int(mikasa_envs.get_task(self.task).max_episode_steps)
        except Exception as exc:
            raise ValueError(f"--env.task={self.task!r}: {exc}") from None
        if self.episode_length is None:
            self.episode_length = horizon
        elif not 0 < self.episode_length <= horizon:
            raise ValueError(
                f"--env.episode_length={self.episode_length}: {self.task} runs at most {horizon} "
                f"steps (its max_episode_steps); choose 1..{horizon}"
            )
        if self.render_device not in RENDER_DEVICES:
            raise ValueError(
                f"--env.render_device={self.render_device!r}; expected one of {', '.join(RENDER_DEVICES)}"
            )

    @property
    def package_name(self) -> str:
        """What ``make_env`` imports if `GYM_ID` is not registered yet: this package."""
        return __name__

    @property
    def gym_id(self) -> str:
        """The gym id ``make_env`` passes to ``gym.make``."""
        return GYM_ID

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        """The kwargs ``make_env`` passes to ``gym.make`` (to `MikasaLeRobotEnv`)."""
        return {
            "env_id": self.task,
            "episode_length": self.episode_length,
            "sim_backend": self.sim_backend,
            "render_device": self.render_device,
            "fps": self.fps,
        }


class MikasaLeRobotEnv(gym.Env):
    """One MIKASA task (canonical chain, ``num_envs=1``) as the single, numpy env that
    lerobot's vector-env rollout steps (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": FPS}

    def __init__(
        self,
        env_id: str = DEFAULT_TASK,
        episode_length: int | None = None,
        sim_backend: str = "cpu",
        render_device: str = "auto",
        fps: int = FPS,
        render_mode: str | None = "rgb_array",
    ) -> None:
        import torch

        # As mikasa-bench's workers: restrict Vulkan to lavapipe before the first env of
        # the process when rendering on the CPU is asked for (no-op otherwise).
        apply_environment(worker_environment(render_device))
        self._env = make_benchmark_env(
            env_id, BenchmarkConfig(sim_backend=sim_backend, render_device=render_device)
        )
        check_render_device(self._env, render_device)
        self.metadata = {**self.metadata, "render_fps": int(fps)}
        self.render_mode = render_mode
        self.task = env_id
        self.task_description = task_instruction(None, env_id)
        horizon = int(self._env.max_episode_steps)
        self._max_episode_steps = min(int(episode_length or horizon), horizon)
        self._device = getattr(self._env.unwrapped, "device", None) or torch.device("cpu")
        inner = self._env.action_space
        self.action_space = spaces.Box(
            low=np.asarray(inner.low, dtype=np.float32),
            high=np.asarray(inner.high, dtype=np.float32),
            dtype=np.float32,
        )
        image = spaces.Box(0, 255, (IMAGE_SIZE, IMAGE_SIZE, 3), dtype=np.uint8)
        self.observation_space = spaces.Dict(
            {
                "pixels": spaces.Dict({"top": image, "wrist": image}),
                "agent_pos": spaces.Box(-np.inf, np.inf, (7,), dtype=np.float32),
            }
        )
        self._last: dict[str, Any] | None = None
        self._steps = 0
        self._success = False

    def _observation(self, obs: dict[str, Any]) -> dict[str, Any]:
        rgb = obs["rgb"][0].cpu().numpy()
        out = {
            "pixels": {
                "top": np.ascontiguousarray(rgb[..., 0:3]),
                "wrist": np.ascontiguousarray(rgb[..., 3:6]),
            },
            "agent_pos": obs["proprio"][0].cpu().numpy().astype(np.float32),
        }
        self._last = out
        return out

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Reset the task (``seed`` as mikasa-bench's episode seed)."""
        super().reset(seed=seed)
        obs, _ = self._env.reset(seed=None if seed is None else int(seed), options=options)
        self._steps = 0
        self._success = False
        return self._observation(obs), {"is_success": False, "success": False}

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        """One control step; ``info["is_success"]`` is the episode's success latch (the
        benchmark's ``success_once``: lerobot-eval reads it when the episode ends)."""
        import torch

        a = torch.as_tensor(
            np.asarray(action, dtype=np.float32).reshape(1, -1), device=self._device
        )
        obs, reward, terminated, truncated, info = self._env.step(a)
        self._steps += 1
        success = bool(first_value(info.get("success", False)))
        self._success = self._success or success
        truncated = bool(first_value(truncated)) or self._steps >= self._max_episode_steps
        return (
            self._observation(obs),
            float(first_value(reward)),
            bool(first_value(terminated)),
            truncated,
            {"is_success": self._success, "success": success},
        )

    def render(self) -> np.ndarray:
        """The policy's two cameras side by side (top | wrist), (128, 256, 3) uint8."""
        if self._last is None:
            return np.zeros((IMAGE_SIZE, 2 * IMAGE_SIZE, 3), dtype=np.uint8)
        pixels = self._last["pixels"]
        return np.concatenate([pixels["top"], pixels["wrist"]], axis=1)

    def close(self) -> None:
        """Close the MIKASA env."""
        env, self._env = getattr(self, "_env", None), None
        if env is not None:
            env.close()


if GYM_ID not in gym.registry:
    # No OrderEnforcing / TimeLimit around the env (module docstring); the env truncates
    # at its own episode_length.
    gym.register(
        id=GYM_ID,
        entry_point=MikasaLeRobotEnv,
        order_enforce=False,
        disable_env_checker=True,
    )


def main() -> None:
    """``python -m mikasa_bench.lerobot.env ARGS``: ``lerobot-eval ARGS`` with the ``mikasa``
    env type registered, in a process where torchvision was made importable first.

    A ``--policy.path`` whose features do not fit MIKASA stops here, with mikasa-bench's
    message naming both sides (exit code 2), before lerobot-eval builds anything.
    """
    from lerobot.configs.parser import get_path_arg
    from lerobot.scripts.lerobot_eval import main as lerobot_eval_main

    path = get_path_arg("policy")
    if path and Path(path).expanduser().is_dir():  # a Hub id is lerobot-eval's to resolve
        try:
            load_policy_config(path, device="cpu")  # device: only the features are checked
        except BenchError as exc:
            print(f"error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
    lerobot_eval_main()
