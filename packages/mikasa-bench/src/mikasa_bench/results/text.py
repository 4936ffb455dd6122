"""Plain-text formatting shared by the results table, ``compare`` and ``list``."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["format_percent", "format_rows"]


def format_percent(x: float | None) -> str:
    """A rate in [0, 1] as a whole percentage (``"42%"``); ``"—"`` for None or NaN."""
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.0f}%"


def format_rows(header: Sequence[str], rows: Sequence[Sequence[str]], right: set[int]) -> str:
    """An aligned text table: the header, a dashed rule, then the rows; the columns whose
    index is in ``right`` are right-aligned."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows, strict=False)]

    def fmt(row: Sequence[str]) -> str:
        cells = [
            str(c).rjust(w) if i in right else str(c).ljust(w)
            for i, (c, w) in enumerate(zip(row, widths, strict=False))
        ]
        return "  ".join(cells).rstrip()

    sep = "  ".join("-" * w for w in widths)
    return "\n".join([fmt(header), sep, *(fmt(r) for r in rows)])
