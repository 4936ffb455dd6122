"""ShellGameShuffleTouch: see where the ball is, follow its mug through a shuffle, touch it."""

from __future__ import annotations

import torch
from mani_skill.utils.structs import Actor

from mikasa_envs.family import TaskFamily
from mikasa_envs.registration import register_task
from mikasa_envs.tasks._shell_game import (
    SHUFFLE_TASK_STATE,
    RedBallMixin,
    ScriptedShellGameVLABaseEnv,
    TouchMugMixin,
    shell_game_chance,
)

FAMILY = TaskFamily(
    "shell_game_shuffle_touch",
    hidden=(
        "which mug hides the ball: the ball is in view during the cue; the mug is tracked "
        "while the mugs swap places"
    ),
    overlays="shell_game",
    frozen_cue_on_short_ids=True,
    wrapper_table_rank=(2, 5),
    chance=shell_game_chance,
)



class ShellGameShuffleTouchVLABaseEnv(TouchMugMixin, RedBallMixin, ScriptedShellGameVLABaseEnv):
    """**Task Description:** a red ball lies on the table at one of three places; then three
    upside-down mugs appear over the three places and swap places several times, two at a
    time along half circles. Track the mug that hides the ball and touch it once the
    shuffle is over (TCP within 8 cm of its centre), then hold still.

    **Randomizations:** the ball's slot; the slot row's position (±0.1 m in x and y); the
    cue length, shuffle length and number of swaps, and which slots each swap exchanges;
    arm joint noise.

    **Success Conditions:** in the action phase (after the shuffle), the TCP is within
    0.08 m of the ball mug's centre and every arm joint moves slower than 0.2 rad/s (the
    mugs are scripted, so the 0.05 m mug-displacement check always holds). Success does not
    end the episode.
    """

    LANGUAGE_INSTRUCTION = (
        "Observe which cup hides the ball, track the cups as they shuffle, then touch the correct cup."
    )
    SHUFFLE_STEPS = (20, 35)
    NUM_SWAPS = (2, 4)
    TASK_STATE = SHUFFLE_TASK_STATE

    def _scripted_balls(self) -> list[Actor]:
        return [self.red_ball]

    def _ball_positions_at(self, t: torch.Tensor) -> torch.Tensor:
        # Cue: on the table at slot t; shuffle: parked above it; action: under mug t again.
        rows = torch.arange(self.num_envs, device=self.device)
        ball_mug = self.cup_with_ball_number.long()
        start = self.slot_positions[rows, ball_mug].clone()
        final = self.final_positions[rows, ball_mug].clone()
        start[:, 2] = final[:, 2] = self.BALL_ON_TABLE_Z
        parked = start + torch.tensor([0.0, 0.0, self.HEIGHT_OFFSET], device=self.device)
        ball = torch.where((t < self.cue_steps_per_env)[:, None], start, parked)
        ball = torch.where((t >= self.action_phase_start)[:, None], final, ball)
        return ball[:, None]


@register_task(FAMILY, "ShellGameShuffleTouch-VLA-v0", number=32, split="short", data_source="PPO",
               memory_type="Tracking", max_episode_steps=60)
class ShellGameShuffleTouchVLAEnv(ShellGameShuffleTouchVLABaseEnv):
    """ShellGameShuffleTouch: 1-5 cue steps, a 20-35 step shuffle of 2-4 swaps."""

    CUE_PHASE_STEPS = (1, 5)


@register_task(FAMILY, "ShellGameShuffleTouch-Long-VLA-v0", number=69, split="medium",
               data_source="MP", memory_type="Tracking", max_episode_steps=600)
class ShellGameShuffleTouchLongVLAEnv(ShellGameShuffleTouchVLABaseEnv):
    """ShellGameShuffleTouch: 10-100 cue steps, a 100-400 step shuffle of 5-15 swaps."""

    CUE_PHASE_STEPS = (10, 100)
    SHUFFLE_STEPS = (100, 400)
    NUM_SWAPS = (5, 15)
