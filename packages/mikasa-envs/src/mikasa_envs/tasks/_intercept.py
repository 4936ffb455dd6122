"""Machinery shared by the Intercept and InterceptGrab families: a red ball launched along +y.

At every episode start a ball of radius 2 cm is placed at x ~ U[−0.35, −0.05),
y ~ U[−0.90, −0.65) and given a launch velocity (vx ~ U[0, 0.05), vy ~ U[v_min, v_max),
0). It slides, then rolls at ≈ 5/7 of the launch speed. There are no phases; the memory
demand is that one frame shows no velocity (``intercept.md``).

The ball is in view for its first ``BALL_SHOWN_STEPS`` frames, long enough to measure its
motion, then out of view until the robot first touches it (DEVIATIONS.md, Fixed #35): with
the ball in view every frame, a policy without memory that assumed a velocity from the
narrow launch range and aimed at the ball it saw met slow balls in up to half the episodes.
Only the render is affected (physics, draws, the reset frame and the privileged state are
unchanged): the physical ball has no visual; a visual-only kinematic twin, ``ball_visual``,
stands at its pose while it is in view and far below the scene while it is not (ManiSkill's
way to show and hide a marker: SAPIEN's batched renderer forbids changing visibility). The
RL release's ids keep the ball in view (``BALL_SHOWN_STEPS = None``), as published;
``gym.make(id, ball_shown_steps=...)`` sets it for any id.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import sapien
import torch
from mani_skill.utils.building import actors
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.family import Chance, TaskSpec

BALL_RGBA = (1.0, 0.0, 0.0, 1.0)
# Where the ball's visual twin waits while the ball is out of view: beyond every camera's far
# plane and below the floor.
HIDDEN_VISUAL_POSITION = (0.0, 0.0, -1000.0)


_ID_DEFAULT: Any = object()  # ball_shown_steps not given: the id's own BALL_SHOWN_STEPS


SMALL_SCENE_GPU_MEMORY = {"found_lost_pairs_capacity": 2**25, "max_rigid_patch_count": 2**18}
"""Upstream's GPU buffers for Intercept, InterceptGrab and TakeItBack (GPU sim only)."""


class InterceptBallVLABaseEnv(MikasaVLABaseEnv):
    """A ball rolling across the table at a random launch velocity; subclasses add the goal.

    ``oracle_info`` is the launch velocity (vx, vy, 0), float (B, 3), constant per episode.
    ``ball_touched`` latches the first push of a robot link on the ball; ``ball_visible`` says
    whether the cameras show the ball in the current frame.
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
    # Frames (elapsed_steps 0 .. N-1) in which the cameras show the ball before it leaves
    # view until the robot's first touch; None: in view every frame (the reference). Ten
    # frames: it slides for ~3 and rolls for 7, which a policy can measure its motion from.
    BALL_SHOWN_STEPS: ClassVar[int | None] = 10
    # Whether success needs the touch latch; if not, and the ball never leaves view, the
    # per-substep contact scan is skipped (~12 % of an InterceptGrab state step).
    SUCCESS_NEEDS_TOUCH: ClassVar[bool] = False

    ball: Actor

    GPU_MEMORY: ClassVar[dict[str, int]] = SMALL_SCENE_GPU_MEMORY
    TASK_STATE = ("ball_start_pos", "launch_velocity", "ball_touched")

    def __init__(self, *args: Any, ball_shown_steps: int | None = _ID_DEFAULT, **kwargs: Any) -> None:
        """``ball_shown_steps``: frames the ball is in view before it hides until the robot
        touches it (an int >= 1), or None to keep it in view; not given: the id's own
        ``BALL_SHOWN_STEPS``."""
        if ball_shown_steps is not _ID_DEFAULT:
            if ball_shown_steps is not None and (
                isinstance(ball_shown_steps, bool) or not isinstance(ball_shown_steps, int) or ball_shown_steps < 1
            ):
                raise ValueError(
                    f"ball_shown_steps={ball_shown_steps!r} is not accepted; accepted values: an int >= 1 "
                    "(frames in view before the ball hides until the robot touches it), None (always in view)"
                )
            self.BALL_SHOWN_STEPS = ball_shown_steps
        super().__init__(*args, **kwargs)

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        # The physical ball (collision only) and its visual twin (no collision), which the
        # cameras see where the ball is while it is in view.
        builder = self.scene.create_actor_builder()
        builder.add_sphere_collision(radius=self.BALL_RADIUS)
        builder.set_initial_pose(sapien.Pose(p=[0, 0, self.BALL_RADIUS]))
        self.ball = builder.build(name="ball")
        self.ball_visual = actors.build_sphere(
            self.scene,
            radius=self.BALL_RADIUS,
            color=list(BALL_RGBA),
            name="ball_visual",
            body_type="kinematic",
            add_collision=False,
            initial_pose=sapien.Pose(p=[0, 0, self.BALL_RADIUS]),
        )
        self.launch_velocity = torch.zeros(self.num_envs, 3, device=self.device)
        self.ball_start_pos = torch.zeros(self.num_envs, 3, device=self.device)
        # Whether any robot link has pushed on the ball this episode (latched per env).
        self.ball_touched = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        self._robot_entities = {body.entity for link in self.agent.robot.links for body in link._bodies}
        self._hidden_visual_p = torch.tensor(HIDDEN_VISUAL_POSITION, device=self.device)

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
        self.ball_touched[env_idx] = False
        self._place_ball_visual(self._elapsed_steps)

    # ------------------------------------------------------- touch and view
    def _after_simulation_step(self) -> None:
        super()._after_simulation_step()
        # CPU: every substep (a glancing hit may last less than a control step).
        if not self.gpu_sim_enabled and self._tracks_touch and not bool(self.ball_touched[0]):
            self.ball_touched[0] = self._ball_touches_cpu(self._robot_entities, pushing=True)

    def _after_control_step(self) -> None:
        super()._after_control_step()
        if self.gpu_sim_enabled:
            # As ManiSkill's tasks move a marker after a step: fetch the new poses first.
            self.scene._gpu_fetch_all()
            for link in self.agent.robot.links if self._tracks_touch else ():
                force = self.scene.get_pairwise_contact_forces(link, self.ball)
                self.ball_touched |= torch.linalg.norm(force, dim=-1) > 0
        # ManiSkill counts this step after the hook: the frame about to be observed is the next one.
        self._place_ball_visual(self._elapsed_steps + 1)
        if self.gpu_sim_enabled:
            self.scene._gpu_apply_all()

    def _on_state_restored(self, env_idx: torch.Tensor) -> None:
        super()._on_state_restored(env_idx)
        self._place_ball_visual(self._elapsed_steps)

    @property
    def _tracks_touch(self) -> bool:
        return self.SUCCESS_NEEDS_TOUCH or self.BALL_SHOWN_STEPS is not None

    def ball_visible_in(self, frame: torch.Tensor) -> torch.Tensor:
        """(B,) whether the cameras show the ball in the frame observed at elapsed step ``frame``."""
        if self.BALL_SHOWN_STEPS is None:
            return torch.ones(self.num_envs, dtype=torch.bool, device=self.device)
        return (frame < self.BALL_SHOWN_STEPS) | self.ball_touched

    @property
    def ball_visible(self) -> torch.Tensor:
        """(B,) whether the current frame shows the ball."""
        return self.ball_visible_in(self._elapsed_steps)

    def _place_ball_visual(self, frame: torch.Tensor) -> None:
        """Per env, put the ball's visual twin on the ball if the frame ``frame`` shows it,
        else out of every camera's view (physics untouched)."""
        pose = self.ball.pose.raw_pose.clone()
        hidden = ~self.ball_visible_in(frame)
        pose[hidden, :3] = self._hidden_visual_p
        self.ball_visual.set_pose(Pose.create(pose))

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


def intercept_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of Intercept and InterceptGrab: no discrete answer to guess."""
    return Chance(
        0.0,
        "0: no discrete answer; the ball's start and launch velocity are continuous, and after "
        "its first 10 frames it is out of view until touched, so meeting it without memory "
        "takes a lucky guess of a continuous path",
    )


RL_BALL_IN_VIEW = {"BALL_SHOWN_STEPS": None}
"""The RL release's view: the cameras show the ball in every frame (the VLA ids hide it after
its first 10 frames until the robot touches it; ``gym.make(id, ball_shown_steps=10)`` does
that on the RL ids too)."""
