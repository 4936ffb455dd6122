"""RememberShapeAndColor: remember a (shape, colour) pair, then touch the matching object."""

from __future__ import annotations

from mikasa_envs.family import RLVariant, TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._selection import (
    RL_FIXED_CUE_AND_DELAY,
    RememberVLABaseEnv,
    ShapeAndColorMixin,
    arc_slots,
    selection_chance,
)

FAMILY = TaskFamily(
    "remember_shape_and_color",
    hidden="the shown object's shape and colour: in view during the cue, nothing during the delay",
    overlays="shape_color_memory",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(16, 17),
    chance=selection_chance,
    rl_variants=(
        RLVariant(
            number=21, env_id="RememberShapeAndColor3x2-v0",
            vla_env_id="RememberShapeAndColor3x2-VLA-v0", group="RememberShapeAndColor",
            memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_shapes_info+true_colors_info", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
        RLVariant(
            number=22, env_id="RememberShapeAndColor3x3-v0",
            vla_env_id="RememberShapeAndColor3x3-VLA-v0", group="RememberShapeAndColor",
            memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_shapes_info+true_colors_info", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
        RLVariant(
            number=23, env_id="RememberShapeAndColor5x3-v0",
            vla_env_id="RememberShapeAndColor5x3-VLA-v0", group="RememberShapeAndColor",
            memory_type="Object", max_episode_steps=60, reward_divisor=3.0,
            oracle_info="true_shapes_info+true_colors_info", overrides=RL_FIXED_CUE_AND_DELAY,
        ),
    ),
)



class RememberShapeAndColorVLABaseEnv(ShapeAndColorMixin, RememberVLABaseEnv):
    """**Task Description:** one object is shown at the centre of the table; then nothing is
    visible for a delay; then N objects appear, every combination of some shapes (cube,
    sphere, t_shape, cross, torus) and colours (red, green, blue). Bring the TCP to the object
    with the remembered shape *and* colour and hold still.

    **Randomizations:** the answer object; slot jitter (best of 20 draws, σ = 1 cm) and a
    random assignment of objects to slots on a 0.3 m semicircle; cue and delay lengths; arm
    joint noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the answer
    object's origin and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe the object's shape and color, wait, then touch the object of the same shape and color."
    )
    APPEAR_SETTLE_STEPS = 3

    def _base_slots(self):
        # Upstream shifts y only for N in {5, 9}: of 6, 9, 15 objects only N = 9.
        y_shift = 0.025 if self.SHAPES in (5, 9) else 0.0
        return arc_slots(self.SHAPES, radius=0.3, even_offset=True, y_shift=y_shift)


@register_task(FAMILY, "RememberShapeAndColor3x2-VLA-v0", number=20, split="short",
               data_source="PPO", memory_type="Object", max_episode_steps=25)
class RememberShapeAndColor3x2VLAEnv(RememberShapeAndColorVLABaseEnv):
    """3 colours x 2 shapes (6 objects)."""

    SHAPES = 6


@register_task(FAMILY, "RememberShapeAndColor3x3-VLA-v0", number=21, split="short",
               data_source="PPO", memory_type="Object", max_episode_steps=25)
class RememberShapeAndColor3x3VLAEnv(RememberShapeAndColorVLABaseEnv):
    """3 colours x 3 shapes (9 objects)."""

    SHAPES = 9


@register_task(FAMILY, "RememberShapeAndColor5x3-VLA-v0", number=22, split="short",
               data_source="PPO", memory_type="Object", max_episode_steps=25)
class RememberShapeAndColor5x3VLAEnv(RememberShapeAndColorVLABaseEnv):
    """5 shapes x 3 colours (15 objects)."""

    SHAPES = 15


@register_task(FAMILY, "RememberShapeAndColor3x2-Long-VLA-v0", number=57, split="medium",
               data_source="MP", memory_type="Object", max_episode_steps=600)
class RememberShapeAndColor3x2LongVLAEnv(RememberShapeAndColor3x2VLAEnv):
    """3x2 with a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)


@register_task(FAMILY, "RememberShapeAndColor3x3-Long-VLA-v0", number=58, split="medium",
               data_source="MP", memory_type="Object", max_episode_steps=600)
class RememberShapeAndColor3x3LongVLAEnv(RememberShapeAndColor3x3VLAEnv):
    """3x3 with a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)


@register_task(FAMILY, "RememberShapeAndColor5x3-Long-VLA-v0", number=59, split="medium",
               data_source="MP", memory_type="Object", max_episode_steps=600)
class RememberShapeAndColor5x3LongVLAEnv(RememberShapeAndColor5x3VLAEnv):
    """5x3 with a 10-100 step cue and a 50-450 step delay."""

    CUE_PHASE_STEPS = (10, 100)
    EMPTY_PHASE_STEPS = (50, 450)
