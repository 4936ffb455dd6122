"""Env id <-> on-disk dataset name (datasets spec §1).

Every local dataset directory (NPZ, RLDS, LeRobot) is named by the snake-case *dataset
name* of a task (``RememberColor3-VLA-v0`` -> ``remember_color_3_vla_v0``); the env id
itself names the task everywhere else. This module is the single source of truth for
that mapping.
"""

from __future__ import annotations

import re

__all__ = ["env_id_to_dataset_name", "is_dataset_name"]

_DATASET_NAME = re.compile(r"[a-z0-9_]+")
# (a) lowercase letter followed by an uppercase letter: "eC" -> "e_C".
_LOWER_UPPER = re.compile(r"([a-z])([A-Z])")
# (b) a run of capitals followed by a capitalised word: "HTTPServer" -> "HTTP_Server".
_ACRONYM_WORD = re.compile(r"([A-Z]+)([A-Z][a-z])")
# (c) letter -> digit, but only when two or more letters precede the digit, so version
# tags and short codes ("v0", "X3", "V2A") stay whole: "Color3" -> "Color_3".
_WORD_DIGIT = re.compile(r"(?<=[A-Za-z])([A-Za-z])(\d)")


def is_dataset_name(value: str) -> bool:
    """True iff ``value`` is non-empty and made only of ``a-z``, ``0-9`` and ``_``."""
    return bool(value) and _DATASET_NAME.fullmatch(value) is not None


def _snake_piece(piece: str) -> str:
    piece = _LOWER_UPPER.sub(r"\1_\2", piece)
    piece = _ACRONYM_WORD.sub(r"\1_\2", piece)
    piece = _WORD_DIGIT.sub(r"\1_\2", piece)
    return piece.lower()


def env_id_to_dataset_name(env_id: str) -> str:
    """The dataset name of ``env_id`` (spec §1.2); idempotent on dataset names.

    >>> env_id_to_dataset_name("RememberColor3-VLA-v0")
    'remember_color_3_vla_v0'
    >>> env_id_to_dataset_name("RememberShapeAndColor3x2-Long-VLA-v0")
    'remember_shape_and_color_3x2_long_vla_v0'
    """
    if is_dataset_name(env_id):
        return env_id
    # Empty pieces are dropped so "--" collapses into a single separator.
    return "_".join(_snake_piece(p) for p in env_id.split("-") if p)
