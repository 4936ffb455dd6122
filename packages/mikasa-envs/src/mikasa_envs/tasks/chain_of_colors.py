"""ChainOfColors: touch the cubes in the order they were shown, then press the button."""

from __future__ import annotations

import torch

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._color_sequence import RL_COLOR_SEQUENCE_TIMING
from mikasa_envs.tasks._ordered_color_sequence import (
    OrderedColorSequenceVLABaseEnv,
    color_sequence_chance,
)

FAMILY = TaskFamily(
    "chain_of_colors",
    hidden=(
        "the shown cubes and their order: one at a time during the cue, nothing during the "
        "delay"
    ),
    overlays="memory_capacity",
    wrapper_table_rank=(25, 26),
    chance=color_sequence_chance,
    rl_variants=(
        RLVariant(
            number=30, env_id="ChainOfColors3-v0", vla_env_id="ChainOfColors3-VLA-v0",
            group="ChainOfColors", memory_type="Sequential", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
        RLVariant(
            number=31, env_id="ChainOfColors5-v0", vla_env_id="ChainOfColors5-VLA-v0",
            group="ChainOfColors", memory_type="Sequential", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
        RLVariant(
            number=32, env_id="ChainOfColors7-v0", vla_env_id="ChainOfColors7-VLA-v0",
            group="ChainOfColors", memory_type="Sequential", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
    ),
)



class ChainOfColorsVLABaseEnv(OrderedColorSequenceVLABaseEnv):
    """**Task Description:** L of nine coloured cubes are shown one at a time at the centre
    of the table, each for the same number of steps, with a button in front of the robot;
    then no cube is visible for a delay; then all nine cubes appear on an arc around the
    button. Touch the shown cubes in the order they were shown (TCP held still just above
    each one), touch no other, then press the button and hold still.

    **Randomizations:** the L target colours and their order; the layout (arc points
    jittered by σ = 1 cm, ≥ 6 cm apart, assigned to colours at random) and with it the
    button position; the per-cube cue duration and the delay; arm joint noise.

    **Success Conditions:** in the action phase, the first touches of distinct cubes were
    exactly the L targets in cue order (a touch: TCP within 2 cm of the point 5 mm above a
    cube's top while every arm joint moves slower than 0.2 rad/s), a press has been
    confirmed after that, no cube has been pushed more than 6 cm from its layout point, and
    the arm is static.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe which colored cubes appear during the cue, wait, then touch all of them in the same order "
        "as the cubes were shown and press the center button."
    )
    CORRECT_TOUCHES_KEY = "correct_touches_in_order"

    @property
    def touched_in_correct_order(self) -> torch.Tensor:
        """(B,) whether every slot holds the target at that slot."""
        return self.slot_matches.all(dim=-1)

    def _order_ok(self) -> torch.Tensor:
        return self.touched_in_correct_order

    def _next_target_key(self) -> torch.Tensor:
        """The target at the first slot not holding its target (stuck there after a wrong touch)."""
        mismatch = ~self.slot_matches
        slot = mismatch.int().argmax(dim=-1)
        key = self.target_keys.gather(1, slot[:, None])[:, 0]
        return torch.where(mismatch.any(dim=-1), key, -1)

    def touch_counts(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(slots holding their target, filled slots holding another key); upstream's
        "in order" count is the plain number of matching slots (quirk 1)."""
        matches = self.slot_matches
        wrong = (self.touched_cubes_idx >= 0) & ~matches
        return matches.sum(dim=-1), wrong.sum(dim=-1)


@register_task(FAMILY, "ChainOfColors3-VLA-v0", number=29, split="medium", data_source="MP",
               memory_type="Sequential", max_episode_steps=400)
class ChainOfColors3VLAEnv(ChainOfColorsVLABaseEnv):
    """ChainOfColors with 3 targets."""

    SEQUENCE_LENGTH = 3


@register_task(FAMILY, "ChainOfColors5-VLA-v0", number=30, split="medium", data_source="MP",
               memory_type="Sequential", max_episode_steps=400)
class ChainOfColors5VLAEnv(ChainOfColorsVLABaseEnv):
    """ChainOfColors with 5 targets."""

    SEQUENCE_LENGTH = 5


@register_task(FAMILY, "ChainOfColors7-VLA-v0", number=31, split="medium", data_source="MP",
               memory_type="Sequential", max_episode_steps=400)
class ChainOfColors7VLAEnv(ChainOfColorsVLABaseEnv):
    """ChainOfColors with 7 targets."""

    SEQUENCE_LENGTH = 7


@register_task(FAMILY, "ChainOfColors3-Long-VLA-v0", number=66, split="long", data_source="MP",
               memory_type="Sequential", max_episode_steps=800)
class ChainOfColors3LongVLAEnv(ChainOfColors3VLAEnv):
    """ChainOfColors with 3 targets shown 10-100 steps each and a 50-400 step delay."""

    CUE_STEP_DURATION = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)


@register_task(FAMILY, "ChainOfColors5-Long-VLA-v0", number=67, split="long", data_source="MP",
               memory_type="Sequential", max_episode_steps=1000)
class ChainOfColors5LongVLAEnv(ChainOfColors5VLAEnv):
    """ChainOfColors with 5 targets shown 10-100 steps each and a 50-400 step delay."""

    CUE_STEP_DURATION = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)


@register_task(FAMILY, "ChainOfColors7-Long-VLA-v0", number=68, split="long", data_source="MP",
               memory_type="Sequential", max_episode_steps=1200)
class ChainOfColors7LongVLAEnv(ChainOfColors7VLAEnv):
    """ChainOfColors with 7 targets shown 10-100 steps each and a 50-400 step delay."""

    CUE_STEP_DURATION = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)
