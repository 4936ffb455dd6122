"""BunchOfColors: remember which cubes were shown together, touch all of them, press the button."""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import torch

from mikasa_envs.family import Chance, RLVariant, TaskFamily, TaskSpec
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._color_sequence import (
    RL_COLOR_SEQUENCE_TIMING,
    ColorSequenceVLABaseEnv,
)


def color_set_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of BunchOfColors: a uniform guess of the shown set of L of the cubes."""
    length, colors = env_class.SEQUENCE_LENGTH, env_class.COLORS
    sets = math.comb(colors, length)
    return Chance(1 / sets, f"1/C({colors},{length}) = 1/{sets}: the shown set of {length} of {colors} cubes")


FAMILY = TaskFamily(
    "bunch_of_colors",
    hidden="the set of shown cubes: in view together during the cue, nothing during the delay",
    overlays="memory_capacity",
    wrapper_table_rank=(21, 22),
    chance=color_set_chance,
    rl_variants=(
        RLVariant(
            number=24, env_id="BunchOfColors3-v0", vla_env_id="BunchOfColors3-VLA-v0",
            group="BunchOfColors", memory_type="Capacity", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
        RLVariant(
            number=25, env_id="BunchOfColors5-v0", vla_env_id="BunchOfColors5-VLA-v0",
            group="BunchOfColors", memory_type="Capacity", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
        RLVariant(
            number=26, env_id="BunchOfColors7-v0", vla_env_id="BunchOfColors7-VLA-v0",
            group="BunchOfColors", memory_type="Capacity", max_episode_steps=120,
            reward_divisor=100.0, oracle_info="true_color_indices",
            overrides=RL_COLOR_SEQUENCE_TIMING,
        ),
    ),
)



def cue_spot_xyz(num_colors: int = 9, half_size: float = 0.02) -> np.ndarray:
    """(9, 3) fixed per-colour cue spots (§3.5): b = π·(k − 4)/9,
    x = 0.22·cos b, y = 0.22·sin b − 0.015·(k − 4), z = half size."""
    centred = np.arange(num_colors, dtype=np.float64) - (num_colors - 1) / 2
    angles = np.pi * centred / num_colors
    x = 0.22 * np.cos(angles)
    y = 0.22 * np.sin(angles) - 0.015 * centred
    return np.stack([x, y, np.full(num_colors, half_size)], axis=1)


class BunchOfColorsVLABaseEnv(ColorSequenceVLABaseEnv):
    """**Task Description:** L of nine coloured cubes are shown together, each at a fixed
    spot of its colour on an arc in front of the robot, with a button at the centre of the
    table; then no cube is visible for a delay; then all nine cubes appear on an arc around
    the button. Touch every cube that was shown (any order, TCP held still just above it),
    touch no other, then press the button (push the TCP down over it and lift it again) and
    hold still.

    **Randomizations:** the L target colours; the layout (arc points jittered by σ = 1 cm,
    ≥ 6 cm apart, assigned to colours at random) and with it the button position; cue and
    delay lengths; arm joint noise.

    **Success Conditions:** in the action phase, exactly the L target cubes have been
    touched (TCP within 2 cm of the point 5 mm above a cube's top while every arm joint
    moves slower than 0.2 rad/s), a press has been confirmed after that, no cube has been
    pushed more than 6 cm from its layout point, and the arm is static.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe which colored cubes appear during the cue, wait, then touch all of them in any order "
        "and press the center button."
    )
    CUE_SPOTS: ClassVar[np.ndarray] = cue_spot_xyz()

    def _cue_layouts(self, env_idx: torch.Tensor) -> torch.Tensor:
        """One cue frame: the targets at their colours' spots, the other cubes hidden."""
        cue = self._hidden_poses(env_idx)
        spots = torch.as_tensor(self.CUE_SPOTS, dtype=cue.dtype, device=self.device)
        shown = self.sequence_cubes_mask[env_idx, :, None]
        cue[..., :3] = torch.where(shown, spots, cue[..., :3])
        return cue[None]


@register_task(FAMILY, "BunchOfColors3-VLA-v0", number=23, split="medium", data_source="MP",
               memory_type="Capacity", max_episode_steps=400)
class BunchOfColors3VLAEnv(BunchOfColorsVLABaseEnv):
    """BunchOfColors with 3 targets."""

    SEQUENCE_LENGTH = 3


@register_task(FAMILY, "BunchOfColors5-VLA-v0", number=24, split="medium", data_source="MP",
               memory_type="Capacity", max_episode_steps=400)
class BunchOfColors5VLAEnv(BunchOfColorsVLABaseEnv):
    """BunchOfColors with 5 targets."""

    SEQUENCE_LENGTH = 5


@register_task(FAMILY, "BunchOfColors7-VLA-v0", number=25, split="medium", data_source="MP",
               memory_type="Capacity", max_episode_steps=400)
class BunchOfColors7VLAEnv(BunchOfColorsVLABaseEnv):
    """BunchOfColors with 7 targets."""

    SEQUENCE_LENGTH = 7


@register_task(FAMILY, "BunchOfColors3-Long-VLA-v0", number=60, split="long", data_source="MP",
               memory_type="Capacity", max_episode_steps=700)
class BunchOfColors3LongVLAEnv(BunchOfColors3VLAEnv):
    """BunchOfColors with 3 targets, a 10-100 step cue and a 50-400 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)


@register_task(FAMILY, "BunchOfColors5-Long-VLA-v0", number=61, split="long", data_source="MP",
               memory_type="Capacity", max_episode_steps=700)
class BunchOfColors5LongVLAEnv(BunchOfColors5VLAEnv):
    """BunchOfColors with 5 targets, a 10-100 step cue and a 50-400 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)


@register_task(FAMILY, "BunchOfColors7-Long-VLA-v0", number=62, split="long", data_source="MP",
               memory_type="Capacity", max_episode_steps=700)
class BunchOfColors7LongVLAEnv(BunchOfColors7VLAEnv):
    """BunchOfColors with 7 targets, a 10-100 step cue and a 50-400 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 400)
