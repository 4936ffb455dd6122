"""Slot jitter shared by the families that lay objects out on fixed slots."""

from __future__ import annotations

import torch


def jitter_sequential(
    slots: torch.Tensor, sigma: float = 0.01, min_dist: float = 0.06, tries: int = 50
) -> torch.Tensor:
    """Jitter slots in order; each keeps the first try ≥ ``min_dist`` from earlier ones."""
    out = slots.clone()
    for i in range(len(out)):
        for _ in range(tries):
            candidate = slots[i] + torch.randn(2) * sigma
            if i == 0 or torch.linalg.norm(out[:i] - candidate, dim=1).min() >= min_dist:
                out[i] = candidate
                break
    return out
