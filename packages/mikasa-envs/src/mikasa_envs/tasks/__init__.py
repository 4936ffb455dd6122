"""Task families, one module each; importing this package registers every env.

Every module here whose name does not start with ``_`` is a task family and is imported
(in name order), which registers its env ids. Then the modules that other installed
packages name in the ``mikasa_envs.tasks`` entry-point group are imported, so a family
written outside this package registers the same way::

    [project.entry-points."mikasa_envs.tasks"]
    my_family = "my_package.my_family"
"""

import importlib
import pkgutil
from importlib.metadata import entry_points

TASK_PLUGIN_GROUP = "mikasa_envs.tasks"
"""The entry-point group whose modules register further task families."""

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    importlib.import_module(f"{__name__}.{_module}")

for _plugin in entry_points(group=TASK_PLUGIN_GROUP):
    try:
        _plugin.load()
    except Exception as _exc:
        raise ImportError(
            f"the task entry point {_plugin.name} = {_plugin.value} (group {TASK_PLUGIN_GROUP}) "
            f"failed to load: {type(_exc).__name__}: {_exc}"
        ) from _exc
