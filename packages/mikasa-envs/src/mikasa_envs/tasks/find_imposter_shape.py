"""FindImposterShape: see N−1 shapes, then touch the shape that was missing."""

from __future__ import annotations

from mikasa_envs.building_blocks.shapes import SHAPE_SCALE
from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._selection import BlueShapesMixin, FindImposterVLABaseEnv, selection_chance

FAMILY = TaskFamily(
    "find_imposter_shape",
    hidden=(
        "which shapes were shown: in view during the cue, nothing during the delay, then all "
        "N permuted"
    ),
    overlays="shape_memory",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(19, 19),
    chance=selection_chance,
)



class FindImposterShapeVLABaseEnv(BlueShapesMixin, FindImposterVLABaseEnv):
    """**Task Description:** N−1 of N blue objects of different shapes are shown at their
    slots; then nothing is visible for a delay; then all N reappear with their slots
    permuted. Bring the TCP to the object whose shape was not shown and hold still.

    **Randomizations:** the imposter; slot jitter (σ = 1 cm, ≥ 6 cm apart) and assignment;
    a non-identity permutation of the slots for the action phase; cue and delay lengths;
    arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the imposter's
    origin and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe the shapes shown, wait, then touch the object whose shape was not present before."
    )
    # Upstream places every shape's origin at z = 0.02: flat shapes hover during the cue and
    # drop when released (appearance only, kept).
    FIXED_OBJECT_Z = SHAPE_SCALE


@register_task(FAMILY, "FindImposterShape3-VLA-v0", number=38, split="short", data_source="PPO",
               memory_type="Negative", max_episode_steps=25)
class FindImposterShape3VLAEnv(FindImposterShapeVLABaseEnv):
    """FindImposterShape with cube, sphere, cylinder."""

    SHAPES = 3


@register_task(FAMILY, "FindImposterShape5-VLA-v0", number=39, split="short", data_source="PPO",
               memory_type="Negative", max_episode_steps=25)
class FindImposterShape5VLAEnv(FindImposterShapeVLABaseEnv):
    """FindImposterShape with 5 shapes."""

    SHAPES = 5


@register_task(FAMILY, "FindImposterShape9-VLA-v0", number=40, split="short", data_source="PPO",
               memory_type="Negative", max_episode_steps=25)
class FindImposterShape9VLAEnv(FindImposterShapeVLABaseEnv):
    """FindImposterShape with all 9 shapes."""

    SHAPES = 9
