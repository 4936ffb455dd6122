"""The built-in oracles, one module per task family (or group of families sharing a solver).

Each module registers its oracle classes, and their memoryless variants (small subclasses
with the `mikasa_oracles.scripted.Memoryless` mixin), with
`mikasa_oracles.registry.register_oracle`; importing this package (which ``import
mikasa_oracles`` does) imports every module here.
"""

from __future__ import annotations

import importlib
import pkgutil

from mikasa_oracles.registry import MEMORYLESS_ORACLES, ORACLES

# The registry's tables under their former names here.
ALL_ORACLES: dict[str, type] = ORACLES
ALL_MEMORYLESS_ORACLES: dict[str, type] = MEMORYLESS_ORACLES

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    importlib.import_module(f"{__name__}.{_module}")
