"""TraceShapeSeq: watch the red cube trace 2-5 shapes, trace them in order, then press submit."""

from __future__ import annotations

from typing import Any, ClassVar

import torch

from mikasa_envs.building_blocks.buttons import (
    BUTTON_TOP_Z,
    MAX_PRESS_DEPTH,
    PRESSED_DEPTH,
    RELEASED_DEPTH,
    Button,
)
from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._trace_shape import (
    NUM_WAYPOINTS,
    PADDING_SHAPE,
    SHAPE_CIRCLE,
    SHAPE_SQUARE,
    SHAPE_TRIANGLE,
    TraceShapeCommonVLABaseEnv,
)
from mikasa_envs.tasks._trace_shape_chance import trace_shape_chance

FAMILY = TaskFamily(
    "trace_shape_seq",
    hidden="the demonstrated contours and their order: traced during the cue, then gone",
    overlays="trace_shape",
    wrapper_table_rank=(32, 32),
    chance=trace_shape_chance,
)



class TraceShapeSeqVLABaseEnv(TraceShapeCommonVLABaseEnv):
    """**Task Description:** a lamp glows white, then red while a red cube traces 2-5 shapes
    (circles, squares, triangles) one after the other about the same centre, 64 waypoints
    each, with no pause between them; then the red cube disappears and the lamp turns green.
    Carry the green cube along every shape in the demonstrated order, each back to its start
    point, then press the submit button.

    **Randomizations:** the sequence length L ~ U{2..5} and each element's shape
    (independent, uniform over the variant's set); one centre x ~ U[−0.15, −0.05),
    y ~ U[−0.10, 0.10) for all elements; per element size R ~ U[0.078, 0.13) and rotation
    θ ~ U[0, 2π); the pre-demo length (3-8 steps); arm joint noise. The green cube starts at
    (−0.26, 0), the lamp stands at (0.2, 0) and the button at (−0.05, 0.38) in every episode:
    the reference puts them at centre + (−0.16, 0), + (0.25, 0) and + (0.27, 0.16), which
    show a policy without memory where the contours lie (DEVIATIONS.md).

    **Success Conditions:** only the active element is scored: its 12 checkpoints latch when
    the green cube's centre passes within 3.5 cm (XY); once all are visited and the cube is
    back within 3.5 cm of its checkpoint 0 the element is closed and the next one becomes
    active. Success = the button is pressed (TCP within 6.5 cm of it in XY and at most
    8.31 cm high) after all L elements are closed. Any press ends the episode; a press
    before that is a failed submit.
    """

    LANGUAGE_INSTRUCTION = (
        "Watch the red cube trace a sequence of shapes. When the lamp turns green, pick up the green cube "
        "and trace the same sequence in order. After finishing all shapes, press the button to submit your answer."
    )
    DENSE_REWARD_MAX = 40.0
    MAX_ELEMENTS = 5
    SIZE_BEFORE_CENTRE = False
    SEQUENCE_LEN_RANGE: ClassVar[tuple[int, int]] = (2, 5)
    CUE_PHASE_STEPS = (3 + 2 * NUM_WAYPOINTS, 8 + 5 * NUM_WAYPOINTS)
    # Submit button: base box, cap cylinder, colours, offset from the lamp, press radius (XY).
    BUTTON_BASE_HALF_SIZE: ClassVar[tuple[float, float, float]] = (0.065, 0.065, 0.015)
    BUTTON_CAP_RADIUS: ClassVar[float] = 0.03
    BUTTON_BASE_RGBA: ClassVar[tuple[int, int, int, int]] = (55, 64, 78, 255)
    BUTTON_CAP_RGBA: ClassVar[tuple[int, int, int, int]] = (210, 80, 80, 255)
    BUTTON_OFFSET_FROM_LAMP: ClassVar[tuple[float, float]] = (0.02, 0.16)
    # A fixed spot instead of the reference's lamp + BUTTON_OFFSET_FROM_LAMP (None: the offset).
    # The button sits beside the contours' region (y <= 0.284), its base more than a cube's
    # width clear of them and its 6.5 cm press radius clear of a TCP over any contour, in
    # view, 0.68 m from the robot's base (within a top-down press's reach of ~0.8 m).
    BUTTON_POSITION: ClassVar[tuple[float, float] | None] = (-0.05, 0.38)
    BUTTON_PRESS_RADIUS: ClassVar[float] = 0.065
    # Where the reward's button-reach term aims the TCP: (button XY, this height).
    BUTTON_REACH_Z: ClassVar[float] = 0.063
    FAILED_SUBMIT_REWARD: ClassVar[float] = -2.0
    TASK_STATE = (
        "button", "shape_closed", "_in_sequence", "press_ready", "button_pressed", "submit_success_latched",
        "_submitted", "_successful_submit",
    )

    button: Button
    button_top_z: float = BUTTON_TOP_Z

    # ---------------------------------------------------------------- scene
    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self.button = Button(
            self.scene, "submit_button", self.BUTTON_BASE_HALF_SIZE, self.BUTTON_CAP_RADIUS,
            self.BUTTON_BASE_RGBA, self.BUTTON_CAP_RGBA, self.num_envs, self.device,
        )
        b, dev = self.num_envs, self.device
        self.shape_closed = torch.zeros(b, self.MAX_ELEMENTS, dtype=torch.bool, device=dev)
        # Per env, which of the MAX_ELEMENTS slots hold a shape (index < L).
        self._in_sequence = torch.zeros(b, self.MAX_ELEMENTS, dtype=torch.bool, device=dev)
        self.press_ready = torch.ones(b, dtype=torch.bool, device=dev)
        self.button_pressed = torch.zeros(b, dtype=torch.bool, device=dev)
        self.submit_success_latched = torch.zeros(b, dtype=torch.bool, device=dev)
        # This step's press events (set once per step by the latch update).
        self._submitted = torch.zeros(b, dtype=torch.bool, device=dev)
        self._successful_submit = torch.zeros(b, dtype=torch.bool, device=dev)

    # ------------------------------------------------- published attributes
    @property
    def sequence_len(self) -> torch.Tensor:
        """(B,) number of shapes L."""
        return self._element_count

    @property
    def shape_sequence(self) -> torch.Tensor:
        """(B, 5) shape ids in demonstration order, −1 beyond L."""
        return self._element_shapes

    @property
    def active_shape_idx(self) -> torch.Tensor:
        """(B,) index of the element being scored."""
        return self._active_element

    @property
    def waypoints(self) -> torch.Tensor:
        """(B, 5, 64, 2) world XY waypoints per element (padding: the centre)."""
        return self._element_waypoints

    @property
    def checkpoints(self) -> torch.Tensor:
        """(B, 5, 12, 2) checkpoints per element."""
        return self._element_checkpoints

    @property
    def checkpoint_visited(self) -> torch.Tensor:
        """(B, 5, 12) latched visits per element."""
        return self._element_visited

    @property
    def button_xy(self) -> torch.Tensor:
        """(B, 2) button centre."""
        return self.button.xy

    # ------------------------------------------------------------- episodes
    def _sample_element_shapes(self, env_idx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # Torch: L for the reset envs, then the shapes of the first max(L) elements (one env:
        # its L shapes, as the reference); shapes beyond an env's L become padding.
        b, dev = len(env_idx), self.device
        lo, hi = self.SEQUENCE_LEN_RANGE
        counts = torch.randint(lo, hi + 1, (b,), device=dev)
        longest = int(counts.max())
        shapes = torch.full((b, self.MAX_ELEMENTS), PADDING_SHAPE, dtype=torch.long, device=dev)
        drawn = self._draw_shape_ids((b, longest))
        in_sequence = torch.arange(longest, device=dev) < counts[:, None]
        shapes[:, :longest] = torch.where(in_sequence, drawn, PADDING_SHAPE)
        return shapes, counts

    def _place_fixtures(self, env_idx: torch.Tensor, centre: torch.Tensor) -> None:
        super()._place_fixtures(env_idx, centre)
        lamp_xy = self.lamp.position[env_idx, :2]
        self.button.place(env_idx, self._fixture_xy(self.BUTTON_POSITION, self.BUTTON_OFFSET_FROM_LAMP, lamp_xy))

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        super()._on_episode_start(env_idx)
        self.shape_closed[env_idx] = False
        slots = torch.arange(self.MAX_ELEMENTS, device=self.device)
        self._in_sequence[env_idx] = slots < self._element_count[env_idx, None]
        self.press_ready[env_idx] = True
        self.button_pressed[env_idx] = False
        self.submit_success_latched[env_idx] = False
        self._submitted[env_idx] = False
        self._successful_submit[env_idx] = False
        self.task_cue = self._element_shapes

    def _oracle_info_now(self) -> torch.Tensor:
        return self._element_shapes

    # ------------------------------------------------------------- evaluate
    @property
    def all_shapes_closed(self) -> torch.Tensor:
        """(B,) every one of the L elements is closed."""
        return (self.shape_closed | ~self._in_sequence).all(dim=-1)

    def _after_scoring(
        self, fresh: torch.Tensor, scoring: torch.Tensor, progress: dict[str, torch.Tensor], action: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        # Close the active element and advance (its successor counts from the next step).
        closed_now = scoring & progress["is_closed"]
        if bool(closed_now.any()):
            self.shape_closed[self._rows, self._active_element] |= closed_now
            advance = closed_now & (self._active_element + 1 < self._element_count)
            if bool(advance.any()):
                self._active_element = self._active_element + advance.long()
                progress = self._score_active_element(torch.zeros_like(scoring), self._cube_position[:, :2])
        # Submit: a press event whenever the depth reaches PRESSED_DEPTH while armed; the
        # button is live in the action phase only.
        depth = self.button.press_depth(self._tcp_position, self.BUTTON_PRESS_RADIUS)
        depth = torch.where(action, depth, torch.zeros_like(depth))
        self.button.show_depth(depth)
        press = scoring & self.press_ready & (depth >= PRESSED_DEPTH)
        self.press_ready = (self.press_ready & ~press) | (scoring & (depth <= RELEASED_DEPTH))
        successful = press & self.all_shapes_closed
        self.button_pressed |= press
        self.submit_success_latched |= successful
        # Events belong to the step that produced them; a repeated evaluate() keeps them.
        self._submitted = torch.where(fresh, press, self._submitted)
        self._successful_submit = torch.where(fresh, successful, self._successful_submit)
        return progress

    def _task_info(self, masks: dict[str, torch.Tensor], progress: dict[str, torch.Tensor]) -> dict:
        action = masks["action_mask"]
        tcp = self._tcp_position
        all_closed = self.all_shapes_closed
        # Goal: the nearest unvisited checkpoint of the active element (checkpoint 0 once all
        # are visited), or the button once every shape is closed and it is not yet pressed.
        checkpoint = self._element_checkpoints[self._rows, self._active_element, progress["nearest_unvisited_index"]]
        goal = torch.cat([checkpoint, torch.full_like(tcp[:, :1], self.CUBE_HALFSIZE)], dim=-1)
        to_button = all_closed & ~self.button_pressed & action
        goal = torch.where(to_button[:, None], self._button_reach_point(), goal)
        return dict(
            success=self.submit_success_latched.clone(),
            failed_submit=self._submitted & ~self._successful_submit,
            submitted=self._submitted.clone(),
            successful_submit_event=self._successful_submit.clone(),
            **masks,
            sequence_progress=self.shape_closed.float().sum(dim=-1) / self._element_count,
            all_shapes_closed=all_closed,
            active_shape_idx=self._active_element.clone(),
            active_shape_id=self._element_shapes[self._rows, self._active_element],
            active_visit_fraction=progress["visit_fraction"],
            active_all_visited=progress["all_visited"],
            is_active_contour_closed=progress["is_closed"],
            start_checkpoint_dist=progress["start_checkpoint_dist"],
            button_pressed=self.button_pressed.clone(),
            button_pressable=all_closed & action,
            button_press_depth=self.button.depth.clone(),
            xy_dist_to_button=torch.linalg.norm(tcp[:, :2] - self.button.xy, dim=-1),
            submit_success_latched=self.submit_success_latched.clone(),
            obj_to_goal_pos=goal - tcp,
        )

    def _button_reach_point(self) -> torch.Tensor:
        """(B, 3) where the reward's button-reach term aims the TCP."""
        return torch.cat([self.button.xy, torch.full_like(self.button.xy[:, :1], self.BUTTON_REACH_Z)], dim=-1)

    def _privileged_obs(self, info: dict) -> dict[str, torch.Tensor]:
        return dict(
            sequence_progress=info["sequence_progress"],
            active_shape_idx=info["active_shape_idx"].float(),
            active_shape_id=info["active_shape_id"].float(),
            sequence_len=self._element_count.float(),
            button_xy=self.button.xy,
            button_pressed=info["button_pressed"].float(),
            oracle_info=self.oracle_info.float(),
        )

    def _terminated(self, info: dict) -> torch.Tensor:
        return info["success"] | info["submitted"]

    # ---------------------------------------------------------------- reward
    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict) -> torch.Tensor:
        """Reach, trace the active element, close the sequence, then reach and press the
        button; −2 on a failed submit, 40 on success."""
        terms = self._shared_reward_terms(info, action)
        active_all = info["active_all_visited"].float()
        button_reach = 1 - torch.tanh(8 * torch.linalg.norm(self._button_reach_point() - self._tcp_position, dim=-1))
        button_press = (info["button_press_depth"] / MAX_PRESS_DEPTH).clamp(0.0, 1.0)
        btn = (info["all_shapes_closed"] & ~info["button_pressed"] & info["action_mask"]).float()
        action_terms = (
            terms["reach"]
            + 1.8 * terms["near"]
            + 2.5 * info["active_visit_fraction"]
            + 3 * info["sequence_progress"]
            + 2 * active_all * terms["closure"]
        )
        reward = (
            0.5 * terms["cue"] * terms["reach"]
            + terms["act"] * action_terms
            + 1.5 * btn * button_reach
            + 2.5 * btn * button_press
            - terms["smooth"]
        )
        reward = torch.where(info["failed_submit"], torch.full_like(reward, self.FAILED_SUBMIT_REWARD), reward)
        reward = torch.where(info["success"], torch.full_like(reward, self.DENSE_REWARD_MAX), reward)
        self._reward_dict = {
            "tcp_to_cube_dist": terms["tcp_to_cube_dist"],
            "reach_reward": terms["reach"],
            "is_grasping": terms["near"].bool(),
            "active_visit_fraction": info["active_visit_fraction"],
            "sequence_progress": info["sequence_progress"],
            "closure_reward": terms["closure"],
            "button_reach_reward": button_reach,
            "button_press_reward": button_press,
            "failed_submit": info["failed_submit"],
            "success": info["success"],
            "action_l2": terms["action_l2"],
            "delta_action_l2": terms["delta_action_l2"],
            "qvel_l2": terms["qvel_l2"],
            "smooth_penalty": terms["smooth"],
        }
        return reward


@register_task(FAMILY, "TraceShapeSeqEasy-VLA-v0", number=77, split="long", data_source="MP",
               memory_type="Procedural", max_episode_steps=1500)
class TraceShapeSeqEasyVLAEnv(TraceShapeSeqVLABaseEnv):
    """TraceShapeSeq with circles only."""

    SHAPE_SET = (SHAPE_CIRCLE,)
    # trace_shape_guess_rate(SHAPE_SET, lengths=SEQUENCE_LEN_RANGE, shapes_shown=True)
    # (30,000 samples, seed 0): the chance rule's rate.
    GUESS_RATE = 0.0242


@register_task(FAMILY, "TraceShapeSeqMedium-VLA-v0", number=78, split="long", data_source="MP",
               memory_type="Procedural", max_episode_steps=1500)
class TraceShapeSeqMediumVLAEnv(TraceShapeSeqVLABaseEnv):
    """TraceShapeSeq with circles and squares."""

    SHAPE_SET = (SHAPE_CIRCLE, SHAPE_SQUARE)
    # trace_shape_guess_rate(SHAPE_SET, lengths=SEQUENCE_LEN_RANGE, shapes_shown=True)
    # (30,000 samples, seed 0): the chance rule's rate.
    GUESS_RATE = 0.0083


@register_task(FAMILY, "TraceShapeSeqHard-VLA-v0", number=79, split="long", data_source="MP",
               memory_type="Procedural", max_episode_steps=1500)
class TraceShapeSeqHardVLAEnv(TraceShapeSeqVLABaseEnv):
    """TraceShapeSeq with circles, squares and triangles."""

    SHAPE_SET = (SHAPE_CIRCLE, SHAPE_SQUARE, SHAPE_TRIANGLE)
    # trace_shape_guess_rate(SHAPE_SET, lengths=SEQUENCE_LEN_RANGE, shapes_shown=True)
    # (30,000 samples, seed 0): the chance rule's rate.
    GUESS_RATE = 0.0056
