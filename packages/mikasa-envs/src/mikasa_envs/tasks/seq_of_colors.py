"""SeqOfColors: remember cubes shown one after another, touch them in that order, press the button."""

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
    "seq_of_colors",
    hidden=(
        "the shown cubes and their order: one at a time during the cue, nothing during the "
        "delay"
    ),
    overlays="memory_capacity",
    wrapper_table_rank=(23, 24),
    chance=color_sequence_chance,
    rl_variants=(
        RLVariant(
            number=27, env_id="SeqOfColors3-v0", vla_env_id="SeqOfColors3-VLA-v0",
            group="SeqOfColors", memory_type="Capacity", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
        RLVariant(
            number=28, env_id="SeqOfColors5-v0", vla_env_id="SeqOfColors5-VLA-v0",
            group="SeqOfColors", memory_type="Capacity", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
        RLVariant(
            number=29, env_id="SeqOfColors7-v0", vla_env_id="SeqOfColors7-VLA-v0",
            group="SeqOfColors", memory_type="Capacity", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
    ),
)



class SeqOfColorsVLABaseEnv(OrderedColorSequenceVLABaseEnv):
    """**Task Description:** L of nine coloured cubes are shown one at a time at the centre
    of the table, each for the same number of steps, with a button in front of the robot;
    then no cube is visible for a delay; then all nine cubes appear on an arc around the
    button. Touch the shown cubes in the order they were shown (TCP held still just above
    each one), touch no other, then press the button and hold still. The instruction says
    "in any order", as upstream's does, but the order is enforced (``seq_of_colors.md``
    quirk 1).

    **Randomizations:** the L target colours and their order; the layout (arc points
    jittered by σ = 1 cm, ≥ 6 cm apart, assigned to colours at random) and with it the
    button position; the per-cube cue duration and the delay; arm joint noise.

    **Success Conditions:** in the action phase, the L target cubes have been touched, in
    cue order and no other cube at all (a touch: TCP within 2 cm of the point 5 mm above a
    cube's top while every arm joint moves slower than 0.2 rad/s), a press has been
    confirmed after that, no cube has been pushed more than 6 cm from its layout point, and
    the arm is static.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe which colored cubes appear during the cue, wait, then touch all of them in any order "
        "and press the center button."
    )

    @property
    def wrong_order_touched(self) -> torch.Tensor:
        """(B,) whether some filled slot holds a key other than the target at that slot."""
        return ((self.touched_cubes_idx >= 0) & ~self.slot_matches).any(dim=-1)

    def _order_ok(self) -> torch.Tensor:
        return ~self.wrong_order_touched

    def _next_target_key(self) -> torch.Tensor:
        """The target at the first empty slot, unless an out-of-order touch happened."""
        filled = (self.touched_cubes_idx >= 0).sum(dim=-1)
        ok = (filled < self.SEQUENCE_LENGTH) & ~self.wrong_order_touched
        slot = filled.clamp(max=self.SEQUENCE_LENGTH - 1)
        key = self.target_keys.gather(1, slot[:, None])[:, 0]
        return torch.where(ok, key, -1)


@register_task(FAMILY, "SeqOfColors3-VLA-v0", number=26, split="medium", data_source="MP",
               memory_type="Capacity", max_episode_steps=400)
class SeqOfColors3VLAEnv(SeqOfColorsVLABaseEnv):
    """SeqOfColors with 3 targets."""

    SEQUENCE_LENGTH = 3


@register_task(FAMILY, "SeqOfColors5-VLA-v0", number=27, split="medium", data_source="MP",
               memory_type="Capacity", max_episode_steps=400)
class SeqOfColors5VLAEnv(SeqOfColorsVLABaseEnv):
    """SeqOfColors with 5 targets."""

    SEQUENCE_LENGTH = 5


@register_task(FAMILY, "SeqOfColors7-VLA-v0", number=28, split="medium", data_source="MP",
               memory_type="Capacity", max_episode_steps=400)
class SeqOfColors7VLAEnv(SeqOfColorsVLABaseEnv):
    """SeqOfColors with 7 targets."""

    SEQUENCE_LENGTH = 7


@register_task(FAMILY, "SeqOfColors3-Long-VLA-v0", number=63, split="long", data_source="MP",
               memory_type="Capacity", max_episode_steps=800)
class SeqOfColors3LongVLAEnv(SeqOfColors3VLAEnv):
    """SeqOfColors with 3 targets shown 10-100 steps each and a 50-400 step delay."""

    CUE_STEP_DURATION = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)


@register_task(FAMILY, "SeqOfColors5-Long-VLA-v0", number=64, split="long", data_source="MP",
               memory_type="Capacity", max_episode_steps=1000)
class SeqOfColors5LongVLAEnv(SeqOfColors5VLAEnv):
    """SeqOfColors with 5 targets shown 10-100 steps each and a 50-400 step delay."""

    CUE_STEP_DURATION = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)


@register_task(FAMILY, "SeqOfColors7-Long-VLA-v0", number=65, split="long", data_source="MP",
               memory_type="Capacity", max_episode_steps=1200)
class SeqOfColors7LongVLAEnv(SeqOfColors7VLAEnv):
    """SeqOfColors with 7 targets shown 10-100 steps each and a 50-400 step delay."""

    CUE_STEP_DURATION = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)
