"""``import torchvision`` next to a CPU torch: PyPI's CUDA torchvision wheel made importable.

PyPI's torchvision wheels are CUDA builds: their compiled ops library ``torchvision/_C.so``
links against ``libtorch_cuda``, so beside the CPU build of torch it fails to load.
torchvision tolerates that (``torchvision.extension._has_ops()`` is then False), but its
``_meta_registrations`` module then registers fake kernels for ``torchvision::nms`` and
``torchvision::qnms`` unconditionally, ops that only ``_C`` defines, and ``import
torchvision`` dies with ``RuntimeError: operator torchvision::nms does not exist``.
Declaring those two schemas through torch's public ``torch.library`` right after
``torchvision.extension`` has run (and only when its ``_C`` failed to load) lets the
pure-Python parts import: models and transforms, all that lerobot's dataset, policy and
evaluation code use. The detection ops stay unusable (no kernels); nothing here calls them.
A torchvision whose ``_C`` loads is left untouched, and a missing one is left to the
importer to report.

Two ways in, one mechanism (`install`: a ``sys.meta_path`` finder that wraps the loader of
``torchvision.extension`` and nothing else):

* ``scripts/setup_datasets_envs.sh`` copies this file into ``.venv-datasets``'s
  site-packages as ``_mikasa_torchvision_cpu.py`` beside ``_mikasa_torchvision_cpu.pth``,
  whose one line calls `install` at interpreter start. Every Python process of that
  environment (``lerobot-train``, ``lerobot-eval``, ``python -c "import torchvision"``)
  then imports torchvision without any wrapper. At start-up this costs one small module
  import and one list insertion: nothing is imported (no torch, no torchvision) until the
  process itself imports torchvision.
* `ensure_importable` (``mikasa_datasets.lerobot.ensure_torchvision_importable``) does the
  same inside a process of any other environment, also after a failed ``import
  torchvision``.

Standalone on purpose: only the standard library's ``sys`` at import time, no package
import, so the same file works as the start-up hook outside the ``mikasa_datasets``
package.
"""

import sys  # the only import at start-up (not even __future__: it would cost an import)

__all__ = ["define_op_schemas", "ensure_importable", "install"]

TARGET = "torchvision.extension"
"""The module after which the schemas are declared: it tries to load ``_C``."""
OP_SCHEMAS = (
    "nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
    "qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor",
)
"""The ops torchvision's import registers fake kernels for without checking ``_C``."""
_MARK = "_mikasa_torchvision_cpu"
"""Attribute that marks this finder, also when a second copy of this file is loaded."""

_ops_libraries: list = []  # keeps the schema-only op libraries (and so their definitions) alive


def define_op_schemas() -> None:
    """Declare ``torchvision::nms`` / ``qnms`` (schemas only) where nothing defines them."""
    import torch  # already imported: torchvision.extension imports it first

    missing = [s for s in OP_SCHEMAS if not hasattr(torch.ops.torchvision, s.split("(")[0])]
    if not missing:
        return  # the real _C, or this file's other copy (hook / package), defined them
    library = torch.library.Library("torchvision", "DEF")
    for schema in missing:
        library.define(schema)
    _ops_libraries.append(library)


class _ExtensionLoader:
    """Runs ``torchvision.extension`` with its own loader, then declares the schemas if its
    ``_C`` did not load. Put back as the module's loader once it has run."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        try:
            self._loader.exec_module(module)
        finally:
            module.__loader__ = self._loader
            if getattr(module, "__spec__", None) is not None:
                module.__spec__.loader = self._loader
        has_ops = getattr(module, "_has_ops", None)
        if has_ops is not None and not has_ops():
            define_op_schemas()

    def __getattr__(self, name):  # get_code, get_filename, is_package, ...
        return getattr(self._loader, name)


class _Finder:
    """Meta path finder for ``torchvision.extension`` only; the real lookup is left to the
    other finders of ``sys.meta_path``."""

    _mikasa_torchvision_cpu = True

    def find_spec(self, fullname, path=None, target=None):
        if fullname != TARGET:
            return None
        for finder in sys.meta_path:
            if getattr(finder, _MARK, False) is True or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(fullname, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _ExtensionLoader(spec.loader)
                return spec
        return None

    def invalidate_caches(self):
        pass


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once per process, whichever copy of this
    file asks). Imports nothing."""
    if not any(getattr(f, _MARK, False) is True for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def ensure_importable() -> None:
    """`install`, then ``import torchvision``; a torchvision import that already failed in
    this process is retried (its leftover submodules are dropped first). A missing
    torchvision is not an error here."""
    install()
    if "torchvision" not in sys.modules:  # never imported, or an import that failed
        for name in [m for m in sys.modules if m.startswith("torchvision.")]:
            del sys.modules[name]
    try:
        import torchvision  # noqa: F401
    except ImportError:
        return
