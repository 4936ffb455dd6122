"""Machinery shared by the six selection families (Remember*, FindImposter*).

A selection task shows a cue, hides everything for a delay, then lays out N candidate
objects; the robot must bring its TCP to the one the cue identifies and hold still.
Families differ in the objects (cubes / shapes / shape-colour pairs), the slot layout and
what the cue shows; the phase-dependent placement, success, reward and privileged state
live here once.

Placement is physical for every family (``common.md`` §10, mechanism 2, recommended):
for a step that produces a cue, empty or settle frame, every object is written to its
phase pose with zero velocity before the physics substeps (so the robot meets the layout
of the frame it is producing) and again after them (so the frame shows it exactly). The
writes reach PhysX on GPU too, so hiding is not visual-only there.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import torch
from mani_skill.utils.structs import Actor

from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.building_blocks.cubes import COLOR_PALETTE_RGB, CUBE_HALF_SIZE, rgba01
from mikasa_envs.building_blocks.layouts import jitter_sequential
from mikasa_envs.building_blocks.object_sets import (
    ObjectSet,
    blue_shapes,
    palette_cubes,
    shape_color_objects,
)
from mikasa_envs.building_blocks.poses import set_cpu_actor_pose, write_actor_poses
from mikasa_envs.building_blocks.shapes import SHAPE_AND_COLOR_SHAPES, SHAPE_SCALE
from mikasa_envs.family import Chance, TaskSpec

HIDDEN_Z = 1000.0
# Which pinned layout a frame shows: the cue, everything hidden, the action layout; or free.
LAYOUT_CUE, LAYOUT_HIDDEN, LAYOUT_ACTION, LAYOUT_FREE = 0, 1, 2, -1
IDENTITY_QUAT = (1.0, 0.0, 0.0, 0.0)


# --------------------------------------------------------------------- layouts
def arc_slots(n: int, radius: float = 0.3, even_offset: bool = False, y_shift: float = 0.0) -> np.ndarray:
    """(n, 2) xy slots on a semicircle in front of the robot (``remember_color.md`` §3).

    Angle a_k = π(k − ⌊n/2⌋)/n (or π(k + 0.5 − n/2)/n for even n with ``even_offset``);
    x = radius·cos a − 0.25, y = radius·sin a − (k − ⌊n/2⌋)·y_shift.
    """
    k = np.arange(n, dtype=np.float64)
    centred = k + 0.5 - n / 2 if (even_offset and n % 2 == 0) else k - n // 2
    angles = np.pi * centred / n
    x = radius * np.cos(angles) - 0.25
    y = radius * np.sin(angles) - (k - n // 2) * y_shift
    return np.stack([x, y], axis=1)


def line_slots_3() -> np.ndarray:
    """The three slots of the N = 3 colour/shape tasks: (0, +0.1), (0, 0), (0, −0.1)."""
    return np.array([[0.0, 0.1], [0.0, 0.0], [0.0, -0.1]])




def _min_pairwise_distance(xy: torch.Tensor) -> torch.Tensor:
    d = torch.cdist(xy, xy)
    d.fill_diagonal_(float("inf"))
    return d.min()


def jitter_best_of(
    slots: torch.Tensor, sigma: float = 0.01, min_dist: float = 0.06, tries: int = 20
) -> torch.Tensor:
    """Jitter all slots at once, keeping the draw with the largest minimum spacing."""
    best, best_score = slots.clone(), torch.tensor(0.0)
    for _ in range(tries):
        candidate = slots + torch.randn(slots.shape) * sigma
        score = _min_pairwise_distance(candidate)
        if score > best_score:
            best, best_score = candidate, score
            if best_score >= min_dist:
                break
    return best


def spread_and_stretch(
    xy: torch.Tensor,
    min_dist: float = 0.09,
    sigma: float = 0.012,
    tries: int = 80,
    scale: float = 2.0,
    clamp: float = 0.5,
) -> torch.Tensor:
    """Push objects ≥ ``min_dist`` apart, then stretch y about its mean (N = 3 layouts)."""
    xy = xy.clone()
    for i in range(1, len(xy)):
        for _ in range(tries):
            if torch.linalg.norm(xy[:i] - xy[i], dim=1).min() >= min_dist:
                break
            xy[i] = xy[i] + torch.randn(2) * sigma
    xy[:, 1] = xy[:, 1].clamp(-clamp, clamp)
    mean_y = xy[:, 1].mean()
    xy[:, 1] = (mean_y + scale * (xy[:, 1] - mean_y)).clamp(-clamp, clamp)
    return xy


def line_or_arc_slots(n: int) -> np.ndarray:
    """Base slots of RememberColor/Shape and FindImposterColor/Shape: line (N = 3) or arc."""
    return line_slots_3() if n == 3 else arc_slots(n, radius=0.3, y_shift=0.025)


def non_identity_permutation(n: int) -> torch.Tensor:
    """A uniform random permutation of n, redrawn while it is the identity."""
    identity = torch.arange(n)
    while True:
        perm = torch.randperm(n)
        if not torch.equal(perm, identity):
            return perm


# ------------------------------------------------------------------ the class
class SelectionVLABaseEnv(MikasaVLABaseEnv):
    """Base of the selection families: N objects, one answer, cue → delay → choose.

    Subclasses return their ``ObjectSet`` from ``_load_objects`` and may override
    ``_base_slots`` and ``JITTER``; the Remember / FindImposter protocols turn the shuffled
    slots into ``cue_poses`` / ``action_poses`` ((B, N, 7) raw poses) and ``cue_visible``
    ((B, N)) in ``_set_layout``.
    """

    GOAL_THRESH: ClassVar[float] = 0.05
    STATIC_QVEL_THRESH: ClassVar[float] = 0.2
    # Smoothness penalty coefficients (action L2, action delta, joint-velocity L2).
    ACTION_L2_COEF: ClassVar[float] = 0.02
    ACTION_DELTA_L2_COEF: ClassVar[float] = 0.05
    QVEL_L2_COEF: ClassVar[float] = 0.01
    # How the base slots are jittered (jitter_sequential or jitter_best_of).
    JITTER: ClassVar[Callable[[torch.Tensor], torch.Tensor]] = staticmethod(jitter_sequential)
    # Steps (from the first action-phase frame) during which the action layout is re-imposed
    # before every substep; 0 = written once, at the first substep of the first action step.
    APPEAR_SETTLE_STEPS: ClassVar[int] = 1

    task_objects: list[Actor]
    # Whether each object's origin sits at its own rest height (else at FIXED_OBJECT_Z).
    FIXED_OBJECT_Z: ClassVar[float | None] = None
    # The pinned layouts (_layouts, _layouts_np) are rebuilt from these on a restore.
    TASK_STATE = ("answer_index", "cue_poses", "action_poses", "cue_visible", "manip_layout_applied")
    # The CPU "objects are free" step: a cache the pinning recomputes (dropped on restore).
    TRANSIENT_STATE = ("_free_from_step",)

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        objects = self._load_objects()
        self.task_objects = objects.actors
        n, b = len(self.task_objects), self.num_envs
        rest = torch.as_tensor(objects.rest_poses, dtype=torch.float32, device=self.device)
        if self.FIXED_OBJECT_Z is not None:
            rest[:, 2] = self.FIXED_OBJECT_Z
        self.rest_poses = rest
        self.cue_poses = rest.repeat(b, 1, 1)
        self.action_poses = rest.repeat(b, 1, 1)
        self.cue_visible = torch.zeros(b, n, dtype=torch.bool, device=self.device)
        # Per layout (LAYOUT_CUE / _HIDDEN / _ACTION) and env, the (N, 7) pinned poses.
        self._layouts = rest.repeat(3, b, 1, 1)
        self.answer_index = torch.zeros(b, dtype=torch.long, device=self.device)
        self.manip_layout_applied = torch.zeros(b, dtype=torch.bool, device=self.device)
        self._free_from_step: int | None = None

    def _load_objects(self) -> ObjectSet:
        """Build the N candidate objects (in key order)."""
        raise NotImplementedError

    @property
    def num_objects(self) -> int:
        """N, the number of candidate objects."""
        return len(self.task_objects)

    def _sample_answer(self, env_idx: torch.Tensor) -> torch.Tensor:
        """Draw one uniform answer key per reset env from that env's numpy episode RNG."""
        keys = self._batched_episode_rng[env_idx.cpu().numpy()].choice(self.num_objects)
        answer = torch.as_tensor(keys, dtype=torch.long, device=self.device)
        self.answer_index[env_idx] = answer
        self.oracle_info = self._oracle_info_of(self.answer_index)
        return answer

    def _oracle_info_of(self, answer_index: torch.Tensor) -> torch.Tensor:
        """The published answer encoding: the key as uint8 (B,)."""
        return answer_index.to(torch.uint8)

    def _shuffled_slot_layout(self, b: int, slots: np.ndarray, jitter: Callable) -> torch.Tensor:
        """(b, N, 7) poses: per env, jitter the slots and assign them to objects at random.

        Each object keeps its rest height and orientation. Torch draws per env: the jitter,
        then one permutation (upstream's order).
        """
        slots_t = torch.as_tensor(slots, dtype=torch.float32, device=self.device)
        poses = self.rest_poses.repeat(b, 1, 1)
        for row in range(b):
            xy = jitter(slots_t)
            poses[row, :, :2] = xy[torch.randperm(self.num_objects)]
        return poses

    def _base_slots(self) -> np.ndarray:
        """(N, 2) unjittered xy slots: a line for N = 3, else the colour tasks' arc."""
        return line_or_arc_slots(self.num_objects)

    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        # Upstream's draw order: the answer (numpy), then per env the jitter and the slot
        # permutation (torch), then the protocol's own draws (FindImposter's permutation).
        self._sample_answer(env_idx)
        poses = self._shuffled_slot_layout(len(env_idx), self._base_slots(), type(self).JITTER)
        self._set_layout(env_idx, poses)

    def _set_layout(self, env_idx: torch.Tensor, poses: torch.Tensor) -> None:
        """Turn the reset envs' shuffled slot poses into cue and action layouts."""
        raise NotImplementedError

    # --------------------------------------------------------------- phases
    def _frame_layouts(self, env_idx: torch.Tensor) -> None:
        """Precompute, per env, the poses of the three pinned layouts of this episode."""
        hidden = self.cue_poses[env_idx].clone()
        hidden[..., 2] = HIDDEN_Z
        shown = self.cue_visible[env_idx, :, None]
        self._layouts[LAYOUT_CUE, env_idx] = torch.where(shown, self.cue_poses[env_idx], hidden)
        self._layouts[LAYOUT_HIDDEN, env_idx] = hidden
        self._layouts[LAYOUT_ACTION, env_idx] = self.action_poses[env_idx]
        # The CPU sim has one env: keep float64 numpy rows ready for the SAPIEN setters.
        self._layouts_np = self._layouts[:, 0].cpu().numpy().astype(np.float64)

    def _pinned_layout(self, t: torch.Tensor, first_substep: bool) -> torch.Tensor:
        """Per env, which layout (LAYOUT_*) pins the objects for frame ``t``, or LAYOUT_FREE."""
        start = self.action_phase_start
        if self.APPEAR_SETTLE_STEPS > 0:
            settle = (t >= start) & (t < start + self.APPEAR_SETTLE_STEPS)
        else:
            settle = (t >= start) & ~self.manip_layout_applied & first_substep
        self.manip_layout_applied |= settle
        layout = torch.where(t < self.cue_steps_per_env, LAYOUT_CUE, LAYOUT_HIDDEN)
        layout = torch.where(settle, LAYOUT_ACTION, layout)
        return torch.where((t < start) | settle, layout, LAYOUT_FREE)

    def _pin(self, t: torch.Tensor, first_substep: bool, env_mask: torch.Tensor | None = None) -> None:
        """Teleport the objects of pinned envs to their layout for frame ``t``, zero velocity."""
        if self._free_from_step is not None and int(t[0]) > self._free_from_step:
            return  # CPU: the episode's objects are free from here on; skip the tensor logic
        layout = self._pinned_layout(t, first_substep)
        if env_mask is not None:
            layout = torch.where(env_mask, layout, LAYOUT_FREE)
        if not self.gpu_sim_enabled:
            # CPU sim (one env): set the SAPIEN bodies directly; ManiSkill's batched setters
            # cost ~10x more per call and this runs twice per step in pinned phases.
            which = int(layout[0])
            if which == LAYOUT_FREE:
                self._free_from_step = int(t[0])
                return
            for actor, row in zip(self.task_objects, self._layouts_np[which], strict=True):
                set_cpu_actor_pose(actor, row, zero_velocity=True)
            return
        idx = torch.nonzero(layout != LAYOUT_FREE).flatten()
        if len(idx) == 0:
            return
        # The GPU body buffer is fetched after _after_control_step: refresh it first, or
        # applying it would rewind every free body by this step's physics.
        self.scene.px.gpu_fetch_rigid_dynamic_data()
        write_actor_poses(self.scene, self.task_objects, idx, self._layouts[layout[idx], idx], zero_velocity=True)
        self.scene.px.gpu_apply_rigid_dynamic_data()

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self.manip_layout_applied[env_idx] = False
        self._free_from_step = None
        self._frame_layouts(env_idx)
        mask = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        mask[env_idx] = True
        self._pin(self.elapsed_steps, first_substep=True, env_mask=mask)

    def _on_state_restored(self, env_idx: torch.Tensor) -> None:
        super()._on_state_restored(env_idx)
        self._free_from_step = None
        self._frame_layouts(env_idx)

    def _before_control_step(self) -> None:
        # Lay out the frame this step produces (elapsed_steps + 1; the counter is incremented
        # after physics) before the first substep, so the robot meets the new layout.
        self._pin(self.elapsed_steps + 1, first_substep=True)

    def _after_control_step(self) -> None:
        # Pin again after the last substep: pinned objects show exactly at their phase poses,
        # undoing any push by the robot, the fall of hidden objects parked at z = 1000 and
        # collisions between them.
        self._pin(self.elapsed_steps + 1, first_substep=False)

    # --------------------------------------------------------------- queries
    def object_positions(self) -> torch.Tensor:
        """(B, N, 3) current origins of the candidate objects."""
        if not self.gpu_sim_enabled:
            positions = np.array([a._objs[0].pose.p for a in self.task_objects], dtype=np.float32)
            return torch.from_numpy(positions)[None].to(self.device)
        return torch.stack([a.pose.p for a in self.task_objects], dim=1)

    def target_position(self) -> torch.Tensor:
        """(B, 3) current origin of the answer object."""
        if not self.gpu_sim_enabled:
            actor = self.task_objects[int(self.answer_index[0])]
            return torch.from_numpy(np.asarray(actor._objs[0].pose.p, dtype=np.float32))[None].to(self.device)
        positions = self.object_positions()
        return positions[torch.arange(self.num_envs, device=self.device), self.answer_index]

    def evaluate(self) -> dict:
        """Placed (TCP within GOAL_THRESH of the answer), static, and success in the action phase."""
        obj_to_goal_pos = self.target_position() - self.agent.tcp.pose.p
        is_obj_placed = torch.linalg.norm(obj_to_goal_pos, dim=-1) <= self.GOAL_THRESH
        is_robot_static = self.arm_qvel.abs().max(dim=-1).values <= self.STATIC_QVEL_THRESH
        in_action_phase = self.elapsed_steps >= self.action_phase_start
        return dict(
            obj_to_goal_pos=obj_to_goal_pos,
            is_obj_placed=is_obj_placed,
            is_robot_static=is_robot_static,
            success=is_obj_placed & is_robot_static & in_action_phase,
        )

    def _get_obs_extra(self, info: dict) -> dict:
        obs = dict(tcp_pose=self.agent.tcp.pose.raw_pose)
        if self.obs_mode in ("state", "state_dict"):
            obs["oracle_info"] = self.oracle_info
            # Only the answer's position is non-zero; evaluate() already located it.
            target = info["obj_to_goal_pos"] + self.agent.tcp.pose.p
            is_target = torch.arange(self.num_objects, device=self.device) == self.answer_index[:, None]
            goals = (target[:, None, :] * is_target[..., None]).unbind(1)
            for k, goal in enumerate(goals):
                obs[f"goal_{k}_pose"] = goal
        return obs

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reaching + stillness + placed bonus − smoothness penalty; 3.0 on success."""
        distance = torch.linalg.norm(info["obj_to_goal_pos"], dim=-1)
        qvel_l2 = torch.linalg.norm(self.arm_qvel, dim=-1)
        reaching = 1 - torch.tanh(10 * distance)
        static = 1 - torch.tanh(5 * qvel_l2)
        bonus = 0.5 * (info["is_robot_static"] & info["is_obj_placed"]).float()
        penalty, smoothness = self.smoothness_penalty(action)
        reward = reaching + 0.5 * static + bonus - penalty
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = {
            "tcp_to_obj_dist": distance,
            "reaching_reward": reaching,
            "is_robot_static": info["is_robot_static"],
            "reached": distance < self.GOAL_THRESH,
            "success": info["success"],
            "static_reward": static,
            **smoothness,
            "obj_to_goal_pos_y": info["obj_to_goal_pos"][:, 1],
            "obj_to_goal_pos_x": info["obj_to_goal_pos"][:, 0],
        }
        return reward


class RememberVLABaseEnv(SelectionVLABaseEnv):
    """Remember protocol: the answer alone is shown at the cue spot, then all N appear."""

    CUE_SPOT_XY: ClassVar[tuple[float, float]] = (0.0, 0.0)
    # Upstream spreads the layout apart (after the phase draws) only when N = 3.
    SPREAD_WHEN_THREE: ClassVar[bool] = False

    def _set_layout(self, env_idx: torch.Tensor, action_poses: torch.Tensor) -> None:
        """Record the action-phase poses; the cue shows the answer alone at the cue spot."""
        answer = self.answer_index[env_idx]
        self.action_poses[env_idx] = action_poses
        cue = action_poses.clone()
        rows = torch.arange(len(env_idx), device=self.device)
        cue[rows, answer, 0] = self.CUE_SPOT_XY[0]
        cue[rows, answer, 1] = self.CUE_SPOT_XY[1]
        self.cue_poses[env_idx] = cue
        visible = torch.zeros_like(self.cue_visible[env_idx])
        visible[rows, answer] = True
        self.cue_visible[env_idx] = visible

    def _after_phase_sampling(self, env_idx: torch.Tensor) -> None:
        if not (self.SPREAD_WHEN_THREE and self.num_objects == 3):
            return
        for i in env_idx.tolist():
            self.action_poses[i, :, :2] = spread_and_stretch(self.action_poses[i, :, :2])
            # Hidden cue-phase objects keep their (new) action-phase x, y.
            shown = self.cue_visible[i, :, None]
            self.cue_poses[i, :, :2] = torch.where(shown, self.cue_poses[i, :, :2], self.action_poses[i, :, :2])

    @property
    def initial_poses(self) -> dict[int, torch.Tensor]:
        """Action-phase position of each object, key -> (B, 3)."""
        return {k: self.action_poses[:, k, :3] for k in range(self.num_objects)}


class FindImposterVLABaseEnv(SelectionVLABaseEnv):
    """Imposter protocol: N−1 objects are shown, then all N reappear with slots permuted."""

    # Written once at the first substep of the first action step, then free (upstream).
    APPEAR_SETTLE_STEPS = 0

    def _set_layout(self, env_idx: torch.Tensor, cue_poses: torch.Tensor) -> None:
        """Record cue poses; action poses permute the cue slots (never the identity)."""
        imposter = self.answer_index[env_idx]
        self.cue_poses[env_idx] = cue_poses
        action = cue_poses.clone()
        n = cue_poses.shape[1]
        for row in range(len(env_idx)):
            sigma = non_identity_permutation(n).to(self.device)
            action[row, :, :3] = cue_poses[row, sigma, :3]
        self.action_poses[env_idx] = action
        visible = torch.ones_like(self.cue_visible[env_idx])
        visible[torch.arange(len(env_idx), device=self.device), imposter] = False
        self.cue_visible[env_idx] = visible

    @property
    def imposter_key(self) -> torch.Tensor:
        """The imposter's key, uint8 (B,)."""
        return self.answer_index.to(torch.uint8)

    @property
    def _cue_raw_poses(self) -> dict[int, torch.Tensor]:
        return {k: self.cue_poses[:, k] for k in range(self.num_objects)}

    @property
    def _manip_raw_poses(self) -> dict[int, torch.Tensor]:
        return {k: self.action_poses[:, k] for k in range(self.num_objects)}


class ColorCubesMixin:
    """Objects of the two colour families: N cubes in the first N palette colours."""

    COLORS: ClassVar[int] = 3
    CUBE_HALFSIZE: ClassVar[float] = CUBE_HALF_SIZE

    @classmethod
    def candidate_count(cls) -> int:
        """N, the objects on the table in the action phase."""
        return cls.COLORS

    def _load_objects(self) -> ObjectSet:
        objects = palette_cubes(self.scene, self.COLORS)
        self.color_dict = objects.descriptions
        self.cubes = dict(enumerate(objects.actors))
        return objects


class BlueShapesMixin:
    """Objects of the two shape families: the first N task shapes, all blue."""

    SHAPES: ClassVar[int] = 3
    SHAPE_SCALE: ClassVar[float] = SHAPE_SCALE

    @classmethod
    def candidate_count(cls) -> int:
        """N, the objects on the table in the action phase."""
        return cls.SHAPES

    def _load_objects(self) -> ObjectSet:
        objects = blue_shapes(self.scene, self.SHAPES)
        self.shape_dict = objects.descriptions
        self.shape_actors = dict(enumerate(objects.actors))
        self.shape_resting_z = {k: float(objects.rest_poses[k, 2]) for k in self.shape_dict}
        return objects


class ShapeAndColorMixin:
    """Answer encoding and vocabularies shared by the two ShapeAndColor families.

    Object i is shape i // 3 in colour i % 3; ``oracle_info`` is (B, 2) uint8 [shape_id, color_id].
    """

    BASE_SHAPES: ClassVar[tuple[str, ...]] = SHAPE_AND_COLOR_SHAPES
    COLOR_PALETTE: ClassVar[tuple[np.ndarray, ...]] = tuple(rgba01(rgba) for _, rgba in COLOR_PALETTE_RGB)
    SHAPE_SCALE: ClassVar[float] = SHAPE_SCALE
    # Penalty-free dense reward in both ShapeAndColor families (upstream).
    ACTION_L2_COEF = 0.0
    ACTION_DELTA_L2_COEF = 0.0
    QVEL_L2_COEF = 0.0
    SHAPES: ClassVar[int] = 6
    JITTER = staticmethod(jitter_best_of)

    @classmethod
    def candidate_count(cls) -> int:
        """N, the objects on the table in the action phase."""
        return cls.SHAPES

    def _load_objects(self) -> ObjectSet:
        objects = shape_color_objects(self.scene, self.SHAPES)
        self.shape_color_dict = objects.descriptions
        self.shape_actors = dict(enumerate(objects.actors))
        self.shape_resting_z = {i: float(objects.rest_poses[i, 2]) for i in range(self.SHAPES)}
        return objects

    def _oracle_info_of(self, answer_index: torch.Tensor) -> torch.Tensor:
        n_colors = len(self.COLOR_PALETTE)
        return torch.stack([answer_index // n_colors, answer_index % n_colors], dim=-1).to(torch.uint8)

    @property
    def true_shape_indices(self) -> torch.Tensor:
        """The answer's object index (3·shape_id + color_id), uint8 (B,)."""
        return self.answer_index.to(torch.uint8)

    @property
    def true_shapes_info(self) -> torch.Tensor:
        """The answer's shape id, uint8 (B,)."""
        return self.oracle_info[:, 0]

    @property
    def true_colors_info(self) -> torch.Tensor:
        """The answer's colour id, uint8 (B,)."""
        return self.oracle_info[:, 1]


def selection_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of the six selection families: a uniform guess among the N objects on the
    table in the action phase."""
    n = env_class.candidate_count()
    which = "find the imposter among" if issubclass(env_class, FindImposterVLABaseEnv) else (
        "the shown one is one of"
    )
    return Chance(1 / n, f"1/{n}: {which} the {n} objects on the table in the action phase")


RL_FIXED_CUE_AND_DELAY = {"CUE_PHASE_STEPS": (5, 5), "EMPTY_PHASE_STEPS": (5, 5)}
"""The RL release's Remember* timing: the cue shown for 5 steps, then an empty table for 5
(``TIME_OFFSET = 5``, ``delta_time = 5`` upstream), where the VLA families draw each from
[1, 5]."""
