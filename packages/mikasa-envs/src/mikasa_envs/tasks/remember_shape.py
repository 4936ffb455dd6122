"""RememberShape: remember one object's shape, then touch the object of that shape."""

from __future__ import annotations

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._selection import (
    RL_FIXED_CUE_AND_DELAY,
    BlueShapesMixin,
    RememberVLABaseEnv,
    selection_chance,
)

FAMILY = TaskFamily(
    "remember_shape",
    hidden="the shown object's shape: in view during the cue, nothing during the delay",
    overlays="shape_memory",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(14, 15),
    chance=selection_chance,
    rl_variants=(
        RLVariant(
            number=18, env_id="RememberShape3-v0", vla_env_id="RememberShape3-VLA-v0",
            group="RememberShape", memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_shape_indices", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
        RLVariant(
            number=19, env_id="RememberShape5-v0", vla_env_id="RememberShape5-VLA-v0",
            group="RememberShape", memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_shape_indices", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
        RLVariant(
            number=20, env_id="RememberShape9-v0", vla_env_id="RememberShape9-VLA-v0",
            group="RememberShape", memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_shape_indices", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
    ),
)



class RememberShapeVLABaseEnv(BlueShapesMixin, RememberVLABaseEnv):
    """**Task Description:** one blue object is shown at the centre of the table; then
    nothing is visible for a delay; then all N blue objects of different shapes appear at
    new places. Bring the TCP to the object of the remembered shape and hold still.

    **Randomizations:** the answer shape; slot jitter (σ = 1 cm, ≥ 6 cm apart) and a random
    assignment of objects to slots; for N = 3 the objects are spread ~0.2 m apart along y;
    cue and delay lengths; arm joint noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the answer
    object's origin and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = "Observe the object's shape, wait, then touch the object of the same shape."
    # Objects teleported onto the table are held in place for 3 frames (upstream).
    APPEAR_SETTLE_STEPS = 3
    SPREAD_WHEN_THREE = True

    @property
    def true_shape_indices(self):
        """The answer shape key, uint8 (B,)."""
        return self.oracle_info


@register_task(FAMILY, "RememberShape3-VLA-v0", number=17, split="short", data_source="PPO",
               memory_type="Object", max_episode_steps=25)
class RememberShape3VLAEnv(RememberShapeVLABaseEnv):
    """RememberShape with cube, sphere, cylinder."""

    SHAPES = 3


@register_task(FAMILY, "RememberShape5-VLA-v0", number=18, split="short", data_source="PPO",
               memory_type="Object", max_episode_steps=25)
class RememberShape5VLAEnv(RememberShapeVLABaseEnv):
    """RememberShape with 5 shapes (+ cross, torus)."""

    SHAPES = 5


@register_task(FAMILY, "RememberShape9-VLA-v0", number=19, split="short", data_source="PPO",
               memory_type="Object", max_episode_steps=25)
class RememberShape9VLAEnv(RememberShapeVLABaseEnv):
    """RememberShape with all 9 shapes."""

    SHAPES = 9


@register_task(FAMILY, "RememberShape3-Long-VLA-v0", number=54, split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=600)
class RememberShape3LongVLAEnv(RememberShape3VLAEnv):
    """RememberShape3 with a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)


@register_task(FAMILY, "RememberShape5-Long-VLA-v0", number=55, split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=600)
class RememberShape5LongVLAEnv(RememberShape5VLAEnv):
    """RememberShape5 with a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)


@register_task(FAMILY, "RememberShape9-Long-VLA-v0", number=56, split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=600)
class RememberShape9LongVLAEnv(RememberShape9VLAEnv):
    """RememberShape9 with a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)
