"""Learning curves of PPO runs from their TensorBoard logs: a PNG and the points as JSON.

    python docs/lab-notes/rl-ppo-runs/plot_curves.py RUN_DIR_OR_EVENT_FILE [...] --labels "PPO-MLP state" \\
        --out docs/lab-notes/rl-ppo-runs/curves/RememberColor3-v0_state

Plots ``eval/success_once`` and ``eval/return`` (or the ``--tags`` given, e.g. ``train/return``)
against env steps, one line per run.
"""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Callable
from pathlib import Path

TAGS = ("eval/success_once", "eval/return")


def read_curves(path: Path, tags: tuple[str, ...] = TAGS) -> dict[str, list[tuple[int, float]]]:
    """{tag: [(env step, value), ...]} of ``tags`` from an event file, or from all event files
    of a run directory (a ``--resume``d run adds one per piece; a later piece's point wins)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    files = [path] if path.is_file() else sorted(path.rglob("events.out.tfevents.*"))
    if not files:
        raise ValueError(f"no TensorBoard event file at {path}")
    curves: dict[str, dict[int, float]] = {}
    for file in files:  # event files are named by creation time: oldest first
        events = EventAccumulator(str(file))
        events.Reload()
        for tag in tags:
            if tag in events.Tags()["scalars"]:
                curves.setdefault(tag, {}).update((e.step, e.value) for e in events.Scalars(tag))
    return {tag: sorted(points.items()) for tag, points in curves.items()}


def curves_json(curves: dict[str, dict[str, list[tuple[int, float]]]]) -> str:
    """The points as JSON, one line per run and tag (a redraw of a grown run then changes a few
    lines, not one per number), values at 7 significant digits (TensorBoard stores float32,
    good to about 7; a curve needs fewer)."""
    def points(values: list[tuple[int, float]]) -> str:
        return json.dumps([[step, float(f"{value:.7g}")] for step, value in values])

    runs = [
        f"  {json.dumps(label)}: {{\n"
        + ",\n".join(f"    {json.dumps(tag)}: {points(values)}" for tag, values in tags.items())
        + "\n  }"
        for label, tags in curves.items()
    ]
    return "{\n" + ",\n".join(runs) + "\n}\n"


def write_replacing(path: Path, write: Callable[[Path], object]) -> None:
    """Write ``path`` through a temporary file beside it, so that a failed or interrupted write
    leaves the curve shipped before it whole."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", type=Path, help="run directories or event files")
    parser.add_argument(
        "--labels", nargs="*", default=None, help="one label per run (default: the paths)"
    )
    parser.add_argument(
        "--tags", nargs="+", default=list(TAGS), help=f"scalars to plot (default: {' '.join(TAGS)})"
    )
    parser.add_argument(
        "--out", required=True, help="output path without extension (.png and .json are written)"
    )
    args = parser.parse_args()
    labels = args.labels or [str(r) for r in args.runs]
    if len(labels) != len(args.runs):
        parser.error(f"{len(args.runs)} runs but {len(labels)} labels")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tags = tuple(args.tags)
    curves = {label: read_curves(run, tags) for label, run in zip(labels, args.runs, strict=True)}
    fig, axes = plt.subplots(1, len(tags), figsize=(5 * len(tags), 3.5), squeeze=False)
    axes = axes[0]
    for ax, tag in zip(axes, tags, strict=True):
        for label, runs in curves.items():
            if tag in runs:
                steps, values = zip(*runs[tag], strict=True)
                ax.plot(steps, values, label=label)
        ax.set_xlabel("env steps")
        ax.set_title(tag)
        ax.grid(alpha=0.3)
        if tag.endswith("success_once"):
            ax.set_ylim(-0.02, 1.02)
    # Below the plots: inside, a legend of long run labels hides the curves.
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=min(2, len(names)), fontsize="small")
    rows = -(-len(names) // 2)
    fig.tight_layout(rect=(0, 0.07 * rows, 1, 1))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = curves_json(curves)
    write_replacing(out.with_suffix(".png"), lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    write_replacing(out.with_suffix(".json"), lambda tmp: tmp.write_text(text))


if __name__ == "__main__":
    main()
