"""Machinery shared by the Intercept and InterceptGrab families: a red ball launched along +y.

At every episode start a ball of radius 2 cm is placed at x ~ U[−0.35, −0.05),
y ~ U[−0.90, −0.65) and given a launch velocity (vx ~ U[0, 0.05), vy ~ U[v_min, v_max),
0). It slides, then rolls at ≈ 5/7 of the launch speed. Nothing is hidden and there are no
phases: the memory demand is that one frame shows no velocity (``intercept.md``).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import sapien
import torch
from mani_skill.utils.building import actors
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.base_env import MikasaVLABaseEnv

BALL_RGBA = (1.0, 0.0, 0.0, 1.0)


SMALL_SCENE_GPU_MEMORY = {"found_lost_pairs_capacity": 2**25, "max_rigid_patch_count": 2**18}
"""Upstream's GPU buffers for Intercept, InterceptGrab and TakeItBack (GPU sim only)."""


class InterceptBallVLABaseEnv(MikasaVLABaseEnv):
    """A ball rolling across the table at a random launch velocity; subclasses add the goal.

    ``oracle_info`` is the launch velocity (vx, vy, 0), float (B, 3), constant per episode.
    """

    BALL_RADIUS: ClassVar[float] = 0.02
    # Height of the ball's centre at reset: 2r in Intercept (it drops), r in InterceptGrab.
    BALL_START_Z: ClassVar[float] = 0.02
    # Start region of the ball centre: [lo, hi) per axis.
    BALL_START_X: ClassVar[tuple[float, float]] = (-0.35, -0.05)
    BALL_START_Y: ClassVar[tuple[float, float]] = (-0.90, -0.65)
    # Launch velocity: vx ~ U[0, VX_MAX), vy ~ U[VELOCITY_RANGE) (m/s).
    VX_MAX: ClassVar[float] = 0.05
    VELOCITY_RANGE: ClassVar[tuple[float, float]] = (0.25, 0.50)
    # No cue / delay phases: the ball moves from the first step.
    CUE_PHASE_STEPS = (0, 0)
    EMPTY_PHASE_STEPS = (0, 0)

    ball: Actor

    GPU_MEMORY: ClassVar[dict[str, int]] = SMALL_SCENE_GPU_MEMORY
    TASK_STATE = ("ball_start_pos", "launch_velocity")

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self.ball = actors.build_sphere(
            self.scene,
            radius=self.BALL_RADIUS,
            color=list(BALL_RGBA),
            name="ball",
            body_type="dynamic",
            initial_pose=sapien.Pose(p=[0, 0, self.BALL_RADIUS]),
        )
        self.launch_velocity = torch.zeros(self.num_envs, 3, device=self.device)
        self.ball_start_pos = torch.zeros(self.num_envs, 3, device=self.device)

    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Torch draws, in order: the ball's start x, y; the launch vx, vy; then the subclass's.
        b = len(env_idx)
        start = torch.zeros(b, 3, device=self.device)
        start[:, 0] = uniform(b, *self.BALL_START_X)
        start[:, 1] = uniform(b, *self.BALL_START_Y)
        start[:, 2] = self.BALL_START_Z
        velocity = torch.zeros(b, 3, device=self.device)
        velocity[:, 0] = uniform(b, 0.0, self.VX_MAX)
        velocity[:, 1] = uniform(b, *self.VELOCITY_RANGE)
        self.ball_start_pos[env_idx] = start
        self.launch_velocity[env_idx] = velocity
        self.oracle_info = self.launch_velocity
        self._sample_goal(env_idx, start)

    def _sample_goal(self, env_idx: torch.Tensor, ball_start: torch.Tensor) -> None:
        """Draw and place whatever the ball is aimed at (after the ball's draws)."""

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        # Launch: the ball at its start with the launch velocity and no spin.
        start = self.ball_start_pos[env_idx]
        quat = torch.tensor([1.0, 0.0, 0.0, 0.0], device=self.device).expand(len(env_idx), 4)
        self.ball.set_pose(Pose.create_from_pq(p=start, q=quat))
        self.ball.set_linear_velocity(self.launch_velocity[env_idx])
        self.ball.set_angular_velocity(torch.zeros(len(env_idx), 3, device=self.device))

    # --------------------------------------------------------------- queries
    def ball_position(self) -> torch.Tensor:
        """(B, 3) ball centre."""
        if not self.gpu_sim_enabled:
            return torch.from_numpy(np.asarray(self.ball._objs[0].pose.p, dtype=np.float32))[None].to(self.device)
        return self.ball.pose.p

    def _ball_touches_cpu(self, entities: set, pushing: bool = False) -> bool:
        """Whether the ball is in contact with any of ``entities`` after the last substep
        (CPU, one env); with ``pushing``, only contacts that carry an impulse count."""
        ball = self.ball._bodies[0].entity
        for contact in self.scene.px.get_contacts():
            first, second = contact.bodies[0].entity, contact.bodies[1].entity
            other = second if first == ball else first if second == ball else None
            if other in entities and (not pushing or any(np.any(p.impulse != 0) for p in contact.points)):
                return True
        return False

    def _ball_state_obs(self) -> dict[str, torch.Tensor]:
        """Ball pose, launch velocity and current velocities: privileged state entries."""
        return dict(
            ball_pose=self.ball.pose.raw_pose,
            oracle_info=self.oracle_info,
            ball_linear_vel=self.ball.linear_velocity,
            ball_angular_vel=self.ball.angular_velocity,
        )


def uniform(n: int, lo: float, hi: float) -> torch.Tensor:
    """n draws of U[lo, hi) from torch's global RNG."""
    return torch.rand(n) * (hi - lo) + lo
