"""What the subcommand modules of ``mikasa-bench`` share: messages on stderr and the
``--policy-kwargs`` option's parser."""

from __future__ import annotations

import json
import sys
from typing import Any

from mikasa_bench.errors import BenchError

__all__ = ["eprint", "parse_policy_kwargs"]


def eprint(*args: Any) -> None:
    """``print`` to stderr (progress, hints and errors; stdout carries the tables)."""
    print(*args, file=sys.stderr)


def parse_policy_kwargs(text: str | None) -> dict[str, Any]:
    """The ``--policy-kwargs`` JSON object (``{}`` when not given); `BenchError` with an
    example unless it is a JSON object."""
    if not text:
        return {}
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BenchError(
            f"--policy-kwargs must be a JSON object, e.g. '{{\"seed\": 1}}' ({exc})"
        ) from None
    if not isinstance(value, dict):
        raise BenchError("--policy-kwargs must be a JSON object, e.g. '{\"seed\": 1}'")
    return value
