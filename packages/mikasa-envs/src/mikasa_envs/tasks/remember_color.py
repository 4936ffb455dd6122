"""RememberColor: remember one cube's colour, then touch the cube of that colour."""

from __future__ import annotations

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._selection import (
    RL_FIXED_CUE_AND_DELAY,
    ColorCubesMixin,
    RememberVLABaseEnv,
    selection_chance,
)

FAMILY = TaskFamily(
    "remember_color",
    hidden="the shown cube's colour: in view during the cue, nothing during the delay",
    overlays="color_memory",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(12, 13),
    chance=selection_chance,
    rl_variants=(
        RLVariant(
            number=15, env_id="RememberColor3-v0", vla_env_id="RememberColor3-VLA-v0",
            group="RememberColor", memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_color_indices", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
        RLVariant(
            number=16, env_id="RememberColor5-v0", vla_env_id="RememberColor5-VLA-v0",
            group="RememberColor", memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_color_indices", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
        RLVariant(
            number=17, env_id="RememberColor9-v0", vla_env_id="RememberColor9-VLA-v0",
            group="RememberColor", memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_color_indices", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
    ),
)



class RememberColorVLABaseEnv(ColorCubesMixin, RememberVLABaseEnv):
    """**Task Description:** one cube is shown at the centre of the table; then nothing is
    visible for a delay; then all N differently coloured cubes appear at new places. Bring
    the TCP to the cube of the remembered colour and hold still.

    **Randomizations:** the answer colour; slot jitter (σ = 1 cm, ≥ 6 cm apart) and a random
    assignment of cubes to slots; for N = 3 the cubes are spread ~0.2 m apart along y; cue
    and delay lengths; arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the answer cube's
    centre and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = "Observe the cube's color, wait, then touch the cube of the same color."
    SPREAD_WHEN_THREE = True

    @property
    def true_color_indices(self):
        """The answer colour key, uint8 (B,)."""
        return self.oracle_info


@register_task(FAMILY, "RememberColor3-VLA-v0", number=14, split="short", data_source="PPO",
               memory_type="Object", max_episode_steps=25)
class RememberColor3VLAEnv(RememberColorVLABaseEnv):
    """RememberColor with 3 cubes."""

    COLORS = 3


@register_task(FAMILY, "RememberColor5-VLA-v0", number=15, split="short", data_source="PPO",
               memory_type="Object", max_episode_steps=25)
class RememberColor5VLAEnv(RememberColorVLABaseEnv):
    """RememberColor with 5 cubes."""

    COLORS = 5


@register_task(FAMILY, "RememberColor9-VLA-v0", number=16, split="short", data_source="PPO",
               memory_type="Object", max_episode_steps=25)
class RememberColor9VLAEnv(RememberColorVLABaseEnv):
    """RememberColor with 9 cubes."""

    COLORS = 9


@register_task(FAMILY, "RememberColor3-Long-VLA-v0", number=51, split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=600)
class RememberColor3LongVLAEnv(RememberColor3VLAEnv):
    """RememberColor with 3 cubes, a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)


@register_task(FAMILY, "RememberColor5-Long-VLA-v0", number=52, split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=600)
class RememberColor5LongVLAEnv(RememberColor5VLAEnv):
    """RememberColor with 5 cubes, a fixed 100-step cue (as upstream) and a 50-450 step delay."""

    CUE_PHASE_STEPS = (100, 100)
    EMPTY_PHASE_STEPS = (50, 450)


@register_task(FAMILY, "RememberColor9-Long-VLA-v0", number=53, split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=600)
class RememberColor9LongVLAEnv(RememberColor9VLAEnv):
    """RememberColor with 9 cubes, a fixed 100-step cue (as upstream) and a 50-450 step delay."""

    CUE_PHASE_STEPS = (100, 100)
    EMPTY_PHASE_STEPS = (50, 450)
