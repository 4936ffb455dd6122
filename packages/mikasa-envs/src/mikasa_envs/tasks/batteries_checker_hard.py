"""BatteriesCheckerHard: check every battery in the socket, put it back, confirm with the button."""

from __future__ import annotations

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._batteries_checker import (
    BatteriesCheckerVLABaseEnv,
    batteries_checker_chance,
)

FAMILY = TaskFamily(
    "batteries_checker_hard",
    hidden=(
        "which batteries lit the lamp, and which are checked: the lamp shows it while the "
        "battery sits in the socket and 7 steps after"
    ),
    overlays="batteries_checker",
    wrapper_table_rank=(28, 28),
    chance=batteries_checker_chance,
)



class BatteriesCheckerHardVLABaseEnv(BatteriesCheckerVLABaseEnv):
    """**Task Description:** a tray holds N upright batteries; some of them work. For each
    battery: drop it into the socket (the lamp behind it turns yellow for a working one, for
    as long as it sits there and 7 steps after the insertion), take it out and put it back
    in its own slot, then press the button to confirm it. The lamp is the only place the
    result is shown, so the robot must remember which batteries lit it.

    **Randomizations:** the tray centre (x ~ U[−0.09, −0.01), y ~ U[−0.05, 0.05)), which
    moves the socket, lamp and button with it; which batteries work; arm joint noise.

    **Success Conditions:** every active battery has gone through a full insert → return →
    confirm cycle (so all working ones are found) and every checked battery stands within
    6.9 cm (xy) / 7.2 cm (z) of its slot. The episode terminates on success.
    """

    LANGUAGE_INSTRUCTION = (
        "Find all working batteries by inserting each one into the socket, observing the lamp result, "
        "returning it from the socket to its initial slot, and then pressing the button to confirm."
    )
    # Env steps of one check cycle (pick, insert, return, press) of the oracle, measured
    # (Hard-3: 427-430 steps for 3 cycles); the chance rule counts the cycles that fit.
    CHECK_CYCLE_STEPS = 143


@register_task(FAMILY, "BatteriesCheckerHard-3-VLA-v0", number=46, split="long", data_source="MP",
               memory_type="Checklist", max_episode_steps=1080)
class BatteriesCheckerHard3VLAEnv(BatteriesCheckerHardVLABaseEnv):
    """3 batteries, 1 working."""

    ACTIVE_BATTERIES = 3
    WORKING_BATTERIES = 1


@register_task(FAMILY, "BatteriesCheckerHard-6-VLA-v0", number=47, split="long", data_source="MP",
               memory_type="Checklist", max_episode_steps=2160)
class BatteriesCheckerHard6VLAEnv(BatteriesCheckerHardVLABaseEnv):
    """6 batteries, 3 working."""

    ACTIVE_BATTERIES = 6
    WORKING_BATTERIES = 3


@register_task(FAMILY, "BatteriesCheckerHard-9-VLA-v0", number=94, memory_type="Checklist",
               max_episode_steps=3240, )
class BatteriesCheckerHard9VLAEnv(BatteriesCheckerHardVLABaseEnv):
    """9 batteries, 5 working (registered, not canonical)."""

    ACTIVE_BATTERIES = 9
    WORKING_BATTERIES = 5


@register_task(FAMILY, "BatteriesCheckerHard-12-VLA-v0", number=95, memory_type="Checklist",
               max_episode_steps=4320, )
class BatteriesCheckerHard12VLAEnv(BatteriesCheckerHardVLABaseEnv):
    """12 batteries, 7 working (registered, not canonical)."""

    ACTIVE_BATTERIES = 12
    WORKING_BATTERIES = 7


@register_task(FAMILY, "BatteriesCheckerHard-15-VLA-v0", number=96, memory_type="Checklist",
               max_episode_steps=4320, )
class BatteriesCheckerHard15VLAEnv(BatteriesCheckerHardVLABaseEnv):
    """15 batteries, 9 working (registered, not canonical)."""

    ACTIVE_BATTERIES = 15
    WORKING_BATTERIES = 9
