"""`PolicySpec`: a picklable description of a policy, and the kinds of policy target.

Policies are *described* by a `PolicySpec` (picklable, JSON-ready) in the main process
and *built* in each worker by `mikasa_bench.policies.loading.build_policy`, because some
(the oracle) read privileged state of the env instance they are built for.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from mikasa_bench.policies.builtin import BUILTIN_POLICIES

__all__ = ["PolicySpec", "is_lerobot_target", "is_remote_target"]


def is_remote_target(target: str) -> bool:
    """Whether ``target`` names a policy server (``ws://HOST:PORT``, see `mikasa_bench.policies.remote.client`)."""
    return target.startswith(("ws://", "wss://"))


def is_lerobot_target(target: str) -> bool:
    """Whether ``target`` names a LeRobot pretrained policy (``lerobot:DIR``, see
    `mikasa_bench.lerobot.policy`; lerobot itself is imported only when one is used)."""
    return target.startswith("lerobot:")


@dataclass(frozen=True)
class PolicySpec:
    """A picklable description of a policy: built-in name or import target, plus kwargs.

    ``target`` is ``zero``/``random``/``oracle``, ``module:Name`` or an absolute
    ``/path/file.py:Name``.
    """

    target: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    label: str = ""

    @property
    def builtin(self) -> bool:
        """Whether this is one of `BUILTIN_POLICIES`."""
        return self.target in BUILTIN_POLICIES

    def key(self) -> str:
        """A stable identity string (worker caches, job grouping)."""
        return json.dumps([self.target, self.kwargs], sort_keys=True, default=str)

    def model_record(self) -> dict[str, Any]:
        """The ``model`` entry of result files: ``{"name": ..., "config": {...}}``."""
        return {
            "name": self.label or self.target,
            "target": self.target,
            "config": dict(self.kwargs),
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (see `from_dict`)."""
        return {"target": self.target, "kwargs": dict(self.kwargs), "label": self.label}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PolicySpec:
        """Inverse of `to_dict`."""
        return cls(d["target"], dict(d.get("kwargs") or {}), d.get("label", ""))
