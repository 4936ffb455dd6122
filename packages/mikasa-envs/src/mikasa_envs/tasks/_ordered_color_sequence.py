"""The ordered cue of SeqOfColors and ChainOfColors (``bunch_of_colors.md``).

BunchOfColors shows its L cubes at once; these two families show them one at a time at one
spot, and book touches into order slots, on the machinery of ``_color_sequence.py``.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import torch

from mikasa_envs.building_blocks.cubes import CUBE_HALF_SIZE
from mikasa_envs.family import Chance, TaskSpec
from mikasa_envs.tasks._color_sequence import ColorSequenceVLABaseEnv


class OrderedColorSequenceVLABaseEnv(ColorSequenceVLABaseEnv):
    """Sequential cue (one target at a time at the origin, d steps each) and order slots.

    ``touched_cubes_idx`` ((B, L), −1 = empty) books the keys of distinct cubes in the order
    of their first touch; when all L slots are full a further new touch overwrites slot 0
    (upstream). Subclasses give the order rule, next target and touch counts.
    """

    # Per-item cue duration d (uniform int, inclusive); the cue lasts C = d·L steps.
    CUE_STEP_DURATION: ClassVar[tuple[int, int]] = (1, 5)
    CUE_SPOT: ClassVar[tuple[float, float, float]] = (0.0, 0.0, CUBE_HALF_SIZE)
    TASK_STATE = ("cue_step_duration_per_env", "touched_cubes_idx")

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        # The range of C = d·L (not uniform over it), for readers of CUE_PHASE_STEPS.
        lo, hi = cls.CUE_STEP_DURATION
        cls.CUE_PHASE_STEPS = (lo * cls.SEQUENCE_LENGTH, hi * cls.SEQUENCE_LENGTH)

    @property
    def num_cue_layouts(self) -> int:
        return self.SEQUENCE_LENGTH

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self.cue_step_duration_per_env = torch.ones(self.num_envs, dtype=torch.int64, device=self.device)
        self.touched_cubes_idx = torch.full(
            (self.num_envs, self.SEQUENCE_LENGTH), -1, dtype=torch.long, device=self.device
        )

    def _sample_phase_lengths(self, env_idx: torch.Tensor) -> None:
        # Torch draws: d for all reset envs, then E; C = d·L.
        b = len(env_idx)
        d_lo, d_hi = self.CUE_STEP_DURATION
        e_lo, e_hi = self.EMPTY_PHASE_STEPS
        d = torch.randint(d_lo, d_hi + 1, (b,), device=self.device)
        self.cue_step_duration_per_env[env_idx] = d
        self.cue_steps_per_env[env_idx] = d * self.SEQUENCE_LENGTH
        self.empty_steps_per_env[env_idx] = torch.randint(e_lo, e_hi + 1, (b,), device=self.device)

    def _on_episode_start(self, env_idx: torch.Tensor) -> None:
        self.touched_cubes_idx[env_idx] = -1
        super()._on_episode_start(env_idx)

    def _cue_layouts(self, env_idx: torch.Tensor) -> torch.Tensor:
        hidden = self._hidden_poses(env_idx)
        layouts = hidden.repeat(self.SEQUENCE_LENGTH, 1, 1, 1)
        rows = torch.arange(len(env_idx), device=self.device)
        spot = torch.tensor(self.CUE_SPOT, device=self.device)
        for item in range(self.SEQUENCE_LENGTH):
            layouts[item, rows, self.target_keys[env_idx, item], :3] = spot
        return layouts

    def _cue_layout_index(self, t: torch.Tensor) -> torch.Tensor:
        return (t // self.cue_step_duration_per_env).clamp(max=self.SEQUENCE_LENGTH - 1)

    @property
    def slot_matches(self) -> torch.Tensor:
        """(B, L) whether slot i holds target i."""
        return self.touched_cubes_idx == self.target_keys

    def _record_touches(self, new_touches: torch.Tensor) -> None:
        if not bool(new_touches.any()):
            return
        for k in range(self.COLORS):  # several in one frame: booked in key order
            new = new_touches[:, k]
            if not bool(new.any()):
                continue
            filled = (self.touched_cubes_idx >= 0).sum(dim=-1)
            slot = torch.where(filled < self.SEQUENCE_LENGTH, filled, 0)
            rows = torch.nonzero(new).flatten()
            self.touched_cubes_idx[rows, slot[rows]] = k


__all__ = ["OrderedColorSequenceVLABaseEnv"]


def color_sequence_chance(env_class: type, task: TaskSpec) -> Chance:
    """Chance rule of Seq/ChainOfColors: a uniform guess of the shown sequence of L cubes."""
    length, colors = env_class.SEQUENCE_LENGTH, env_class.COLORS
    orders = math.perm(colors, length)
    return Chance(
        1 / orders, f"1/P({colors},{length}) = 1/{orders}: the shown sequence of {length} of {colors} cubes"
    )
