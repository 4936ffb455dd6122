"""The shared frame of the family oracles (``mikasa_oracles.families``), and their
memoryless variants (`Memoryless`)."""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np

# Salts that keep the memoryless oracle's random streams apart from each other (and from
# the env's own episode RNG, which is seeded with the bare episode seed).
_GUESS_SALT = 0x6D656D6C  # "meml"
_DRAW_SALT = 0x64726177  # "draw"


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


class Memoryless:
    """Mixin that turns a family oracle into its memoryless variant (the validity check).

    Put it first in the bases: ``class MemorylessX(Memoryless, XOracle)``. Before every
    step it calls ``forget()``, which wipes whatever the oracle has remembered across steps
    about the hidden answer (cue objects seen, colours, blink counts, the recorded shape,
    …), so the step acts only on what the current frame shows (privileged state minus
    anything a camera cannot see now) and on the task's fixed rules (class constants that
    hold in every episode: an agent can learn them from training data). Motion-only memory
    (the start orientation, which waypoint or stage the arm has reached) stays; each family
    says in its subclass what is wiped.

    Where the answer is not visible when it must act, the oracle guesses among the
    candidates it sees now and commits to the guess within the step. ``guess`` makes the
    guess a deterministic function of (task, episode seed, the view's candidate count, a
    key), so it stays the same while the view does (no dithering between candidates);
    ``draws`` is a per-episode stream for decisions that must be fresh each time the same
    view recurs (e.g. whether to descend now, for a policy without a clock). The task id
    (the instruction names the task) enters every seed: tasks that draw their answers from
    the same episode seed the same way would otherwise share one sequence of lucky or
    unlucky guesses.

    ``reset(seed)`` takes the episode seed (the bench passes it, see
    ``mikasa_bench.policies.reset_policy``; so does `mikasa_oracles.rollout`); without one
    the guesses use seed 0.
    """

    memoryless = True

    def reset(self, seed: int | None = None) -> None:
        """Start an episode; ``seed`` (the episode seed) seeds the guesses."""
        self.episode_seed = 0 if seed is None else int(seed)
        spec = getattr(self.env, "spec", None) or self.env.unwrapped.spec  # type: ignore[attr-defined]
        self.task_key = zlib.crc32(spec.id.encode()) if spec is not None else 0
        self.draws = np.random.default_rng([_DRAW_SALT, self.task_key, self.episode_seed])
        super().reset()  # type: ignore[misc]

    def forward(self, obs: Any) -> np.ndarray:
        """Forget the answer, then act on the current frame."""
        self.forget()
        return super().forward(obs)  # type: ignore[misc]

    def forget(self) -> None:
        """Wipe what the oracle remembers about the hidden answer (per family)."""
        raise NotImplementedError

    def guess_rng(self, *key: int) -> np.random.Generator:
        """A generator that depends only on the task, the episode seed and ``key``
        (non-negative ints describing the view, e.g. the number of candidates)."""
        return np.random.default_rng([_GUESS_SALT, self.task_key, self.episode_seed, *(int(k) for k in key)])

    def guess(self, n: int, *key: int) -> int:
        """A uniform pick in ``range(n)``, the same for the same (task, episode seed, n, key)."""
        if n < 1:
            raise ValueError(f"nothing to guess among (n={n})")
        return int(self.guess_rng(n, *key).integers(n))
