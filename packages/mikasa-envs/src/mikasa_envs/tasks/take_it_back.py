"""TakeItBack: push a cube onto a red target, then, once the target turns purple, back to
where the cube started (a spot the cameras never show). When the cube arrives, it is set
down at a fixed spot of the target and the arm goes back to its rest pose, so nothing in
view tells which way the cube came."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
import sapien
import torch
from mani_skill.utils.structs import Actor, Pose

from mikasa_envs.base_env import ROBOT_INIT_QPOS, MikasaVLABaseEnv
from mikasa_envs.building_blocks.cubes import build_colored_cube, rgba01
from mikasa_envs.building_blocks.poses import only_rows, positions_to_poses, write_actor_poses
from mikasa_envs.building_blocks.targets import (
    TARGET_Z,
    SwitchingTarget,
    build_target_disc,
    set_disc_pose,
)
from mikasa_envs.family import Chance, RLVariant, TaskFamily, TaskSpec
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._intercept import SMALL_SCENE_GPU_MEMORY


def take_it_back_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule: P(a guessed row centre lies within the success radius of the true start).

    The start is x ~ U[START_X), y = START_Y_STEP·j + U[0, START_Y_JITTER) with
    j ~ U{−1, 0, 1}; the guess is (centre of START_X, START_Y_STEP·j' + START_Y_JITTER / 2)
    with j' uniform. The guessed row always succeeds (its corners are 0.056 away); a
    neighbouring row only where its near edge comes within the radius (a midpoint integral
    over the row's y jitter).
    """
    x_lo, x_hi = env_class.START_X
    width, jitter, r = x_hi - x_lo, env_class.START_Y_JITTER, env_class.GOAL_RADIUS
    near = env_class.START_Y_STEP - jitter / 2  # y gap from a row centre to the next row's near edge
    n = 20_000
    share = 0.0
    for i in range(n):
        dy = near + (i + 0.5) / n * jitter
        if dy < r:
            share += min(2 * math.sqrt(r * r - dy * dy), width) / width
    neighbour = share / n
    mean_neighbours = 4 / 3  # rows −1 and 1 have one neighbour, row 0 two
    return Chance(
        (1 + mean_neighbours * neighbour) / 3,
        "≈1/3: the start is in one of 3 rows; a guess at a row's centre is within the "
        f"{r} radius of every start of that row (and of a sliver of a neighbouring row)",
    )


FAMILY = TaskFamily(
    "take_it_back",
    hidden=(
        "the cube's start spot: unmarked for the cameras, known only from where the cube "
        "stood before the push"
    ),
    overlays="intercept",
    wrapper_table_rank=(11, 11),
    chance=take_it_back_chance,
    rl_variants=(
        RLVariant(
            number=14, env_id="TakeItBack-v0", vla_env_id="TakeItBack-VLA-v0", group="TakeItBack",
            memory_type="Spatial", max_episode_steps=180, reward_divisor=30.0,
            oracle_info="xyz_initial",
        ),
    ),
)


CUBE_GREEN_255 = (0, 255, 0, 255)
START_MARKER_BLUE_255 = (0, 0, 255, 255)
# The start spot's rows j (y = START_Y_STEP·j + jitter).
START_ROWS = (-1, 0, 1)
GOAL_RED_255 = (194, 19, 22, 255)
GOAL_CHANGED_PURPLE_255 = (147, 0, 211, 255)


@register_task(FAMILY, "TakeItBack-VLA-v0", number=13, split="short", data_source="PPO",
               memory_type="Spatial", max_episode_steps=60)
class TakeItBackVLAEnv(MikasaVLABaseEnv):
    """**Task Description:** a green cube stands on the table. Push it onto the red/white
    target; once it gets there the target turns purple/white, and the cube must be brought
    back to where it started. The start spot is marked only in human renders (hidden from
    the policy's cameras, and under the cube at reset): the robot must remember it. At the
    step the cube first enters the target, the cube is set down at rest at the target's
    near edge (HANDOVER_OFFSET towards the robot from its centre) and the arm is put back
    in its rest pose: otherwise where the push left the cube and the gripper shows the
    direction it came from (DEVIATIONS.md, Fixed #29).

    **Randomizations:** the cube's start s (x ∈ [−0.05, 0.05), y = 0.1·j + [0, 0.05) with
    j ∈ {−1, 0, 1}); the target g (x ∈ [0.20, 0.25), y ∈ [−0.025, 0.025)); arm joint noise.

    **Success Conditions:** the cube has been within 0.08 of the target (xy) at some step of
    the episode, and is now within 0.08 of its start (xy), at any step (not latched).
    """

    LANGUAGE_INSTRUCTION = (
        "Push the cube onto the red target, and when the target changes color, return the cube to its original position."
    )
    GOAL_RADIUS: ClassVar[float] = 0.08
    CUBE_HALFSIZE: ClassVar[float] = 0.02
    # Smoothness penalty coefficients (action L2, action delta, joint-velocity L2).
    ACTION_L2_COEF: ClassVar[float] = 0.01
    ACTION_DELTA_L2_COEF: ClassVar[float] = 0.08
    QVEL_L2_COEF: ClassVar[float] = 0.01
    DENSE_REWARD_MAX = 30.0
    CUE_PHASE_STEPS = (0, 0)
    EMPTY_PHASE_STEPS = (0, 0)
    # Start spot: x ~ U[START_X), y = START_Y_STEP·j + U[0, START_Y_JITTER), j ~ U{−1, 0, 1}.
    START_X: ClassVar[tuple[float, float]] = (-0.05, 0.05)
    START_Y_STEP: ClassVar[float] = 0.1
    START_Y_JITTER: ClassVar[float] = 0.05
    GOAL_X: ClassVar[tuple[float, float]] = (0.20, 0.25)
    GOAL_Y: ClassVar[tuple[float, float]] = (-0.025, 0.025)
    # Dense reward: the push point sits behind the cube (−x), the pull point beyond it (+x).
    PUSH_OFFSET: ClassVar[float] = 0.025
    PULL_OFFSET: ClassVar[float] = 0.03
    REACHED_DIST: ClassVar[float] = 0.03
    # Where the cube is set down when it first enters the target: this far on the robot's
    # side (−x) of the target's centre, inside GOAL_RADIUS and within the arm's reach.
    HANDOVER_OFFSET: ClassVar[float] = 0.07

    cube: Actor

    GPU_MEMORY: ClassVar[dict[str, int]] = SMALL_SCENE_GPU_MEMORY
    TASK_STATE = ("initial_pos", "goal_pos", "goal_achieved", "goal_reached_status", "goal")

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        half = self.CUBE_HALFSIZE
        self.cube = build_colored_cube(self.scene, rgba01(CUBE_GREEN_255), "cube", half, sapien.Pose(p=[0, 0, half]))
        self.initial_region = build_target_disc(
            self.scene, self.GOAL_RADIUS, "initial_region", START_MARKER_BLUE_255
        )
        self.goal = SwitchingTarget(
            self.scene,
            self.GOAL_RADIUS,
            "goal_region",
            GOAL_RED_255,
            GOAL_CHANGED_PURPLE_255,
            changed_name="changed_goal_region",
        )
        self.goal_region = self.goal.first
        self.changed_goal_region = self.goal.second
        # The start marker is for human renders only (ManiSkill hides these from sensors).
        self._hidden_objects.append(self.initial_region)
        n = self.num_envs
        self.initial_pos = torch.zeros(n, 3, device=self.device)
        self.goal_pos = torch.zeros(n, 3, device=self.device)
        self.goal_achieved = torch.zeros(n, dtype=torch.bool, device=self.device)
        self.goal_reached_status = torch.zeros(n, dtype=torch.bool, device=self.device)

    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # As the reference (its seed-0 reset reproduced): the start's row j ~ U{−1, 0, 1} from
        # each env's numpy episode RNG (before the arm noise, common.md §11); then torch: the
        # start's x, its y jitter, the goal's x, y.
        b = len(env_idx)
        rows = self._batched_episode_rng[env_idx.cpu().numpy()].choice(START_ROWS)
        row = torch.as_tensor(rows, dtype=torch.float32, device=self.device)
        (x_lo, x_hi), (gx_lo, gx_hi), (gy_lo, gy_hi) = self.START_X, self.GOAL_X, self.GOAL_Y
        start = torch.zeros(b, 3, device=self.device)
        start[:, 0] = torch.rand(b) * (x_hi - x_lo) + x_lo
        start[:, 1] = self.START_Y_STEP * row + torch.rand(b) * self.START_Y_JITTER
        start[:, 2] = TARGET_Z
        goal = torch.zeros(b, 3, device=self.device)
        goal[:, 0] = torch.rand(b) * (gx_hi - gx_lo) + gx_lo
        goal[:, 1] = torch.rand(b) * (gy_hi - gy_lo) + gy_lo
        goal[:, 2] = TARGET_Z
        self.initial_pos[env_idx] = start
        self.goal_pos[env_idx] = goal
        self.oracle_info = self.initial_pos

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        b = len(env_idx)
        cube_p = self.initial_pos[env_idx].clone()
        cube_p[:, 2] = self.CUBE_HALFSIZE
        identity = torch.tensor([1.0, 0.0, 0.0, 0.0], device=self.device).expand(b, 4)
        self.cube.set_pose(Pose.create_from_pq(p=cube_p, q=identity))
        self.cube.set_linear_velocity(torch.zeros(b, 3, device=self.device))
        self.cube.set_angular_velocity(torch.zeros(b, 3, device=self.device))
        set_disc_pose(self.initial_region, self.initial_pos[env_idx, :2], TARGET_Z, env_idx)
        self.goal.place(env_idx, self.goal_pos[env_idx, :2])
        self.goal_achieved[env_idx] = False
        self.goal_reached_status[env_idx] = False

    # ------------------------------------------------------------- stepping
    def _after_control_step(self) -> None:
        super()._after_control_step()
        if bool(self.goal_reached_status.all()):
            return  # every env is past its arrival: nothing to hand over (no GPU fetch)
        # Before this step's evaluate(): the first arrival latches the goal there, and the
        # observation of this step already shows the handed-over scene.
        if self.gpu_sim_enabled:
            # The GPU body buffer still holds the poses from before the substeps.
            self.scene.px.gpu_fetch_rigid_dynamic_data()
        arrived = ~self.goal_reached_status & self._cube_in_goal()
        if bool(arrived.any()):
            self._hand_over(arrived.nonzero()[:, 0])

    def _hand_over(self, env_idx: torch.Tensor) -> None:
        """Set the cube down at rest at the target's near edge and the arm at its rest pose
        (zero velocity) in the envs ``env_idx``; the start spot is left unseen."""
        b = len(env_idx)
        cube_p = self.goal_pos[env_idx].clone()
        cube_p[:, 0] -= self.HANDOVER_OFFSET
        cube_p[:, 2] = self.CUBE_HALFSIZE
        qpos = torch.as_tensor(np.tile(ROBOT_INIT_QPOS, (b, 1)), dtype=torch.float32, device=self.device)
        if self.gpu_sim_enabled:
            # After the substeps the GPU buffers still hold the data from before them (ManiSkill
            # fetches after this hook): refresh them before writing rows into them.
            self.scene._gpu_fetch_all()
        write_actor_poses(self.scene, [self.cube], env_idx, positions_to_poses(cube_p)[:, None], zero_velocity=True)
        with only_rows(self.scene, env_idx):  # GPU: these envs' rows only (CPU: one env)
            self.agent.reset(qpos)
        if self.gpu_sim_enabled:
            self.scene._gpu_apply_all()
            self.scene.px.gpu_update_articulation_kinematics()

    # ---------------------------------------------------------------- queries
    def _cube_in_goal(self) -> torch.Tensor:
        """(B,) whether the cube's centre is within GOAL_RADIUS of the target (xy, strict)."""
        return torch.linalg.norm(self.cube_position()[:, :2] - self.goal_pos[:, :2], dim=-1) < self.GOAL_RADIUS

    def cube_position(self) -> torch.Tensor:
        """(B, 3) cube centre."""
        if not self.gpu_sim_enabled:
            return torch.from_numpy(np.asarray(self.cube._objs[0].pose.p, dtype=np.float32))[None].to(self.device)
        return self.cube.pose.p

    def evaluate(self) -> dict:
        """Swap the target if the cube reached it at the previous evaluation, then test the
        goal (latched) and the return (``take_it_back.md``, episode logic)."""
        # The colour change shows one step after the goal event (upstream order).
        self.goal.switch(self.goal_achieved)
        self.goal_achieved = self._cube_in_goal()
        self.goal_reached_status = self.goal_reached_status | self.goal_achieved
        cube_xy = self.cube_position()[:, :2]
        is_cube_returned = torch.linalg.norm(cube_xy - self.initial_pos[:, :2], dim=-1) < self.GOAL_RADIUS
        return dict(
            success=is_cube_returned & self.goal_reached_status,
            goal_achieved=self.goal_achieved.clone(),
            goal_reached_status=self.goal_reached_status.clone(),
        )

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs["goal_pos"] = self.goal_pos
            obs["cube_pose"] = self.cube.pose.raw_pose
            obs["oracle_info"] = self.oracle_info
            obs["goal_reached_status"] = info["goal_reached_status"][:, None]
        return obs

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Push to the goal, then pull back to the start; 30 on success."""
        cube = self.cube.pose.p
        tcp = self.agent.tcp.pose.p
        along_x = torch.zeros_like(cube)
        along_x[:, 0] = 1.0
        push_dist = torch.linalg.norm(cube - self.PUSH_OFFSET * along_x - tcp, dim=-1)
        pull_dist = torch.linalg.norm(cube + self.PULL_OFFSET * along_x - tcp, dim=-1)
        reaching_push = 1 - torch.tanh(5 * push_dist)
        reaching_pull = 1 - torch.tanh(5 * pull_dist)
        reached_push = (push_dist < self.REACHED_DIST).float()
        reached_pull = (pull_dist < self.REACHED_DIST).float()
        place_goal = 1 - torch.tanh(5 * torch.linalg.norm(cube[:, :2] - self.goal_pos[:, :2], dim=-1))
        place_back = 1 - torch.tanh(5 * torch.linalg.norm(cube[:, :2] - self.initial_pos[:, :2], dim=-1))
        keep_contact = 1 - torch.tanh(6 * torch.linalg.norm(cube - tcp, dim=-1))
        smooth, smoothness = self.smoothness_penalty(action)
        before = 2 * reaching_push + 1.5 * place_goal + 5 * place_goal * reached_push
        after = 10 * reaching_pull + 4 * keep_contact + 15 * place_back * reached_pull
        reward = torch.where(info["goal_reached_status"], after, before) - smooth
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = {
            "reached_push": reached_push,
            "reached_pull": reached_pull,
            "tcp_push_dist": push_dist,
            "tcp_pull_dist": pull_dist,
            "reaching_reward_push": reaching_push,
            "reaching_reward_pull": reaching_pull,
            "keep_contact_reward": keep_contact,
            "goal_achieved": info["goal_achieved"],
            "goal_reached_status": info["goal_reached_status"],
            "place_in_goal_reward": place_goal,
            "place_back_reward": place_back,
            **smoothness,
        }
        return reward
