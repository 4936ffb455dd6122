"""Observation and action wrappers of the canonical MIKASA-Robo VLA chain.

All wrappers work on batched torch tensors (B = ``num_envs``) on the env device and never
round-trip through numpy on the step path. They follow gymnasium >= 1.0 semantics: the base
env is reached through ``env.unwrapped`` (no attribute forwarding). Observation spaces are
derived from the wrapped env's own ``observation_space`` (no reset at construction), and
every observation wrapper also sets ``single_observation_space`` (the unbatched space) so
that ManiSkill's vector wrapper sees the true space.

The code lives in `observation_wrappers` (dict / flatten / proprio conversion),
`step_gated_wrappers` (curriculum and initial no-op actions, camera shutdown) and
`_wrapper_helpers`; this module re-exports their public names.
"""

from __future__ import annotations

from ._drawing import frames_to_uint8, restore_batching  # noqa: F401
from ._wrapper_helpers import (  # noqa: F401
    MISSING_VALUE_SENTINEL,
    as_step_tensor,
    box_for,
    contains_sentinel,
    elapsed_from_info,
    env_device,
    flat_dim,
    is_sentinel_space,
    num_envs_of,
    sentinel_space,
    set_observation_spaces,
    torch_to_numpy_dtype,
)
from .observation_wrappers import (
    ConvertJointsToEEFXyzRpyGripperWrapper,
    FlattenRGBDObservationWrapper,
    StateOnlyTensorToDictWrapper,
)
from .step_gated_wrappers import (
    CameraShutdownWrapper,
    CurriculumPhaseNoopActionWrapper,
    CurriculumPhaseNoopActionWrapperPdJointPos,
    InitialZeroActionWrapper,
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
