"""FindImposterShapeAndColor: see N−1 (shape, colour) objects, then touch the missing one."""

from __future__ import annotations

from mikasa_envs.building_blocks.shapes import SHAPE_SCALE
from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._selection import (
    FindImposterVLABaseEnv,
    ShapeAndColorMixin,
    arc_slots,
    selection_chance,
)

FAMILY = TaskFamily(
    "find_imposter_shape_and_color",
    hidden=(
        "which shape-colour pairs were shown: in view during the cue, nothing during the "
        "delay, then all N permuted"
    ),
    overlays="shape_color_memory",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(20, 20),
    chance=selection_chance,
)



class FindImposterShapeAndColorVLABaseEnv(ShapeAndColorMixin, FindImposterVLABaseEnv):
    """**Task Description:** N−1 of N objects (every combination of some shapes and red,
    green, blue) are shown at their slots; then nothing is visible for a delay; then all N
    reappear with their slots permuted. Bring the TCP to the object whose shape-and-colour
    combination was not shown and hold still.

    **Randomizations:** the imposter; slot jitter (best of 20 draws, σ = 1 cm) and
    assignment on a semicircle (radius 0.3 m, 0.45 m for 15 objects); a non-identity
    permutation of the slots for the action phase; cue and delay lengths; arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the imposter's
    origin and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe the objects shown, wait, then touch the object whose shape and color "
        "combination was not present before."
    )
    # Every object's origin at z = 0.02 as upstream (flat shapes hover during the cue).
    FIXED_OBJECT_Z = SHAPE_SCALE

    def _base_slots(self):
        n = self.SHAPES
        radius = 0.3 if n <= 9 else 0.45
        y_shift = 0.025 if (n % 2 == 1 and n > 3) else 0.0
        return arc_slots(n, radius=radius, even_offset=True, y_shift=y_shift)


@register_task(FAMILY, "FindImposterShapeAndColor3x2-VLA-v0", number=41, split="short",
               data_source="PPO", memory_type="Negative", max_episode_steps=25)
class FindImposterShapeAndColor3x2VLAEnv(FindImposterShapeAndColorVLABaseEnv):
    """3 colours x 2 shapes (6 objects)."""

    SHAPES = 6


@register_task(FAMILY, "FindImposterShapeAndColor3x3-VLA-v0", number=42, split="short",
               data_source="PPO", memory_type="Negative", max_episode_steps=25)
class FindImposterShapeAndColor3x3VLAEnv(FindImposterShapeAndColorVLABaseEnv):
    """3 colours x 3 shapes (9 objects)."""

    SHAPES = 9


@register_task(FAMILY, "FindImposterShapeAndColor5x3-VLA-v0", number=43, split="short",
               data_source="PPO", memory_type="Negative", max_episode_steps=40)
class FindImposterShapeAndColor5x3VLAEnv(FindImposterShapeAndColorVLABaseEnv):
    """5 shapes x 3 colours (15 objects); 40-step horizon as registered upstream."""

    SHAPES = 15
