"""The Intercept tasks' rolling ball as a camera sees it (`mikasa_oracles.families.intercept`).

`BallObserver` remembers the ball's position in every frame that shows it, fits its rolling
motion (one frame shows no motion) and predicts where it is while out of view;
`GuessedMotionObserver` is the memoryless oracle's stand-in, which keeps only the current
frame and answers a guessed motion.
"""

from __future__ import annotations

import numpy as np

# The ball slides for its first ~3 steps before it rolls: fit the velocity to later frames.
FIRST_ROLLING_FRAME = 3
# A rolling ball keeps this share of its speed from one step to the next (measured: 1.4 %
# a second); predictions 40 steps ahead are then within 0.5 mm.
ROLLING_DECAY = 0.99929


class BallObserver:
    """Remembers the ball's position in every frame seen and fits its rolling motion.

    ``now`` is the ball's position in the current frame: seen (``see``) or, while the ball
    is out of view, predicted from the fit (``predict``).
    """

    def __init__(self) -> None:
        self.frames: list[int] = []
        self.positions: list[np.ndarray] = []
        self.fit_from = FIRST_ROLLING_FRAME
        self.now = np.zeros(2)

    def refit_from(self, frame: int) -> None:
        """Fit the motion only to frames from ``frame`` on (the ball was hit before)."""
        self.fit_from = frame

    def see(self, frame: int, position: np.ndarray) -> None:
        """Record the ball centre (xy) seen in ``frame``."""
        self.frames.append(frame)
        self.positions.append(np.asarray(position[:2], dtype=np.float64))
        self.now = self.positions[-1]

    def predict(self, frame: int) -> None:
        """The ball is out of view in ``frame``: move ``now`` on along the fitted path from
        the last frame seen, slowing as a rolling ball does."""
        fit = self._fit()
        if fit is None:
            self.now = self.positions[-1]
            return
        # The fit is the velocity at the middle of the frames it used; the speed at the last
        # one is a little lower, and every later step keeps ROLLING_DECAY of it.
        velocity, fit_frame = fit
        last_velocity = velocity * ROLLING_DECAY ** (self.frames[-1] - fit_frame)
        steps = frame - self.frames[-1]
        self.now = self.positions[-1] + (
            last_velocity * ROLLING_DECAY * (1 - ROLLING_DECAY**steps) / (1 - ROLLING_DECAY)
        )

    def velocity(self) -> np.ndarray | None:
        """xy displacement per step, fitted by least squares (None before two frames)."""
        fit = self._fit()
        return None if fit is None else fit[0]

    def _fit(self) -> tuple[np.ndarray, float] | None:
        """The fitted velocity and the frame it holds for (the middle of the frames used)."""
        frames = np.asarray(self.frames, dtype=np.float64)
        positions = np.asarray(self.positions)
        rolling = frames >= self.fit_from
        if rolling.sum() >= 2:
            frames, positions = frames[rolling], positions[rolling]
        elif len(frames) >= 2:
            # Still sliding: the last displacement, slowed to the rolling speed it settles at.
            return (positions[-1] - positions[-2]) * 0.9, float(frames[-2:].mean())
        else:
            return None
        centred = frames - frames.mean()
        deviations = positions - positions.mean(axis=0)
        velocity = (centred[:, None] * deviations).sum(axis=0) / (centred**2).sum()
        return velocity, float(frames.mean())


class GuessedMotionObserver(BallObserver):
    """A `BallObserver` that keeps no frames but the current one and answers a fixed
    guessed velocity (one frame shows no motion); with the ball out of view, a guessed path
    (start and velocity) says where it is."""

    def __init__(self, guessed_start: np.ndarray, guessed_velocity: np.ndarray) -> None:
        super().__init__()
        self.guessed_start = guessed_start
        self.guessed_velocity = guessed_velocity

    def velocity(self) -> np.ndarray:
        """The guess (xy displacement per step)."""
        return self.guessed_velocity

    def predict(self, frame: int) -> None:
        """Out of view: the guessed start moved on by the guessed velocity."""
        self.now = self.guessed_start + self.guessed_velocity * frame
