"""Task families, one module each; importing this package registers every env.

Every module here whose name does not start with ``_`` is a task family and is imported
(in name order), which registers its env ids.
"""

import importlib
import pkgutil

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    importlib.import_module(f"{__name__}.{_module}")
