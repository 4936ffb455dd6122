"""Render-only overlay wrappers (debug text and markers drawn on ``env.render()`` frames).

Every overlay passes ``reset``/``step`` through unchanged, remembering the latest ``info``,
reward and ``elapsed_steps``, and draws on the frames returned by ``render()`` (one per
env), which it first converts to contiguous uint8 numpy arrays. Values are read from
``info`` first and from ``env.unwrapped`` attributes second; a value that is missing (for
example on a family that does not define it) is simply not drawn.

The wrappers live in `generic_overlays` (base class, value helpers, step / reward
overlays) and `task_overlays` (per-family overlays); this module re-exports them and
defines the named overlay chains.
"""

from __future__ import annotations

import gymnasium as gym
from mikasa_envs.building_blocks.shapes import SHAPE_NAMES  # noqa: F401

from ._drawing import (  # noqa: F401
    BLACK,
    WHITE,
    draw_swatch,
    draw_text,
    frames_to_uint8,
    restore_batching,
    text_size,
    to_rgb255,
)
from .generic_overlays import (  # noqa: F401
    DISABLE_REWARD_OVERLAY_ENV_VAR,
    DebugRewardWrapper,
    RenderOverlayWrapper,
    RenderRewardInfoWrapper,
    RenderStepInfoWrapper,
    lookup,
    per_env,
    reward_overlay_disabled,
    scalar,
    to_numpy,
)
from .task_overlays import (  # noqa: F401
    CUP_NAMES,
    MemoryCapacityInfoWrapper,
    RememberColorInfoWrapper,
    RememberShapeAndColorInfoWrapper,
    RememberShapeInfoWrapper,
    RenderPressProgressInfoWrapper,
    RenderTimedTransferInfoWrapper,
    RenderTraceShapeDebugWrapper,
    RenderWorkingBatteriesInfoWrapper,
    RotateRenderAngleInfoWrapper,
    ShellGameRenderCupInfoWrapper,
)

__all__ = [
    "RenderStepInfoWrapper",
    "RenderRewardInfoWrapper",
    "RememberColorInfoWrapper",
    "RememberShapeInfoWrapper",
    "RememberShapeAndColorInfoWrapper",
    "ShellGameRenderCupInfoWrapper",
    "RotateRenderAngleInfoWrapper",
    "MemoryCapacityInfoWrapper",
    "RenderWorkingBatteriesInfoWrapper",
    "RenderPressProgressInfoWrapper",
    "RenderTraceShapeDebugWrapper",
    "RenderTimedTransferInfoWrapper",
    "DebugRewardWrapper",
    "DISABLE_REWARD_OVERLAY_ENV_VAR",
    "reward_overlay_disabled",
    "COLOR_MEMORY",
    "SHAPE_MEMORY",
    "SHAPE_COLOR_MEMORY",
    "SHELL_GAME",
    "INTERCEPT",
    "ROTATE",
    "MEMORY_CAPACITY",
    "BATTERIES_CHECKER",
    "BLINK_COUNT",
    "TRACE_SHAPE",
    "TIMED_TRANSFER",
    "STEP_REWARD",
    "OVERLAY_CHAINS",
]


# ----------------------------------------------------------------------------------------
# named chains (inner -> outer)
# ----------------------------------------------------------------------------------------

COLOR_MEMORY = (RememberColorInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
SHAPE_MEMORY = (RememberShapeInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
SHAPE_COLOR_MEMORY = (
    RememberShapeAndColorInfoWrapper,
    RenderStepInfoWrapper,
    RenderRewardInfoWrapper,
)
SHELL_GAME = (RenderStepInfoWrapper, ShellGameRenderCupInfoWrapper, RenderRewardInfoWrapper)
INTERCEPT = (RenderStepInfoWrapper, RenderRewardInfoWrapper)
ROTATE = (RenderStepInfoWrapper, RenderRewardInfoWrapper, RotateRenderAngleInfoWrapper)
MEMORY_CAPACITY = (MemoryCapacityInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
BATTERIES_CHECKER = (
    RenderWorkingBatteriesInfoWrapper,
    RenderStepInfoWrapper,
    RenderRewardInfoWrapper,
)
BLINK_COUNT = (RenderPressProgressInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
TRACE_SHAPE = (RenderTraceShapeDebugWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
TIMED_TRANSFER = (
    RenderTimedTransferInfoWrapper,
    RenderStepInfoWrapper,
    RenderRewardInfoWrapper,
)
STEP_REWARD = (RenderStepInfoWrapper, RenderRewardInfoWrapper)

OVERLAY_CHAINS: dict[str, tuple[type[gym.Wrapper], ...]] = {
    "color_memory": COLOR_MEMORY,
    "shape_memory": SHAPE_MEMORY,
    "shape_color_memory": SHAPE_COLOR_MEMORY,
    "shell_game": SHELL_GAME,
    "intercept": INTERCEPT,
    "rotate": ROTATE,
    "memory_capacity": MEMORY_CAPACITY,
    "batteries_checker": BATTERIES_CHECKER,
    "blink_count": BLINK_COUNT,
    "trace_shape": TRACE_SHAPE,
    "timed_transfer": TIMED_TRANSFER,
    "step_reward": STEP_REWARD,
    "none": (),
}
"""The named overlay chains by lowercase name (``"shell_game"`` is `SHELL_GAME`); ``"none"`` is
the empty chain of a task without overlays."""
