"""The shared frame of the family oracles (``mikasa_oracles.families``)."""

from __future__ import annotations

from typing import Any


class ScriptedOracle:
    """Base of a family's scripted oracle, for one env (``num_envs == 1``).

    Follows the bench policy protocol (``chunk_size``, ``reset()``, ``forward(obs)``):
    holds the wrapped env, its unwrapped base env (privileged state and the phase clock)
    and the controller gain (``GAIN`` unless given), then calls ``reset()``, which each
    family extends to forget its episode.
    """

    chunk_size = 1
    GAIN = 1.0

    def __init__(self, env: Any, gain: float | None = None) -> None:
        self.env = env
        self.base = env.unwrapped
        self.gain = self.GAIN if gain is None else gain
        self.reset()

    def reset(self) -> None:
        """Forget the previous episode (families add their own state)."""
