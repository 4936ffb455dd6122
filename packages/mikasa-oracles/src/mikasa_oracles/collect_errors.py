"""The errors of ``mikasa-collect``: a leaf module, so that the collector
(:mod:`mikasa_oracles.collect`), its pools and its resume checks all raise the same ones."""

from __future__ import annotations

__all__ = ["CollectError", "CollectionFailed"]


class CollectError(ValueError):
    """Bad input (unknown task, no oracle, bad counts, inconsistent existing data): exit 2."""


class CollectionFailed(RuntimeError):
    """The collection could not finish (attempt budget spent, a worker crashed): exit 1.

    Episodes saved so far stay valid; re-running continues from them.
    """
