"""The oracle registry: which oracle class solves each task family.

A task's family is its manifest row's ``family`` (``mikasa_envs.manifest.get_task(env_id)
.family``); every consumer (``mikasa_oracles.make_oracle``, ``mikasa-collect``, the bench's
``--policy oracle``) looks the oracle up here by that name. A family has at most one oracle
and at most one memoryless variant (`mikasa_oracles.scripted.Memoryless`); registering a
second one for the same family is an error.

The built-in oracles register themselves with :func:`register_oracle` when
``mikasa_oracles.families`` imports its modules (on ``import mikasa_oracles``). An oracle
defined anywhere else registers the same way, in the module that defines it; for processes
that import only ``mikasa_oracles`` (the worker processes of ``mikasa-collect`` and of the
bench), name that module in an entry point of the group :data:`ENTRY_POINT_GROUP`:
``import mikasa_oracles`` ends with :func:`load_entry_point_oracles`.

This module is a leaf: it imports nothing of the package.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points
from typing import TypeVar

__all__ = [
    "ENTRY_POINT_GROUP",
    "MEMORYLESS_ORACLES",
    "ORACLES",
    "DuplicateOracleError",
    "UnknownFamilyError",
    "load_entry_point_oracles",
    "oracle_class",
    "register_oracle",
]

ENTRY_POINT_GROUP = "mikasa_oracles.families"
"""Entry-point group of the modules that register oracles from other distributions."""

ORACLES: dict[str, type] = {}
"""Task family -> oracle class (filled by :func:`register_oracle`)."""
MEMORYLESS_ORACLES: dict[str, type] = {}
"""Task family -> the oracle's memoryless variant (filled by ``register_oracle(...,
memoryless=True)``)."""

OracleClass = TypeVar("OracleClass", bound=type)


class DuplicateOracleError(ValueError):
    """A family that already has an oracle (of that kind) was given a second one."""


class UnknownFamilyError(ValueError):
    """No oracle (of that kind) is registered for the family asked for."""


def _table(memoryless: bool) -> dict[str, type]:
    return MEMORYLESS_ORACLES if memoryless else ORACLES


def _kind(memoryless: bool) -> str:
    return "memoryless oracle" if memoryless else "oracle"


def _qualified_name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def register_oracle(
    *families: str, memoryless: bool = False
) -> Callable[[OracleClass], OracleClass]:
    """Class decorator: ``cls`` is the oracle of each of ``families`` (task family names).

    ``memoryless=True`` registers the family's memoryless variant instead. The class is
    built as ``cls(env, **kwargs)`` for one env made with ``gym.make`` (see
    `mikasa_oracles.scripted.ScriptedOracle`) and follows the bench policy protocol
    (``chunk_size``, ``reset()``, ``forward(obs)``). Usable as a plain call too:
    ``register_oracle("my_family")(MyOracle)``.

    Raises :class:`DuplicateOracleError`, registering none of ``families``, if one of them
    already has another oracle of that kind (registering the same class again is a no-op).
    """
    if not families or not all(isinstance(f, str) and f for f in families):
        raise ValueError(f"register_oracle needs one or more family names, got {families!r}")

    def register(cls: OracleClass) -> OracleClass:
        table = _table(memoryless)
        for family in families:
            existing = table.get(family)
            if existing is not None and existing is not cls:
                raise DuplicateOracleError(
                    f"family {family!r} already has the {_kind(memoryless)} "
                    f"{_qualified_name(existing)}; cannot register {_qualified_name(cls)} "
                    "for it too (one per family)"
                )
        for family in families:
            table[family] = cls
        return cls

    return register


def oracle_class(family: str, memoryless: bool = False, *, env_id: str | None = None) -> type:
    """The oracle class registered for ``family`` (its memoryless variant if ``memoryless``).

    Raises :class:`UnknownFamilyError` naming the families that have one; ``env_id``, if
    given, is named in it as the task asked for.
    """
    table = _table(memoryless)
    if family not in table:
        task = f"{env_id!r} (family {family!r})" if env_id is not None else f"family {family!r}"
        raise UnknownFamilyError(
            f"no {_kind(memoryless)} for {task}; they exist for: {', '.join(sorted(table))}"
        )
    return table[family]


def load_entry_point_oracles() -> None:
    """Import every module named by an entry point of :data:`ENTRY_POINT_GROUP` (installed
    distributions' oracles, which register themselves on import).

    Called at the end of ``import mikasa_oracles``, so such a module may import anything of
    the package. A module that fails to import fails ``import mikasa_oracles``, naming it.
    """
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        try:
            entry.load()
        except Exception as exc:
            raise ImportError(
                f"the oracle entry point {entry.name} = {entry.value} "
                f"(group {ENTRY_POINT_GROUP}) failed to load: {type(exc).__name__}: {exc}"
            ) from exc
