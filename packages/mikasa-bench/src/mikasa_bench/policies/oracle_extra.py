"""mikasa-oracles, the ``oracles`` extra of mikasa-bench.

The ``oracle`` and ``oracle-memoryless`` policies, the gallery (an oracle episode per task)
and the oracle column of ``mikasa-bench list`` need the scripted oracles; every other part
of the bench runs without them, so ``pip install mikasa-bench`` leaves them out.
"""

from __future__ import annotations

from types import ModuleType

from mikasa_bench.errors import BenchError

__all__ = ["ORACLES_INSTALL_COMMAND", "require_oracles"]

ORACLES_INSTALL_COMMAND = "pip install 'mikasa-bench[oracles]'"
"""The command that installs mikasa-oracles beside the bench."""


def require_oracles(purpose: str = "the oracle policies") -> ModuleType:
    """The ``mikasa_oracles`` package; `BenchError` naming `ORACLES_INSTALL_COMMAND` when it
    is not installed (``purpose`` says what needed it)."""
    try:
        # Imported on demand: the extra may be absent.
        import mikasa_oracles
    except ModuleNotFoundError as exc:
        if exc.name != "mikasa_oracles":
            raise  # mikasa-oracles is there but one of its own dependencies is not
        raise BenchError(
            f"{purpose} need mikasa-oracles, which is not installed: {ORACLES_INSTALL_COMMAND}"
        ) from None
    return mikasa_oracles
