"""Observation and action wrappers of the canonical MIKASA-Robo VLA chain.

All wrappers work on batched torch tensors (B = ``num_envs``) on the env device and never
round-trip through numpy on the step path. They follow gymnasium >= 1.0 semantics: the base
env is reached through ``env.unwrapped`` (no attribute forwarding). Observation spaces are
derived from the wrapped env's own ``observation_space`` (no reset at construction), and
every observation wrapper also sets ``single_observation_space`` (the unbatched space) so
that ManiSkill's vector wrapper sees the true space.

The code lives in `observation_wrappers` (dict / flatten / proprio conversion),
`step_gated_wrappers` (curriculum and initial no-op actions, camera shutdown) and
`_wrapper_helpers`; this module re-exports all of it.
"""

from __future__ import annotations

from ._drawing import frames_to_uint8, restore_batching  # noqa: F401
from ._wrapper_helpers import (  # noqa: F401
    MISSING_VALUE_SENTINEL,
    _as_step_tensor,
    _box_for,
    _contains_sentinel,
    _elapsed_from_info,
    _env_device,
    _flat_dim,
    _is_sentinel_space,
    _num_envs,
    _sentinel_space,
    _set_spaces,
    _torch_to_numpy_dtype,
    _unbatch_space,
)
from .observation_wrappers import (  # noqa: F401
    ConvertJointsToEEFXyzRpyGripperWrapper,
    FlattenRGBDObservationWrapper,
    StateOnlyTensorToDictWrapper,
    _concat_last_dim,
    _quat_wxyz_to_rpy_numpy,
    _quat_wxyz_to_rpy_torch,
)
from .step_gated_wrappers import (  # noqa: F401
    _FINGER_CENTER,
    _FINGER_HALF_RANGE,
    CameraShutdownWrapper,
    CurriculumPhaseNoopActionWrapper,
    CurriculumPhaseNoopActionWrapperPdJointPos,
    InitialZeroActionWrapper,
    _StepGatedActionWrapper,
)

__all__ = [
    "MISSING_VALUE_SENTINEL",
    "StateOnlyTensorToDictWrapper",
    "CurriculumPhaseNoopActionWrapper",
    "CurriculumPhaseNoopActionWrapperPdJointPos",
    "InitialZeroActionWrapper",
    "CameraShutdownWrapper",
    "FlattenRGBDObservationWrapper",
    "ConvertJointsToEEFXyzRpyGripperWrapper",
]
