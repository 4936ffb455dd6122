"""Machinery shared by the two Rotate families (RotateLenient, RotateStrict).

A single-coloured, 180°-symmetric peg lies flat on the table at a random heading; the
instruction asks for a turn by a given number of degrees about the vertical axis, measured
from the heading the peg started with. Once the peg moves its start heading can no longer
be seen, so the robot must remember it (or track the turn). The two families share the
scene, the target draw, the angle measurement and the info / observation layout; they
differ in the success test (Strict also keeps the peg's centre in place) and the reward.

There are no cue or delay phases: the target is in the instruction (and ``task_cue``) for
the whole episode, so ``cue_steps_per_env`` / ``empty_steps_per_env`` stay 0 and nothing
is hidden.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import sapien
import torch
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.building_blocks.cubes import rgba01
from mikasa_envs.family import Chance, TaskSpec

MODE_POS = "pos_angle"
MODE_POS_NEG = "pos_neg_angle"


def wrap_angle(angle: torch.Tensor) -> torch.Tensor:
    """((φ + π) mod 2π) − π: the angle in [−π, π)."""
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


def xyz_euler_gamma(quat_wxyz: torch.Tensor) -> torch.Tensor:
    """The third angle γ of the intrinsic X-Y-Z decomposition R = Rx(α)·Ry(β)·Rz(γ).

    The first row of R is (cos β cos γ, −cos β sin γ, sin β), so γ = atan2(−R01, R00);
    for a peg lying flat it is the heading about world z. ``quat_wxyz``: (..., 4).
    """
    w, x, y, z = quat_wxyz.unbind(-1)
    r00 = 1 - 2 * (y * y + z * z)
    r01 = 2 * (x * y - w * z)
    return torch.atan2(-r01, r00)


def sample_target_angles(u: torch.Tensor, mode: str, threshold: float) -> torch.Tensor:
    """Target turn (rad) from uniform draws ``u`` in [0, 1) (``rotate_lenient.md``).

    ``pos_angle``: a + u·(π/2 − a). ``pos_neg_angle``: magnitude a + u·(π/4 − a), sign + if
    u > 0.5 else − (the same draw, as upstream), with a = ``threshold``.
    """
    if mode == MODE_POS:
        return threshold + u * (math.pi / 2 - threshold)
    if mode == MODE_POS_NEG:
        magnitude = threshold + u * (math.pi / 4 - threshold)
        return torch.where(u > 0.5, magnitude, -magnitude)
    raise ValueError(f"unknown rotate MODE {mode!r}; expected {MODE_POS!r} or {MODE_POS_NEG!r}")


def target_degrees(task_cue: torch.Tensor) -> torch.Tensor:
    """Whole degrees of the float16 target as the instruction shows them (ties to even)."""
    return torch.round(task_cue.float() * (180 / math.pi)).to(torch.int64)


ANGLE_THRESHOLD = 0.1
"""The default success tolerance (rad) on the final heading (``angle_threshold``)."""

class RotatePegVLABaseEnv(MikasaVLABaseEnv):
    """Base of the Rotate families: turn a flat peg by the instructed angle about z.

    Subclasses set ``MODE`` and ``LANGUAGE_INSTRUCTION`` (a template with ``{angle_deg}``)
    and implement ``compute_dense_reward``; Strict adds its position test through
    ``_extra_evaluation``.
    """

    # Success counts only once elapsed_steps exceeds it (None: from step 0). The RL release's
    # RotateLenient sets 5, so that a peg that starts near the target is not a free success.
    SUCCESS_AFTER_STEP: ClassVar[int | None] = None

    MODE: ClassVar[str] = MODE_POS
    PEG_HALF_WIDTH: ClassVar[float] = 0.025
    PEG_HALF_LENGTH: ClassVar[float] = 0.12
    PEG_COLOR_RGBA: ClassVar[tuple[int, int, int, int]] = (12, 42, 160, 255)
    # Peg centre x, y ~ U[−range, range).
    PEG_SPAWN_HALF_RANGE: ClassVar[float] = 0.1
    STATIC_QVEL_THRESH: ClassVar[float] = 0.2
    # Smoothness penalty coefficients (action L2, action delta, joint-velocity L2): all 0.
    ACTION_L2_COEF: ClassVar[float] = 0.0
    ACTION_DELTA_L2_COEF: ClassVar[float] = 0.0
    QVEL_L2_COEF: ClassVar[float] = 0.0
    # No cue / delay phases: the target stays in the instruction.
    CUE_PHASE_STEPS = (0, 0)
    EMPTY_PHASE_STEPS = (0, 0)
    RENDER_CAMERA_EYE = (0.6, 0.7, 0.6)
    RENDER_CAMERA_TARGET = (0.0, 0.0, 0.35)
    # language_instruction is rebuilt from task_cue on a restore.
    TASK_STATE = ("initial_rotations", "initial_peg_position", "_robot_static")

    peg: Actor

    def __init__(self, *args: Any, angle_threshold: float = ANGLE_THRESHOLD, **kwargs: Any) -> None:
        # Both the success tolerance (rad) and the lower end of the target range.
        self.angle_threshold = float(angle_threshold)
        self.language_instruction: list[str] = []
        super().__init__(*args, **kwargs)

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self.peg = self._build_peg()
        n = self.num_envs
        self.initial_rotations = torch.zeros(n, dtype=torch.float32, device=self.device)
        self.initial_peg_position = torch.zeros(n, 3, dtype=torch.float32, device=self.device)
        self.task_cue = torch.zeros(n, dtype=torch.float16, device=self.device)
        self.oracle_info = torch.zeros(n, dtype=torch.float32, device=self.device)
        self.language_instruction = [self.LANGUAGE_INSTRUCTION] * n
        self._robot_static = torch.zeros(n, dtype=torch.bool, device=self.device)

    def _build_peg(self) -> Actor:
        """The peg: one box collision, drawn as two half-length boxes of the same colour."""
        hw, hl = self.PEG_HALF_WIDTH, self.PEG_HALF_LENGTH
        builder = self.scene.create_actor_builder()
        builder.add_box_collision(half_size=[hl, hw, hw])
        material = sapien.render.RenderMaterial(base_color=rgba01(self.PEG_COLOR_RGBA).tolist())
        for side in (-1.0, 1.0):
            builder.add_box_visual(
                pose=sapien.Pose(p=[side * hl / 2, 0.0, 0.0]), half_size=[hl / 2, hw, hw], material=material
            )
        builder.set_initial_pose(sapien.Pose(p=[0.0, 0.0, hw]))
        return builder.build(name="peg")

    # ------------------------------------------------------------- episodes
    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # As the reference (its seed-0 reset reproduced): numpy, each env's episode RNG, the
        # target's u ~ U[0, 1) for every reset env, then the start heading θ0 ~ U[0, 2π) (before
        # the arm noise, common.md §11); then torch: the peg centre x, y.
        b = len(env_idx)
        rngs = self._batched_episode_rng[env_idx.cpu().numpy()]
        u = torch.as_tensor(rngs.uniform(0.0, 1.0), dtype=torch.float64, device=self.device)  # float16 at the end
        theta0 = torch.as_tensor(rngs.uniform(0.0, 2 * math.pi), dtype=torch.float32, device=self.device)
        spread = self.PEG_SPAWN_HALF_RANGE
        xyz = torch.zeros(b, 3, device=self.device)
        xyz[:, :2] = torch.rand(b, 2, device=self.device) * (2 * spread) - spread
        xyz[:, 2] = self.PEG_HALF_WIDTH
        quat = torch.zeros(b, 4, device=self.device)
        quat[:, 0] = torch.cos(theta0 / 2)
        quat[:, 3] = torch.sin(theta0 / 2)
        self.peg.set_pose(Pose.create_from_pq(xyz, quat))
        zeros = torch.zeros(b, 3, device=self.device)
        self.peg.set_linear_velocity(zeros)
        self.peg.set_angular_velocity(zeros)
        self.initial_rotations[env_idx] = theta0
        self.initial_peg_position[env_idx] = xyz
        self.task_cue[env_idx] = sample_target_angles(u, self.MODE, self.angle_threshold).to(torch.float16)
        for i, degrees in zip(env_idx.tolist(), target_degrees(self.task_cue[env_idx]).tolist(), strict=True):
            self.language_instruction[i] = self.LANGUAGE_INSTRUCTION.format(angle_deg=degrees)

    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        # No phases (and no random draws for them): the action phase starts at t = 0.
        self.cue_steps_per_env[env_idx] = 0
        self.empty_steps_per_env[env_idx] = 0

    def _on_state_restored(self, env_idx: torch.Tensor) -> None:
        super()._on_state_restored(env_idx)
        for i, degrees in zip(env_idx.tolist(), target_degrees(self.task_cue[env_idx]).tolist(), strict=True):
            self.language_instruction[i] = self.LANGUAGE_INSTRUCTION.format(angle_deg=degrees)

    # --------------------------------------------------------------- queries
    @property
    def peg_heading(self) -> torch.Tensor:
        """(B,) the peg's current heading γ (intrinsic X-Y-Z Euler, third angle)."""
        return xyz_euler_gamma(self.peg.pose.q)

    def evaluate(self) -> dict:
        """Turn so far, turn still to go (also ``oracle_info``), stillness and success."""
        relative_angle = wrap_angle(self.peg_heading - self.initial_rotations)
        error = wrap_angle(self.task_cue.float() - relative_angle)
        self.oracle_info = error
        self._robot_static = self.arm_qvel.abs().max(dim=-1).values <= self.STATIC_QVEL_THRESH
        info = dict(relative_angle=relative_angle, y_angle_error=error)
        success = (error.abs() < self.angle_threshold) & self._robot_static
        success = success & self._extra_evaluation(info)
        if self.SUCCESS_AFTER_STEP is not None:
            success = success & (self.elapsed_steps > self.SUCCESS_AFTER_STEP)
        return dict(success=success, **info)

    def _extra_evaluation(self, info: dict) -> torch.Tensor:
        """Add family-specific info entries; return a further success condition per env."""
        return torch.ones(self.num_envs, dtype=torch.bool, device=self.device)

    def get_info(self) -> dict:
        """The common info; the instruction is this family's list, one string per env."""
        info = super().get_info()
        info["language_instruction"] = list(self.language_instruction)
        return info

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs["oracle_info"] = self.oracle_info
            obs["peg_pose"] = self.peg.pose.raw_pose
        return obs

    # ---------------------------------------------------------------- reward
    def _reward_inputs(self, action: torch.Tensor, info: dict) -> dict[str, torch.Tensor]:
        """Terms both rewards use: TCP-to-peg distance, |error|, correctness, smoothness."""
        error = info["y_angle_error"].abs()
        smooth, smoothness = self.smoothness_penalty(action)
        return dict(
            distance=torch.linalg.norm(self.peg.pose.p - self.agent.tcp.pose.p, dim=-1),
            abs_error=error,
            correct=error < self.angle_threshold,
            still=self._robot_static,
            success=info["success"],
            smoothness=smoothness,
        )

    def _finish_reward(self, reward: torch.Tensor, reward_dict: dict[str, torch.Tensor]) -> torch.Tensor:
        """Success steps get the maximum; keep the debug terms (``info`` shows them a step late)."""
        self._reward_dict = reward_dict
        return torch.where(reward_dict["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)


def rotate_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of the Rotate families: the success window's share of the start heading."""
    t = ANGLE_THRESHOLD
    return Chance(
        t / math.pi,
        f"{t}/π: no discrete answer; the unseen start heading is uniform in [0, 2π), and a "
        f"guess succeeds within ±{t} rad of it",
    )
