"""Error types of mikasa-bench.

Every error a user can cause (bad id, split, policy, results directory, policy output)
is a `BenchError`: the CLI prints its message without a traceback and exits with code 2.
"""

from __future__ import annotations

__all__ = [
    "BenchError",
    "PolicyOutputError",
    "UnknownTaskError",
    "EpisodeFailedError",
    "EpisodeInterrupted",
]


class BenchError(ValueError):
    """A user-facing error whose message says what was expected."""


class UnknownTaskError(BenchError):
    """An env id that is not in the manifest, not registered, or not supported."""


class PolicyOutputError(BenchError):
    """A policy returned something that is not an action or an action chunk."""


class EpisodeFailedError(BenchError):
    """An episode raised in a worker; the message names the task, episode and seed."""


class EpisodeInterrupted(BenchError):
    """The policy lost its memory of the episode in progress (e.g. the connection to its
    server dropped mid-episode): the episode must be played again from its reset, never
    continued. Workers restart it up to the policy's ``max_episode_restarts`` times."""
