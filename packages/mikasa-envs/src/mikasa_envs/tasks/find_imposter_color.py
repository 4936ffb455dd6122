"""FindImposterColor: see N−1 coloured cubes, then touch the colour that was missing."""

from __future__ import annotations

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._selection import ColorCubesMixin, FindImposterVLABaseEnv, selection_chance

FAMILY = TaskFamily(
    "find_imposter_color",
    hidden=(
        "which colours were shown: in view during the cue, nothing during the delay, then all "
        "N permuted"
    ),
    overlays="color_memory",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(18, 18),
    chance=selection_chance,
)



class FindImposterColorVLABaseEnv(ColorCubesMixin, FindImposterVLABaseEnv):
    """**Task Description:** N−1 of N differently coloured cubes are shown at their slots;
    then nothing is visible for a delay; then all N cubes reappear with their slots
    permuted. Bring the TCP to the cube whose colour was not shown and hold still.

    **Randomizations:** the imposter; slot jitter (σ = 1 cm, ≥ 6 cm apart) and assignment;
    a non-identity permutation of the slots for the action phase; cue and delay lengths;
    arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the imposter's
    centre and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe the cubes shown, wait, then touch the cube whose color was not present before."
    )


@register_task(FAMILY, "FindImposterColor3-VLA-v0", number=35, split="short", data_source="PPO",
               memory_type="Negative", max_episode_steps=25)
class FindImposterColor3VLAEnv(FindImposterColorVLABaseEnv):
    """FindImposterColor with 3 cubes."""

    COLORS = 3


@register_task(FAMILY, "FindImposterColor5-VLA-v0", number=36, split="short", data_source="PPO",
               memory_type="Negative", max_episode_steps=25)
class FindImposterColor5VLAEnv(FindImposterColorVLABaseEnv):
    """FindImposterColor with 5 cubes."""

    COLORS = 5


@register_task(FAMILY, "FindImposterColor9-VLA-v0", number=37, split="short", data_source="PPO",
               memory_type="Negative", max_episode_steps=25)
class FindImposterColor9VLAEnv(FindImposterColorVLABaseEnv):
    """FindImposterColor with 9 cubes."""

    COLORS = 9
