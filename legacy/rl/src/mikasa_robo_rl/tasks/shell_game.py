"""ShellGame{Touch,Push,Pick}-v0: see which mug the ball is put under, then act on that mug."""

from __future__ import annotations

from mikasa_envs.tasks.shell_game_pick import ShellGamePickVLAEnv
from mikasa_envs.tasks.shell_game_push import ShellGamePushVLAEnv
from mikasa_envs.tasks.shell_game_touch import ShellGameTouchVLAEnv

from mikasa_robo_rl.registration import register_rl_task


class ShellGameRLTiming:
    """The RL release's shell-game clock: the ball is visible while ``elapsed_steps < 5``
    (the mugs are away), then the mugs stand over the slots; success and reward count from
    step 5 on (the VLA family draws the cue length from [1, 5])."""

    CUE_PHASE_STEPS = (5, 5)
    EMPTY_PHASE_STEPS = (0, 0)


@register_rl_task("ShellGameTouch-v0")
class ShellGameTouchEnv(ShellGameRLTiming, ShellGameTouchVLAEnv):
    """ShellGameTouch (RL): touch the mug that hides the ball. Horizon 90, divisor 3."""


@register_rl_task("ShellGamePush-v0")
class ShellGamePushEnv(ShellGameRLTiming, ShellGamePushVLAEnv):
    """ShellGamePush (RL): push the mug that hides the ball forward. Horizon 90, divisor 4."""


@register_rl_task("ShellGamePick-v0")
class ShellGamePickEnv(ShellGameRLTiming, ShellGamePickVLAEnv):
    """ShellGamePick (RL): lift the mug that hides the ball by its handle. Horizon 90, divisor 75."""


__all__ = ["ShellGameTouchEnv", "ShellGamePushEnv", "ShellGamePickEnv"]
