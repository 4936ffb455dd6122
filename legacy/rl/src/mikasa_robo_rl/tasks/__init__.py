"""The 32 RL tasks, one module per group; importing this package registers every id.

Each RL task is a small subclass of its MIKASA-Robo-VLA counterpart (``mikasa_envs.tasks``)
with the RL release's fixed phase timing and reward divisor: the scene, randomisation,
success and reward code is the VLA family's.
"""

import importlib
import pkgutil

for _module in sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_")):
    importlib.import_module(f"{__name__}.{_module}")
