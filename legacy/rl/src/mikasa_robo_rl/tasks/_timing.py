"""The RL release's fixed phase timing, shared by the Remember* and *OfColors groups."""

from __future__ import annotations


class FixedCueAndDelay:
    """Cue shown for 5 steps, then an empty table for 5 steps (``TIME_OFFSET = 5``,
    ``delta_time = 5`` upstream), where the VLA release draws each from [1, 5]."""

    CUE_PHASE_STEPS = (5, 5)
    EMPTY_PHASE_STEPS = (5, 5)


class FixedColorSequenceTiming(FixedCueAndDelay):
    """Bunch/Seq/ChainOfColors: each cue lasts 5 steps (``STEP_DURATION``; Seq/Chain show
    the cubes one after another, so their cue lasts 5·L), then 5 empty steps
    (``EMPTY_DURATION``). (The release normalises the dense reward by 100 instead of 400,
    while a success step still earns 400: the manifest's divisor, set at registration.)"""

    CUE_STEP_DURATION = (5, 5)
