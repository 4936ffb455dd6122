"""Oracles, one module per task family (or group of families sharing a solver).

Each module defines ``ORACLES: dict[str, type]`` (task family -> oracle class) and
``MEMORYLESS_ORACLES`` (task family -> its memoryless variant, a small subclass with the
`mikasa_oracles.scripted.Memoryless` mixin); this package imports every module and merges
them into ``ALL_ORACLES`` and ``ALL_MEMORYLESS_ORACLES``.
"""

from __future__ import annotations

import importlib
import pkgutil

ALL_ORACLES: dict[str, type] = {}
ALL_MEMORYLESS_ORACLES: dict[str, type] = {}
for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    _loaded = importlib.import_module(f"{__name__}.{_module}")
    for _table, _merged in ((_loaded.ORACLES, ALL_ORACLES), (getattr(_loaded, "MEMORYLESS_ORACLES", {}), ALL_MEMORYLESS_ORACLES)):
        for _family, _oracle in _table.items():
            if _family in _merged:
                raise RuntimeError(f"two oracles for family {_family!r}")
            _merged[_family] = _oracle
