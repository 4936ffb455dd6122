"""Task families: everything the other packages need to know about a family, declared once.

A family's env module declares a `TaskFamily` (how its observations are overlaid, whether
its short ids freeze the robot during the cue, its chance rule) and registers each env id
with `mikasa_envs.registration.register_task`, which records the id's manifest row here.
The manifest (`mikasa_envs.manifest`), the wrapper chain, the bench's chance rates and the
oracles all read this registry; no other table of families or ids exists.

Plain data: this module imports nothing of the simulator.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "DATA_SOURCES",
    "MEMORY_TYPES",
    "SPLITS",
    "Chance",
    "ChanceRule",
    "RLVariant",
    "TaskFamily",
    "TaskSpec",
    "add_task",
    "declared_families",
    "declared_rl_variants",
    "declared_tasks",
    "env_class",
    "find_task",
    "get_family",
    "task_chance",
]


SPLITS: tuple[str, ...] = ("short", "medium", "long")
MEMORY_TYPES: tuple[str, ...] = (
    "Object",
    "Spatial",
    "Capacity",
    "Temporal",
    "Negative",
    "Sequential",
    "Procedural",
    "Prospective",
    "Tracking",
    "Checklist",
)
DATA_SOURCES: tuple[str, ...] = ("PPO", "MP")


@dataclass(frozen=True)
class TaskSpec:
    """One manifest row.

    ``split`` and ``data_source`` are ``None`` for non-canonical variants.
    """

    env_id: str
    family: str
    split: str | None
    memory_type: str
    max_episode_steps: int
    data_source: str | None
    language_instruction: str
    canonical: bool


@dataclass(frozen=True)
class Chance:
    """A task's chance success rate (what a policy without memory gets) and why, in one line."""

    rate: float
    reason: str


ChanceRule = Callable[[type, TaskSpec], Chance]
"""``rule(env_class, task) -> Chance``: reads the variant's parameters from its env class."""


@dataclass(frozen=True)
class RLVariant:
    """A task of the original RL release (the ``mikasa-robo-rl`` package), built on one of
    the family's registered ids with other parameters.

    ``number``: its place in the RL release's manifest (1-32). ``group`` and ``memory_type``:
    the RL paper's task group and memory type (its 4-type taxonomy). ``reward_divisor``: the
    divisor of its normalised dense reward. ``oracle_info`` / ``task_cue``: the privileged
    names of the paper's Table 1. ``overrides``: the class constants it changes (phase timing,
    the ball kept in view, ...).
    """

    number: int
    env_id: str
    vla_env_id: str
    group: str
    memory_type: str
    max_episode_steps: int
    reward_divisor: float
    oracle_info: str
    task_cue: str | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TaskFamily:
    """What the other packages need to know about one task family.

    ``name``: the family's name (its env module's name). ``hidden``: what a policy must
    remember, and when it is out of view (one line, for docs). ``overlays``: the key of the
    render overlay chain `mikasa_wrappers.overlays.OVERLAY_CHAINS` draws on its videos.
    ``frozen_cue_on_short_ids``: the canonical chain freezes the robot during the cue and
    delay phases of its ids without ``-Long-`` (their training data was collected that way).
    ``wrapper_table_rank``: (short ids, ``-Long-`` ids) positions of the family in the
    reference's wrapper table, which orders ``MIKASA_VLA_ENV_IDS``; ``None`` for a family
    outside it (its ids come last, in manifest order). ``chance``: its chance rule.
    ``rl_variants``: its tasks in the original RL release.
    """

    name: str
    hidden: str = ""
    overlays: str = "none"
    frozen_cue_on_short_ids: bool = False
    wrapper_table_rank: tuple[int, int] | None = None
    chance: ChanceRule | None = None
    rl_variants: tuple[RLVariant, ...] = ()


@dataclass(frozen=True)
class _Entry:
    spec: TaskSpec
    number: int | None
    env_class: type


_FAMILIES: dict[str, TaskFamily] = {}
_TASKS: dict[str, _Entry] = {}


def add_task(family: TaskFamily, spec: TaskSpec, env_class: type, number: int | None) -> None:
    """Record ``spec`` (a row of ``family``) and its env class; ``number`` is the row's place
    in the published manifest (``None``: after the numbered rows, in registration order).

    Raises ``ValueError`` for an id or a number given twice, or a second, different
    declaration of a family name.
    """
    for name, value, accepted in (
        ("split", spec.split, SPLITS),
        ("memory type", spec.memory_type, MEMORY_TYPES),
        ("data source", spec.data_source, DATA_SOURCES),
    ):
        if value is not None and value not in accepted:
            raise ValueError(
                f"{spec.env_id!r}: unknown {name} {value!r}; accepted values: {', '.join(accepted)}"
            )
    known = _FAMILIES.get(family.name, family)
    if known is not family:
        raise ValueError(f"task family {family.name!r} is declared twice: {known} and {family}")
    if spec.family != family.name:
        raise ValueError(f"{spec.env_id!r} names family {spec.family!r}, not {family.name!r}")
    if spec.env_id in _TASKS:
        raise ValueError(f"env id {spec.env_id!r} is registered twice")
    if number is not None and any(e.number == number for e in _TASKS.values()):
        raise ValueError(f"manifest number {number} of {spec.env_id!r} is taken")
    _FAMILIES[family.name] = family
    _TASKS[spec.env_id] = _Entry(spec, number, env_class)


def declared_tasks() -> list[TaskSpec]:
    """Every registered row: numbered rows by number, then the others as registered."""
    entries = list(_TASKS.values())
    numbered = sorted((e for e in entries if e.number is not None), key=lambda e: e.number)
    return [e.spec for e in numbered] + [e.spec for e in entries if e.number is None]


def declared_families() -> dict[str, TaskFamily]:
    """Family name -> declaration, in registration order."""
    return dict(_FAMILIES)


def declared_rl_variants() -> list[tuple[TaskFamily, RLVariant]]:
    """Every declared RL variant with its family, by ``number``."""
    pairs = [(f, v) for f in _FAMILIES.values() for v in f.rl_variants]
    return sorted(pairs, key=lambda pair: pair[1].number)


def get_family(name: str) -> TaskFamily:
    """The declaration of family ``name``; ``KeyError`` naming the known families."""
    try:
        return _FAMILIES[name]
    except KeyError:
        raise KeyError(
            f"unknown task family {name!r}; known families: {', '.join(_FAMILIES)}"
        ) from None


def find_task(env_id: str) -> TaskSpec | None:
    """The registered row of ``env_id``, or ``None``."""
    entry = _TASKS.get(env_id)
    return entry.spec if entry is not None else None


def env_class(env_id: str) -> type:
    """The env class registered under ``env_id``."""
    return _TASKS[env_id].env_class


def task_chance(env_id: str) -> Chance:
    """The chance success rate of ``env_id`` by its family's rule."""
    entry = _TASKS[env_id]
    rule = get_family(entry.spec.family).chance
    if rule is None:
        raise ValueError(f"family {entry.spec.family!r} of {env_id!r} declares no chance rule")
    return rule(entry.env_class, entry.spec)
