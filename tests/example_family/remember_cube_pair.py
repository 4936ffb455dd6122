"""RememberCubePair: the smallest task family, written as the "Adding a task" guide walks it.

A family outside mikasa-envs registers through the ``mikasa_envs.tasks`` entry-point group;
one inside it is a module ``mikasa_envs/tasks/remember_cube_pair.py``. Either way this file
is all the env side needs: the family's declaration and its registered variants.
"""

from __future__ import annotations

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks import remember_color

FAMILY = TaskFamily(
    "remember_cube_pair",
    hidden="the shown cube's colour: in view during the cue, nothing during the delay",
    overlays="color_memory",  # the overlay chain that draws the target colour on videos
    frozen_cue_on_short_ids=True,  # the robot stays still during the cue and the delay
    chance=remember_color.FAMILY.chance,  # a blind guess among the N cubes: 1/2
)


class RememberCubePairVLABaseEnv(remember_color.RememberColorVLABaseEnv):
    """**Task Description:** one of two coloured cubes is shown at the centre of the table;
    then nothing is visible for a delay; then both cubes appear. Bring the TCP to the cube of
    the remembered colour and hold still.

    **Randomizations:** which cube is shown; slot jitter; cue and delay lengths; arm joint
    noise.

    **Success Conditions:** in the action phase, the TCP is within 5 cm of the shown cube's
    centre and every arm joint moves slower than 0.2 rad/s.
    """

    LANGUAGE_INSTRUCTION = "Observe the cube's color, wait, then touch the cube of the same color."
    COLORS = 2


@register_task(FAMILY, "RememberCubePair-VLA-v0", split="short", data_source="MP",
               memory_type="Object", max_episode_steps=30)
class RememberCubePairVLAEnv(RememberCubePairVLABaseEnv):
    """RememberCubePair with a 1-5 step cue and a 1-5 step delay."""


@register_task(FAMILY, "RememberCubePair-Long-VLA-v0", split="medium", data_source="MP",
               memory_type="Object", max_episode_steps=200)
class RememberCubePairLongVLAEnv(RememberCubePairVLABaseEnv):
    """RememberCubePair with a 10-50 step cue and a 50-100 step delay."""

    CUE_PHASE_STEPS = (10, 50)
    EMPTY_PHASE_STEPS = (50, 100)
