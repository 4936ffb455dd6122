"""The base class every MIKASA-Robo-VLA task derives from.

It holds what ``common.md`` says all tasks share: the Panda on the ManiSkill table, the two
128x128 sensor cameras, the robot's initial joint configuration and noise, the
cue / memory / action phase timing drawn from the episode seed, the language instruction,
``task_cue`` / ``oracle_info``, reward normalisation and input validation, and the saving and
restoring of each task's own state with ManiSkill's state API (``get_state_dict`` /
``set_state_dict``; see ``TASK_STATE``).
"""

from __future__ import annotations

import gc
from typing import Any, ClassVar

import numpy as np
import sapien
import torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import common, sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.types import GPUMemoryConfig, SimConfig

from mikasa_envs import render_batcher, task_state
from mikasa_envs.building_blocks.ground import coarsen_ground_visual
from mikasa_envs.camera_group import (
    CameraGroupRenderer,
    SceneCameras,
    env_cameras,
    env_render_device,
    read_rgb_pictures,
    renders_on_cuda,
    rgb_cameras_readable,
)
from mikasa_envs.robot import LightPandaWristCam

ROBOT_ROOT_POSITION = (-0.615, 0.0, 0.0)
# Arm joints, then both fingers fully open.
ROBOT_INIT_QPOS = np.array(
    [0.0, 0.0, 0.0, -2 * np.pi / 3, 0.0, 2 * np.pi / 3, np.pi / 4, 0.04, 0.04]
)
NUM_ARM_JOINTS = 7

OBS_MODES: tuple[str, ...] = ("state", "state_dict", "rgb", "rgbd", "sensor_data", "none")
REWARD_MODES: tuple[str, ...] = ("normalized_dense", "dense", "sparse", "none")


class MikasaVLABaseEnv(BaseEnv):
    """Shared scene, cameras, robot reset, phase timing and bookkeeping of all VLA tasks.

    Subclasses set the class constants, build their objects in ``_load_scene`` (after
    calling ``super()._load_scene``), draw their layout in ``_sample_episode`` and may
    post-process it in ``_after_phase_sampling``; see ``_initialize_episode`` for the order
    of random draws (``common.md`` §11).
    """

    SUPPORTED_ROBOTS: ClassVar[list[str]] = ["panda", "panda_wristcam"]
    SUPPORTED_REWARD_MODES = REWARD_MODES

    LANGUAGE_INSTRUCTION: ClassVar[str] = ""
    # Inclusive [lo, hi] ranges of the cue and empty (memory delay) phases, in steps.
    CUE_PHASE_STEPS: ClassVar[tuple[int, int]] = (1, 5)
    EMPTY_PHASE_STEPS: ClassVar[tuple[int, int]] = (1, 5)
    # The dense reward of a success step; normalized_dense divides by it unless a variant
    # gives its own divisor (NORMALIZED_DENSE_DIVISOR: the RL release divides some families by
    # another constant while their success step keeps this value).
    DENSE_REWARD_MAX: ClassVar[float] = 3.0
    NORMALIZED_DENSE_DIVISOR: ClassVar[float | None] = None
    # The smoothness penalty's coefficients (`smoothness_penalty`), set by the families that use it.
    ACTION_L2_COEF: ClassVar[float]
    ACTION_DELTA_L2_COEF: ClassVar[float]
    QVEL_L2_COEF: ClassVar[float]

    SENSOR_SIZE: ClassVar[int] = 128
    # GPU PhysX buffers a family raises above ManiSkill's defaults (upstream's values),
    # e.g. {"found_lost_pairs_capacity": 2**25}; used by the GPU sim only.
    GPU_MEMORY: ClassVar[dict[str, int]] = {}
    BASE_CAMERA_EYE: ClassVar[tuple[float, float, float]] = (0.3, 0.0, 0.6)
    BASE_CAMERA_TARGET: ClassVar[tuple[float, float, float]] = (-0.1, 0.0, 0.1)
    RENDER_CAMERA_EYE: ClassVar[tuple[float, float, float]] = (0.5, 1.0, 1.0)
    RENDER_CAMERA_TARGET: ClassVar[tuple[float, float, float]] = (-0.3, 0.0, 0.0)

    # ---- saved state (get_state_dict / set_state_dict) ----
    # The task's own per-episode state, saved next to ManiSkill's simulation state under
    # "task" and restored by set_state_dict: every attribute that changes during an episode
    # and that stepping reads (phase lengths, the answer, layouts, latches, counters, what a
    # lamp or button shows). Each class names the attributes it adds (the lists are
    # collected over the MRO, mixins included): tensors with one row per env, dicts or lists
    # of them, or building blocks that name their tensors in STATE_ATTRS. ManiSkill's
    # elapsed-step counter, which the phases read, is saved too ("elapsed_steps").
    TASK_STATE: ClassVar[tuple[str, ...]] = (
        "cue_steps_per_env",
        "empty_steps_per_env",
        "task_cue",
        "oracle_info",
        "_prev_action",
    )
    # Attributes that change during an episode but are deliberately not saved: caches that
    # `_on_state_restored` drops or rebuilds, and the previous step's reward terms
    # (info["reward_dict"] is one step stale: None on the first step after a restore, as
    # after a reset). tests/test_save_restore.py fails on any other attribute that differs
    # after a restore, so a new family cannot silently leave state out.
    TRANSIENT_STATE: ClassVar[tuple[str, ...]] = ("_reward_dict",)

    agent: LightPandaWristCam

    def __init__(
        self,
        *args: Any,
        robot_uids: str = "panda_wristcam",
        robot_init_qpos_noise: float = 0.02,
        **kwargs: Any,
    ) -> None:
        if robot_uids not in self.SUPPORTED_ROBOTS:
            raise UnsupportedRobotError(
                f"robot_uids={robot_uids!r} is not supported by {type(self).__name__}; "
                f"accepted values: {', '.join(self.SUPPORTED_ROBOTS)}"
            )
        _check_mode("obs_mode", kwargs.get("obs_mode"), OBS_MODES, allow_texture_combos=True)
        _check_mode("reward_mode", kwargs.get("reward_mode"), REWARD_MODES)
        self.robot_init_qpos_noise = robot_init_qpos_noise
        self.task_cue: torch.Tensor | None = None
        self.oracle_info: torch.Tensor | None = None
        self._reward_dict: dict[str, torch.Tensor] | None = None
        self._camera_group: CameraGroupRenderer | None = None
        self._camera_view: SceneCameras | None | bool = False  # False: not checked for this scene
        self._render_on_gpu = False  # with _camera_view: through a camera group
        try:
            super().__init__(*args, robot_uids=robot_uids, **kwargs)
        except AssertionError as err:
            # ManiSkill asserts on an unknown control mode; name the accepted ones.
            if "control_mode" in kwargs and "supported" in str(err).lower():
                raise ValueError(f"unknown control_mode: {err}") from None
            raise

    # ------------------------------------------------------------------ scene
    @property
    def _default_sensor_configs(self) -> list[CameraConfig]:
        pose = sapien_utils.look_at(eye=self.BASE_CAMERA_EYE, target=self.BASE_CAMERA_TARGET)
        size = self.SENSOR_SIZE
        return [CameraConfig("base_camera", pose, size, size, np.pi / 2, 0.01, 100)]

    @property
    def _default_human_render_camera_configs(self) -> CameraConfig:
        pose = sapien_utils.look_at(eye=self.RENDER_CAMERA_EYE, target=self.RENDER_CAMERA_TARGET)
        return CameraConfig("render_camera", pose, 512, 512, 1.0, 0.01, 100)

    def _load_agent(self, options: dict) -> None:
        # The wrist-camera Panda is loaded with a light housing mesh (see robot.py); the uid
        # stays "panda_wristcam" so scene builders and users see the usual robot.
        robot_uids = self.robot_uids
        if robot_uids == "panda_wristcam":
            self.robot_uids = LightPandaWristCam
        try:
            super()._load_agent(options, sapien.Pose(p=ROBOT_ROOT_POSITION))
        finally:
            self.robot_uids = robot_uids

    def _load_scene(self, options: dict) -> None:
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()
        coarsen_ground_visual(self.table_scene.ground)  # same look, 1% of the triangles
        n = self.num_envs
        self.cue_steps_per_env = torch.zeros(n, dtype=torch.int64, device=self.device)
        self.empty_steps_per_env = torch.zeros(n, dtype=torch.int64, device=self.device)
        # The previous action of the smoothness penalty (zeros until the first step); a
        # tensor from the start so that every saved state has it.
        action_shape = getattr(self.agent.single_action_space, "shape", None) or (0,)
        self._prev_action: torch.Tensor | None = torch.zeros(n, int(np.prod(action_shape)), device=self.device)

    def _clear(self) -> None:
        # ManiSkill's _clear (3.0.1) without its full gc.collect(), which `close` does
        # instead. _clear also runs at construction and on every reconfigure (a fresh
        # scene; the bench builds one every 5 episodes): there the collection took 0.2-0.3 s
        # of a 0.3 s rebuild, and without it memory stays flat (60 rebuilds: +36 MB, then
        # level), the old scene being freed as it is dropped or by Python's own collector.
        self._close_viewer()
        self.agent = None
        self._sensors = dict()
        self._human_render_cameras = dict()
        self.scene = None
        self._camera_group = None
        self._camera_view = False
        batcher = render_batcher.active_batcher()
        if batcher is not None:
            batcher.forget(self)
        self._hidden_objects = []

    def close(self) -> None:
        """Release the scene, and its GPU memory now (ManiSkill's collection)."""
        had_scene = self.scene is not None
        super().close()
        if had_scene:
            gc.collect()

    # ------------------------------------------------------------ rendering
    def _get_obs_sensor_data(self, apply_texture_transforms: bool = True) -> dict:
        # CPU physics with GPU rendering: both cameras in one batched pass (camera_group.py);
        # envs stepped by several threads of one process share passes (render_batcher.py).
        # CPU rendering: ManiSkill's own capture, pictures read without its extra copy.
        view = self._sensor_camera_view() if apply_texture_transforms else None
        if view is None:
            return super()._get_obs_sensor_data(apply_texture_transforms)
        if not self._render_on_gpu:
            self.scene.update_render(update_sensors=True, update_human_render_cameras=False)
            self.capture_sensor_data()
            images = read_rgb_pictures(view[1])
        elif (batcher := render_batcher.active_batcher()) is not None:
            images = batcher.render(self, view, env_render_device(self))
        else:
            if self._camera_group is None:  # dropped with the scene by _clear
                self._camera_group = CameraGroupRenderer([view], env_render_device(self))
            images = self._camera_group.render()
        return {name: {"rgb": image} for name, image in images.items()}

    def _sensor_camera_view(self) -> SceneCameras | None:
        """The scene and sensor cameras to read rgb from ourselves, or None where ManiSkill's
        path is needed; checked once per scene (_clear forgets it)."""
        if self._camera_view is False:
            readable = self.scene is not None and rgb_cameras_readable(self)
            self._render_on_gpu = readable and renders_on_cuda(self)
            self._camera_view = env_cameras(self) if readable else None
        return self._camera_view  # type: ignore[return-value]

    # ------------------------------------------------------------- episodes
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        with torch.device(self.device):
            # 1. The table builder resets the robot with its own noise (draws discarded).
            self.table_scene.initialize(env_idx)
            # 2-3. The task's answer (numpy) and layout (torch).
            self._sample_episode(env_idx, options)
            # 4. Arm joint noise (numpy), then the task's own robot pose.
            self._reset_robot(env_idx)
            # 5. Phase lengths (torch): C for all reset envs, then E.
            self._sample_phase_lengths(env_idx)
            # 6. Layout post-processing that upstream draws after the phases.
            self._after_phase_sampling(env_idx)
            if self._prev_action is not None:
                self._prev_action[env_idx] = 0
            self._reward_dict = None
            self._on_episode_start(env_idx)

    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        """Draw the episode's answer and object layout for the envs in ``env_idx``."""

    def _after_phase_sampling(self, env_idx: torch.Tensor) -> None:
        """Layout steps that draw random numbers after the phase lengths."""

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        """Put the scene into its t = 0 state."""

    def _reset_robot(self, env_idx: torch.Tensor) -> None:
        # Each env draws its joint noise from its own episode RNG (upstream shared env 0's
        # draw across the batch; identical for env 0, see DEVIATIONS.md).
        noise = np.stack(
            [
                self._batched_episode_rng[int(i)].normal(0, self.robot_init_qpos_noise, NUM_ARM_JOINTS)
                for i in env_idx.cpu().numpy()
            ]
        )
        qpos = np.tile(ROBOT_INIT_QPOS, (len(env_idx), 1))
        qpos[:, :NUM_ARM_JOINTS] += noise
        self.agent.reset(torch.as_tensor(qpos, dtype=torch.float32, device=self.device))
        self.agent.robot.set_pose(sapien.Pose(p=ROBOT_ROOT_POSITION))

    # ---------------------------------------------------------------- phases
    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        b = len(env_idx)
        cue_lo, cue_hi = self.CUE_PHASE_STEPS
        empty_lo, empty_hi = self.EMPTY_PHASE_STEPS
        self.cue_steps_per_env[env_idx] = torch.randint(cue_lo, cue_hi + 1, (b,), device=self.device)
        self.empty_steps_per_env[env_idx] = torch.randint(
            empty_lo, empty_hi + 1, (b,), device=self.device
        )

    @property
    def action_phase_start(self) -> torch.Tensor:
        """Per env, the first ``elapsed_steps`` value of the action phase (C + E)."""
        return self.cue_steps_per_env + self.empty_steps_per_env

    def phase_masks(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per env (cue, empty, action) boolean masks for elapsed-step values ``t``."""
        cue = t < self.cue_steps_per_env
        action = t >= self.action_phase_start
        return cue, ~cue & ~action, action

    # ------------------------------------------------------------- stepping
    def reset(self, seed: Any = None, options: dict | None = None):
        """ManiSkill's reset, one thread at a time: it reseeds and draws from torch's
        global RNG (render_batcher.global_rng_section)."""
        with render_batcher.global_rng_section():
            return super().reset(seed=seed, options=options)

    @property
    def _default_sim_config(self) -> SimConfig:
        return SimConfig(gpu_memory_config=GPUMemoryConfig(**self.GPU_MEMORY))

    def step(self, action: Any):
        """ManiSkill's step with input checks; ``terminated`` is the family's `_terminated`."""
        self._check_action(action)
        obs, reward, _, truncated, info = super().step(action)
        return obs, reward, self._terminated(info), truncated, info

    def _terminated(self, info: dict) -> torch.Tensor:
        """Per env, whether the episode ends at this step. Default, as upstream (which
        returns terminated & ~success): success never ends an episode, and no selection
        task defines a failure, so only a family's "fail" can; families override this."""
        if "fail" in info:
            return info["fail"] & ~info["success"]
        return torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)

    def _check_action(self, action: Any) -> None:
        if action is None or isinstance(action, dict):
            return
        if not isinstance(action, (np.ndarray, torch.Tensor)):
            raise TypeError(
                f"action must be a numpy array or torch tensor, got {type(action).__name__}"
            )
        single = tuple(self.single_action_space.shape)
        shape = tuple(action.shape)
        if shape != single and shape != (self.num_envs, *single):
            raise ValueError(
                f"action has shape {shape}; control mode {self.control_mode!r} expects "
                f"{(self.num_envs, *single)} or {single}"
            )
        is_nan = torch.isnan(action).any() if isinstance(action, torch.Tensor) else np.isnan(action).any()
        if bool(is_nan):
            raise ValueError("action contains NaN; every action value must be a finite number")

    def get_info(self) -> dict:
        """ManiSkill's info plus the keys every MIKASA task reports (``common.md`` §6)."""
        info = super().get_info()
        info["task_cue"] = self.task_cue
        info["language_instruction"] = self.LANGUAGE_INSTRUCTION
        info["oracle_info"] = self.oracle_info
        # The reward is computed after the info, so this is the previous step's dict (as upstream).
        info["reward_dict"] = self._reward_dict
        return info

    # ---------------------------------------------------------- saved state
    @classmethod
    def task_state_names(cls) -> tuple[str, ...]:
        """The attributes ``get_state_dict`` saves under "task" (``TASK_STATE`` over the MRO)."""
        return _collect_over_mro(cls, "TASK_STATE")

    @classmethod
    def transient_state_names(cls) -> tuple[str, ...]:
        """The attributes deliberately not saved (``TRANSIENT_STATE`` over the MRO)."""
        return _collect_over_mro(cls, "TRANSIENT_STATE")

    def get_state_dict(self) -> dict:
        """ManiSkill's state dict (actors, articulations, controller) plus the task's own
        state under "task": (num_envs, -1) tensors, nested dicts for building blocks."""
        state = super().get_state_dict()
        state["task"] = self.get_task_state()
        return state

    def get_task_state(self) -> dict:
        """The elapsed-step counter and the ``task_state_names`` attributes, packed."""
        n = self.num_envs
        state = {"elapsed_steps": task_state.pack(self._elapsed_steps, n, "elapsed_steps")}
        for name in self.task_state_names():
            packed = task_state.pack(getattr(self, name), n, name)
            if packed is not None:
                state[name] = packed
        return state

    def set_state_dict(self, state: dict, env_idx: torch.Tensor | None = None) -> None:
        """Restore a ``get_state_dict`` state in every env, or in the envs ``env_idx``.

        ManiSkill's own version restores the simulation only; this one also restores the
        controller (targets of the ``*_target_*`` control modes) and the task's state,
        elapsed steps included, so that stepping on repeats what followed the save. A state
        without "task" (e.g. recorded before tasks saved theirs) restores the simulation only.
        """
        super().set_state_dict(state, env_idx)
        rows = None if env_idx is None else torch.as_tensor(env_idx, device=self.device).long().reshape(-1)
        if state.get("controller"):
            controller = self.agent.get_controller_state()
            self.agent.set_controller_state(
                task_state.restored(controller, state["controller"], rows, self.num_envs, "controller")
            )
        if "task" in state:
            self.set_task_state(state["task"], rows)

    def set_task_state(self, task: dict, env_idx: torch.Tensor | None = None) -> None:
        """Put back a ``get_task_state`` dict (in the envs ``env_idx``; None: all)."""
        n = self.num_envs
        rows = None if env_idx is None else torch.as_tensor(env_idx, device=self.device).long().reshape(-1)
        if "elapsed_steps" in task:
            self._elapsed_steps = task_state.restored(self._elapsed_steps, task["elapsed_steps"], rows, n, "elapsed_steps")
        for name in self.task_state_names():
            if name in task:
                setattr(self, name, task_state.restored(getattr(self, name), task[name], rows, n, name))
        self._on_state_restored(torch.arange(n, device=self.device) if rows is None else rows)

    def _on_state_restored(self, env_idx: torch.Tensor) -> None:
        """Drop or rebuild what is derived from the task state (families extend this)."""
        self._reward_dict = None

    def set_state(self, state: Any, env_idx: torch.Tensor | None = None) -> None:
        """Restore a flat state vector from ``get_state()``.

        ManiSkill's version rebuilds only the actors and articulations from the vector and
        drops the rest; this one splits it back into the whole state dict (the layout of the
        env's first state) and restores that with ``set_state_dict``.
        """
        flat = common.to_tensor(state, device=self.device)
        if flat.ndim == 1:
            flat = flat[None]
        self.set_state_dict(task_state.unflatten_like(self._init_raw_state, flat), env_idx)

    # --------------------------------------------------------------- reward
    @property
    def normalized_dense_divisor(self) -> float:
        """What normalized_dense divides the dense reward by: ``NORMALIZED_DENSE_DIVISOR`` where
        a variant sets it, else the success value ``DENSE_REWARD_MAX``."""
        divisor = self.NORMALIZED_DENSE_DIVISOR
        return self.DENSE_REWARD_MAX if divisor is None else divisor

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Dense reward divided by ``normalized_dense_divisor``, clipped to [0, 1]."""
        dense = self.compute_dense_reward(obs=obs, action=action, info=info)
        return (dense / self.normalized_dense_divisor).clamp(0.0, 1.0)

    def _action_smoothness_terms(self, action: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """(‖a‖, ‖a − a_prev‖) per env; the delta is 0 on an episode's first step."""
        if action is None:
            zeros = torch.zeros(self.num_envs, device=self.device)
            return zeros, zeros
        action = action.reshape(self.num_envs, -1).float()
        if self._prev_action is None or self._prev_action.shape != action.shape:
            self._prev_action = torch.zeros_like(action)
        delta = torch.linalg.norm(action - self._prev_action, dim=-1)
        delta = torch.where(self.elapsed_steps <= 1, torch.zeros_like(delta), delta)
        self._prev_action = action.clone()
        return torch.linalg.norm(action, dim=-1), delta

    def smoothness_penalty(self, action: torch.Tensor | None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """(B,) c1·tanh(2‖a‖) + c2·tanh(5‖a − a_prev‖) + c3·tanh(2‖arm qvel‖), the smoothness
        penalty the reference's dense rewards share, with the family's ``ACTION_L2_COEF``,
        ``ACTION_DELTA_L2_COEF`` and ``QVEL_L2_COEF``; and its terms, keyed as the families'
        ``reward_dict`` shows them."""
        action_l2, delta_l2 = self._action_smoothness_terms(action)
        qvel_l2 = torch.linalg.norm(self.arm_qvel, dim=-1)
        penalty = (
            self.ACTION_L2_COEF * torch.tanh(2 * action_l2)
            + self.ACTION_DELTA_L2_COEF * torch.tanh(5 * delta_l2)
            + self.QVEL_L2_COEF * torch.tanh(2 * qvel_l2)
        )
        terms = dict(action_l2=action_l2, delta_action_l2=delta_l2, qvel_l2=qvel_l2, smooth_penalty=penalty)
        return penalty, terms

    @property
    def arm_qvel(self) -> torch.Tensor:
        """(B, 7) arm joint velocities (fingers excluded)."""
        return self.agent.robot.get_qvel()[..., :NUM_ARM_JOINTS]


def _collect_over_mro(cls: type, attribute: str) -> tuple[str, ...]:
    """The names listed in ``attribute`` by ``cls`` and its bases, bases first, no repeats."""
    names: dict[str, None] = {}
    for klass in reversed(cls.__mro__):
        names.update(dict.fromkeys(klass.__dict__.get(attribute, ())))
    return tuple(names)


class UnsupportedRobotError(ValueError, NotImplementedError):
    """A robot uid the task does not support (upstream raised NotImplementedError)."""


def _check_mode(name: str, value: str | None, accepted: tuple[str, ...], allow_texture_combos: bool = False) -> None:
    if value is None or value in accepted:
        return
    if allow_texture_combos and all(part in ("rgb", "depth", "segmentation", "normal", "albedo", "position") for part in value.split("+")):
        return
    raise ValueError(f"unknown {name} {value!r}; accepted values: {', '.join(accepted)}")
