"""Oracles, one module per task family (or group of families sharing a solver).

Each module defines ``ORACLES: dict[str, type]`` (task family -> oracle class); this
package imports every module and merges them into ``ALL_ORACLES``.
"""

from __future__ import annotations

import importlib
import pkgutil

ALL_ORACLES: dict[str, type] = {}
for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    for _family, _oracle in importlib.import_module(f"{__name__}.{_module}").ORACLES.items():
        if _family in ALL_ORACLES:
            raise RuntimeError(f"two oracles for family {_family!r}")
        ALL_ORACLES[_family] = _oracle
