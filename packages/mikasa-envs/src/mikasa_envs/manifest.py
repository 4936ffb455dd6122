"""The MIKASA-Robo-VLA task manifest: the 90 canonical tasks plus registered extra variants.

Each family's env module (``mikasa_envs/tasks/<family>.py``) registers its ids with their
manifest rows (`mikasa_envs.registration.register_task`); this module lists them. Canonical
rows (those with a split) are the published benchmark's manifest, in its order; extra
variants are registered environments outside every benchmark split. Task modules of other
installed packages (the ``mikasa_envs.tasks`` entry-point group) are listed too.
"""

from __future__ import annotations

import difflib

from mikasa_envs.family import (  # noqa: F401  (SPLITS, MEMORY_TYPES, DATA_SOURCES: re-exported)
    DATA_SOURCES,
    MEMORY_TYPES,
    SPLITS,
    TaskSpec,
    declared_tasks,
    find_task,
)

SELECTION_FAMILIES: tuple[str, ...] = (
    "remember_color",
    "remember_shape",
    "remember_shape_and_color",
    "find_imposter_color",
    "find_imposter_shape",
    "find_imposter_shape_and_color",
)
"""The six selection families (``tasks/_selection.py``): touch one of N objects."""
SHELL_GAME_FAMILIES: tuple[str, ...] = (
    "shell_game_touch",
    "shell_game_push",
    "shell_game_pick",
    "shell_game_shuffle_touch",
    "shell_game_color_lamp_touch",
    "shell_game_shuffle_color_lamp_touch",
)
"""The six shell-game families (``tasks/_shell_game.py``): act on one of three mugs."""


def _all_tasks() -> list[TaskSpec]:
    import mikasa_envs.tasks  # noqa: F401  (registers the built-in families and plugins)

    return declared_tasks()


def _check_choice(name: str, value: str, accepted: tuple[str, ...]) -> None:
    if value not in accepted:
        raise ValueError(f"unknown {name} {value!r}; accepted values: {', '.join(accepted)}")


def families() -> tuple[str, ...]:
    """All task family names, in manifest order."""
    return tuple(dict.fromkeys(t.family for t in _all_tasks()))


def list_tasks(
    split: str | None = None,
    memory_type: str | None = None,
    family: str | None = None,
    data_source: str | None = None,
    include_extra: bool = False,
) -> list[TaskSpec]:
    """Tasks in manifest order, filtered by every criterion given.

    ``split`` accepts ``short``, ``medium``, ``long`` or ``all``. Non-canonical variants
    are included only with ``include_extra=True`` (they belong to no split).
    """
    if split == "all":
        split = None
    if split is not None:
        _check_choice("split", split, SPLITS + ("all",))
    if memory_type is not None:
        _check_choice("memory type", memory_type, MEMORY_TYPES)
    if family is not None:
        _check_choice("family", family, families())
    if data_source is not None:
        _check_choice("data source", data_source, DATA_SOURCES)
    return [
        t
        for t in _all_tasks()
        if (include_extra or t.canonical)
        and (split is None or t.split == split)
        and (memory_type is None or t.memory_type == memory_type)
        and (family is None or t.family == family)
        and (data_source is None or t.data_source == data_source)
    ]


def canonical_env_ids() -> tuple[str, ...]:
    """The 90 canonical env ids in manifest order."""
    return tuple(t.env_id for t in _all_tasks() if t.canonical)


def unknown_env_id_message(env_id: str, known: list[str] | tuple[str, ...] | None = None) -> str:
    """An error message for an unknown env id that suggests the closest known ids."""
    known = list(known if known is not None else (t.env_id for t in _all_tasks()))
    close = difflib.get_close_matches(env_id, known, n=3, cutoff=0.6)
    hint = f" Did you mean: {', '.join(close)}?" if close else ""
    return (
        f"unknown MIKASA-Robo env id {env_id!r}.{hint} "
        f"See mikasa_envs.list_tasks() for all {len(known)} ids."
    )


class UnknownEnvIdError(KeyError, ValueError):
    """An env id that is not a MIKASA-Robo task (the message suggests close matches)."""

    def __str__(self) -> str:
        return str(self.args[0])


def get_task(env_id: str) -> TaskSpec:
    """The manifest row of ``env_id``; ``UnknownEnvIdError`` with close matches if unknown."""
    spec = find_task(env_id)
    if spec is None:
        _all_tasks()  # the id may belong to a family not imported yet
        spec = find_task(env_id)
    if spec is None:
        raise UnknownEnvIdError(unknown_env_id_message(env_id))
    return spec
