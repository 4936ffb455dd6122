"""BatteriesCheckerEasy: check every battery in the socket and confirm it with the button;
the env puts each inserted battery back in its slot by itself."""

from __future__ import annotations

import torch

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._batteries_checker import batteries_checker_chance
from mikasa_envs.tasks.batteries_checker_hard import BatteriesCheckerHardVLABaseEnv

FAMILY = TaskFamily(
    "batteries_checker_easy",
    hidden=(
        "which batteries lit the lamp, and which are checked: the lamp shows it for 7 steps "
        "at each insertion"
    ),
    overlays="batteries_checker",
    wrapper_table_rank=(27, 27),
    chance=batteries_checker_chance,
)



class BatteriesCheckerEasyVLABaseEnv(BatteriesCheckerHardVLABaseEnv):
    """**Task Description:** a tray holds N upright batteries; some of them work. For each
    battery: drop it into the socket, then press the button to confirm it. On insertion the
    battery is returned to its slot at once, and the lamp behind the socket turns yellow
    for 7 steps if it works. The robot must remember which batteries lit the lamp.

    **Randomizations:** the tray centre (x ~ U[−0.09, −0.01), y ~ U[−0.05, 0.05)), which
    moves the socket, lamp and button with it; which batteries work; arm joint noise.

    **Success Conditions:** every active battery has been inserted and then confirmed with
    a button press, and every checked battery stands within 6.9 cm (xy) / 7.2 cm (z) of its
    slot. The episode terminates on success.
    """

    LANGUAGE_INSTRUCTION = (
        "Find all working batteries by inserting each one into the socket, observing the lamp result, "
        "and then pressing the button to confirm."
    )
    # Env steps of one check cycle (pick, insert, press) of the oracle, measured (Easy-3 /
    # Easy-6: 247-248 / 502-504 steps for 3 / 6 cycles; the memoryless oracle's took 79-88).
    CHECK_CYCLE_STEPS = 84

    def _after_stage_update(self, pos: torch.Tensor) -> torch.Tensor:
        # Automatic return (batteries_checker_easy.md §3): on the insert step the battery goes
        # home and the stage moves on to CONFIRM; the lamp was already set for this step.
        auto = (self.action_stage == self.STAGE_RETURN) & (self.active_battery_idx >= 0)
        if not bool(auto.any()):
            return pos
        pos = self._return_active_home(auto, pos)
        self.action_stage = torch.where(auto, self.STAGE_CONFIRM, self.action_stage)
        events = self._events
        events["new_return_event"] = events["new_return_event"] | auto
        events["socket_has_battery"] = events["socket_has_battery"] & ~auto
        events["socket_has_working"] = events["socket_has_working"] & ~auto
        events["socket_battery_idx"] = torch.where(auto, -1, events["socket_battery_idx"])
        return pos


@register_task(FAMILY, "BatteriesCheckerEasy-3-VLA-v0", number=44, split="medium", data_source="MP",
               memory_type="Checklist", max_episode_steps=540)
class BatteriesCheckerEasy3VLAEnv(BatteriesCheckerEasyVLABaseEnv):
    """3 batteries, 1 working."""

    ACTIVE_BATTERIES = 3
    WORKING_BATTERIES = 1


@register_task(FAMILY, "BatteriesCheckerEasy-6-VLA-v0", number=45, split="long", data_source="MP",
               memory_type="Checklist", max_episode_steps=1080)
class BatteriesCheckerEasy6VLAEnv(BatteriesCheckerEasyVLABaseEnv):
    """6 batteries, 3 working."""

    ACTIVE_BATTERIES = 6
    WORKING_BATTERIES = 3


@register_task(FAMILY, "BatteriesCheckerEasy-9-VLA-v0", number=91, memory_type="Checklist",
               max_episode_steps=1620, )
class BatteriesCheckerEasy9VLAEnv(BatteriesCheckerEasyVLABaseEnv):
    """9 batteries, 5 working (registered, not canonical)."""

    ACTIVE_BATTERIES = 9
    WORKING_BATTERIES = 5


@register_task(FAMILY, "BatteriesCheckerEasy-12-VLA-v0", number=92, memory_type="Checklist",
               max_episode_steps=2160, )
class BatteriesCheckerEasy12VLAEnv(BatteriesCheckerEasyVLABaseEnv):
    """12 batteries, 7 working (registered, not canonical)."""

    ACTIVE_BATTERIES = 12
    WORKING_BATTERIES = 7


@register_task(FAMILY, "BatteriesCheckerEasy-15-VLA-v0", number=93, memory_type="Checklist",
               max_episode_steps=2400, )
class BatteriesCheckerEasy15VLAEnv(BatteriesCheckerEasyVLABaseEnv):
    """15 batteries, 9 working (registered, not canonical)."""

    ACTIVE_BATTERIES = 15
    WORKING_BATTERIES = 9
