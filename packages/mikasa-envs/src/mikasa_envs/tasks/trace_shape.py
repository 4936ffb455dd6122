"""TraceShape: watch the red cube trace a shape, then trace it with the green cube."""

from __future__ import annotations

from typing import Any

import torch

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._trace_shape import (
    BULB_GREEN,
    BULB_RED,
    CHECKPOINT_STRIDE,
    NUM_CHECKPOINTS,
    NUM_WAYPOINTS,
    SHAPE_CIRCLE,
    SHAPE_SQUARE,
    SHAPE_TRIANGLE,
    TraceShapeCommonVLABaseEnv,
    checkpoints_of,
    shape_waypoints,
)
from mikasa_envs.tasks._trace_shape_chance import trace_shape_chance

FAMILY = TaskFamily(
    "trace_shape",
    hidden="the demonstrated contour: traced by the red cube during the cue, then gone",
    overlays="trace_shape",
    wrapper_table_rank=(31, 31),
    chance=trace_shape_chance,
)



class TraceShapeVLABaseEnv(TraceShapeCommonVLABaseEnv):
    """**Task Description:** a lamp glows white, then red while a red cube jumps along the 64
    waypoints of a circle, square or triangle (one per step); then the red cube disappears
    and the lamp turns green. Pick up the green cube (or push it) and move it along the same
    contour, back to where the demonstration started.

    **Randomizations:** the shape (uniform over the variant's set); the shape centre
    x ~ U[−0.15, −0.05), y ~ U[−0.10, 0.10), size R ~ U[0.078, 0.13) and rotation
    θ ~ U[0, 2π); the pre-demo length (3-8 steps); arm joint noise. The green cube starts at
    a fixed spot, (−0.26, 0), where the reference's cube, 0.16 m behind the centre, starts on
    average, and the lamp stands at (0.2, 0), where the reference's lamp, 0.25 m beyond the
    centre, stands at most: placed about the centre, each showed a policy without memory
    where the contour lies (DEVIATIONS.md).

    **Success Conditions:** in the action phase, the green cube's centre has come within
    3.5 cm (XY) of each of the 12 checkpoints (waypoints 0, 5, …, 55) and is now within
    3.5 cm of checkpoint 0 (the start). Evaluated each step; success ends the episode.
    """

    LANGUAGE_INSTRUCTION = (
        "Watch the red cube trace a shape on the table. When the lamp turns green, "
        "pick up the green cube and trace exactly the same shape."
    )
    DENSE_REWARD_MAX = 30.0
    MAX_ELEMENTS = 1
    CUE_PHASE_STEPS = (3 + NUM_WAYPOINTS, 8 + NUM_WAYPOINTS)

    # ------------------------------------------------- per-element views (E = 1)
    @property
    def shape_type(self) -> torch.Tensor:
        """(B,) shape id: 0 circle, 1 square, 2 triangle."""
        return self._element_shapes[:, 0]

    @property
    def waypoints(self) -> torch.Tensor:
        """(B, 64, 2) world XY waypoints of the shape."""
        return self._element_waypoints[:, 0]

    @property
    def checkpoints(self) -> torch.Tensor:
        """(B, 12, 2) checkpoints (waypoints 0, 5, …, 55)."""
        return self._element_checkpoints[:, 0]

    @property
    def checkpoint_visited(self) -> torch.Tensor:
        """(B, 12) latched visits (action phase only)."""
        return self._element_visited[:, 0]

    # ------------------------------------------------------------- episodes
    def _sample_element_shapes(self, env_idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b = len(env_idx)
        shapes = self._draw_shape_ids((b, 1))
        return shapes, torch.ones(b, dtype=torch.long, device=self.device)

    def _oracle_info_now(self) -> torch.Tensor:
        return self.shape_type.to(torch.uint8)

    # ------------------------------------------------------------- evaluate
    def _task_info(self, masks: dict[str, torch.Tensor], progress: dict[str, torch.Tensor]) -> dict:
        closed = progress["is_closed"]
        return dict(
            success=closed & masks["action_mask"],
            **masks,
            visit_fraction=progress["visit_fraction"],
            all_visited=progress["all_visited"],
            is_contour_closed=closed,
            start_checkpoint_dist=progress["start_checkpoint_dist"],
            checkpoint_visited=progress["visited"].clone(),
            obj_to_goal_pos=self._cube_position - self._tcp_position,
        )

    def _privileged_obs(self, info: dict) -> dict[str, torch.Tensor]:
        return dict(visit_fraction=info["visit_fraction"], oracle_info=self.oracle_info)

    def _terminated(self, info: dict) -> torch.Tensor:
        return info["success"].clone()

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reach the cube (any phase), then visit checkpoints and close the contour; 30 on success."""
        terms = self._shared_reward_terms(info, action)
        nearest = 1 - torch.tanh(5 * self._progress["nearest_unvisited_dist"])
        all_visited = info["all_visited"].float()
        near = terms["near"]
        action_terms = (
            terms["reach"]
            + 2 * near
            + 3 * info["visit_fraction"]
            + 2 * near * nearest
            + 2 * all_visited * terms["closure"]
        )
        reward = 0.5 * terms["cue"] * terms["reach"] + terms["act"] * action_terms - terms["smooth"]
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = {
            "tcp_to_cube_dist": terms["tcp_to_cube_dist"],
            "reach_reward": terms["reach"],
            "is_grasping": near.bool(),
            "nearest_checkpoint_reward": nearest,
            "visit_fraction": info["visit_fraction"],
            "closure_reward": terms["closure"],
            "all_visited": info["all_visited"],
            "success": info["success"],
            "action_l2": terms["action_l2"],
            "delta_action_l2": terms["delta_action_l2"],
            "qvel_l2": terms["qvel_l2"],
            "smooth_penalty": terms["smooth"],
        }
        return reward


@register_task(FAMILY, "TraceShapeEasy-VLA-v0", number=74, split="medium", data_source="MP",
               memory_type="Procedural", max_episode_steps=250)
class TraceShapeEasyVLAEnv(TraceShapeVLABaseEnv):
    """TraceShape with circles only."""

    SHAPE_SET = (SHAPE_CIRCLE,)
    # trace_shape_guess_rate(SHAPE_SET) (50,000 samples, seed 0): the chance rule's rate.
    GUESS_RATE = 0.0589


@register_task(FAMILY, "TraceShapeMedium-VLA-v0", number=75, split="medium", data_source="MP",
               memory_type="Procedural", max_episode_steps=300)
class TraceShapeMediumVLAEnv(TraceShapeVLABaseEnv):
    """TraceShape with circles and squares."""

    SHAPE_SET = (SHAPE_CIRCLE, SHAPE_SQUARE)
    # trace_shape_guess_rate(SHAPE_SET) (50,000 samples, seed 0): the chance rule's rate.
    GUESS_RATE = 0.0301


@register_task(FAMILY, "TraceShapeHard-VLA-v0", number=76, split="medium", data_source="MP",
               memory_type="Procedural", max_episode_steps=350)
class TraceShapeHardVLAEnv(TraceShapeVLABaseEnv):
    """TraceShape with circles, squares and triangles."""

    SHAPE_SET = (SHAPE_CIRCLE, SHAPE_SQUARE, SHAPE_TRIANGLE)
    # trace_shape_guess_rate(SHAPE_SET) (50,000 samples, seed 0): the chance rule's rate.
    GUESS_RATE = 0.0168


# The shape geometry the family's oracle and tools need, public here (``_trace_shape`` is the
# two trace families' private base).
__all__ = [
    "BULB_GREEN",
    "BULB_RED",
    "CHECKPOINT_STRIDE",
    "NUM_CHECKPOINTS",
    "NUM_WAYPOINTS",
    "SHAPE_CIRCLE",
    "SHAPE_SQUARE",
    "SHAPE_TRIANGLE",
    "TraceShapeCommonVLABaseEnv",
    "checkpoints_of",
    "shape_waypoints",
    "FAMILY",
    "TraceShapeVLABaseEnv",
    "TraceShapeEasyVLAEnv",
    "TraceShapeMediumVLAEnv",
    "TraceShapeHardVLAEnv",
]
