"""MIKASA-Robo wrappers: the canonical VLA wrapper chain, its wrappers and render overlays.

Typical use::

    import gymnasium as gym
    import mikasa_envs  # registers the tasks
    from mikasa_wrappers import apply_mikasa_vla_wrappers

    env = gym.make("RememberColor3-VLA-v0", obs_mode="rgb", control_mode="pd_ee_delta_pose")
    env = apply_mikasa_vla_wrappers(env)
    obs, info = env.reset(seed=0)  # obs["proprio"]: (B, 7), obs["rgb"]: (B, 128, 128, 6)
"""

from .apply_wrappers import (
    MIKASA_VLA_ENV_IDS,
    REQUIRED_OBS_MODE,
    VLA_WRAPPER_CONFIGS,
    VLAWrapperConfig,
    apply_mikasa_vla_wrappers,
)
from .overlays import (
    BATTERIES_CHECKER,
    BLINK_COUNT,
    COLOR_MEMORY,
    DISABLE_REWARD_OVERLAY_ENV_VAR,
    INTERCEPT,
    MEMORY_CAPACITY,
    OVERLAY_CHAINS,
    ROTATE,
    SHAPE_COLOR_MEMORY,
    SHAPE_MEMORY,
    SHELL_GAME,
    STEP_REWARD,
    TIMED_TRANSFER,
    TRACE_SHAPE,
    DebugRewardWrapper,
    MemoryCapacityInfoWrapper,
    RememberColorInfoWrapper,
    RememberShapeAndColorInfoWrapper,
    RememberShapeInfoWrapper,
    RenderPressProgressInfoWrapper,
    RenderRewardInfoWrapper,
    RenderStepInfoWrapper,
    RenderTimedTransferInfoWrapper,
    RenderTraceShapeDebugWrapper,
    RenderWorkingBatteriesInfoWrapper,
    RotateRenderAngleInfoWrapper,
    ShellGameRenderCupInfoWrapper,
    reward_overlay_disabled,
)
from .wrappers import (
    MISSING_VALUE_SENTINEL,
    CameraShutdownWrapper,
    ConvertJointsToEEFXyzRpyGripperWrapper,
    CurriculumPhaseNoopActionWrapper,
    CurriculumPhaseNoopActionWrapperPdJointPos,
    FlattenRGBDObservationWrapper,
    InitialZeroActionWrapper,
    StateOnlyTensorToDictWrapper,
)

__version__ = "0.1.0"

__all__ = [
    # chain
    "apply_mikasa_vla_wrappers",
    "VLAWrapperConfig",
    "VLA_WRAPPER_CONFIGS",
    "MIKASA_VLA_ENV_IDS",
    "REQUIRED_OBS_MODE",
    # wrappers
    "MISSING_VALUE_SENTINEL",
    "StateOnlyTensorToDictWrapper",
    "CurriculumPhaseNoopActionWrapper",
    "CurriculumPhaseNoopActionWrapperPdJointPos",
    "InitialZeroActionWrapper",
    "CameraShutdownWrapper",
    "FlattenRGBDObservationWrapper",
    "ConvertJointsToEEFXyzRpyGripperWrapper",
    # overlays
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
    "OVERLAY_CHAINS",
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
    "__version__",
]
