"""Reports: a plain-text results table, a Markdown report and a self-contained HTML report.

A report covers one or more runs (e.g. several policies on the same tasks): tables of
success rate (with Wilson 95 % intervals), mean return and episode length per task,
means per split and per memory type, and three plots (success by memory type and split,
per-task success bars, episode lengths). The Markdown file references PNGs in
``report_assets/``; the HTML file embeds the same PNGs as base64 and needs nothing else.
Runs recorded with ``--video`` get a Videos section linking each episode's mp4 (relative
links: they work as long as the report stays next to the run directories).
"""

from __future__ import annotations

import base64
import html
import io
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mikasa_bench.results.files import atomic_write_bytes
from mikasa_bench.results.metrics import aggregate_by, wilson_interval
from mikasa_bench.results.run_data import RunData
from mikasa_bench.results.text import format_percent, format_rows

__all__ = ["text_table", "write_report", "REPORT_MD", "REPORT_HTML", "ASSETS_DIR"]

REPORT_MD = "report.md"
REPORT_HTML = "report.html"
ASSETS_DIR = "report_assets"
_SPLIT_ORDER = ("Short", "Medium", "Long", "Custom")


def _ci(r: dict[str, Any]) -> tuple[float, float]:
    s = r["successes"]
    return wilson_interval(sum(bool(x) for x in s), len(s))


def _mean_len(r: dict[str, Any]) -> float:
    lengths = r.get("episode_lengths") or []
    return sum(lengths) / len(lengths) if lengths else float("nan")


def _task_order(runs: Sequence[RunData]) -> list[str]:
    order: dict[str, None] = {}
    for run in runs:
        for r in run.results:
            order.setdefault(r["env_id"], None)
    return list(order)


def _by_id(run: RunData) -> dict[str, dict[str, Any]]:
    return {r["env_id"]: r for r in run.results}


def _aggregates(run: RunData) -> dict[str, dict[str, float]]:
    return {
        "split": aggregate_by(run.results, "split"),
        "memory_type": dict(sorted(aggregate_by(run.results, "memory_type").items())),
    }


def _overall(run: RunData) -> float:
    return sum(float(r["sr"]) for r in run.results) / len(run.results)


# ------------------------------------------------------------------------------------
# text
# ------------------------------------------------------------------------------------


def text_table(runs: Sequence[RunData]) -> str:
    """The per-task results of every run plus per-split / per-memory-type / overall means."""
    header = ["Task", "Split", "Memory", "Policy", "SR", "95% CI", "Return", "Length", "Eps"]
    rows = _task_cells(runs, ci="[{lo}, {hi}]")
    # One block per task: its id, split and memory type only on the block's first line.
    ids = [row[0] for row in rows]
    for i in range(1, len(rows)):
        if ids[i] == ids[i - 1]:
            rows[i][:3] = ["", "", ""]
    out = [format_rows(header, rows, right={4, 6, 7, 8})]
    agg_rows = _group_cells(runs, titles=("split", "memory"))
    agg_rows.append(["overall (mean task SR)", *[format_percent(_overall(run)) for run in runs]])
    agg_header = ["Group", *[run.label for run in runs]]
    out.append(format_rows(agg_header, agg_rows, right=set(range(1, len(runs) + 1))))
    return "\n\n".join(out)


def _task_cells(runs: Sequence[RunData], *, ci: str) -> list[list[str]]:
    """One row per (task, run): task, split, memory type, policy, SR, CI (``ci`` formats
    ``lo``/``hi``), mean return, mean length, episodes."""
    rows = []
    for env_id in _task_order(runs):
        for run in runs:
            r = _by_id(run).get(env_id)
            if r is None:
                continue
            lo, hi = _ci(r)
            rows.append(
                [
                    env_id,
                    r["split"],
                    r["memory_type"],
                    run.label,
                    format_percent(float(r["sr"])),
                    ci.format(lo=format_percent(lo), hi=format_percent(hi)),
                    f"{float(r['mean_return']):.2f}",
                    f"{_mean_len(r):.1f}",
                    str(len(r["successes"])),
                ]
            )
    return rows


def _group_cells(runs: Sequence[RunData], *, titles: tuple[str, str]) -> list[list[str]]:
    """Per-split and per-memory-type mean SR rows, one column per run (``titles`` name the
    two groupings)."""
    aggs = [_aggregates(run) for run in runs]
    rows = []
    for kind, title in zip(("split", "memory_type"), titles, strict=True):
        keys: dict[str, None] = {}
        for a in aggs:
            keys.update(dict.fromkeys(a[kind]))
        for k in keys:
            rows.append([f"{title}: {k}", *[format_percent(a[kind].get(k, float("nan"))) for a in aggs]])
    return rows


# ------------------------------------------------------------------------------------
# plots
# ------------------------------------------------------------------------------------


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return buf.getvalue()


def _plots(runs: Sequence[RunData]) -> dict[str, bytes]:
    import matplotlib

    matplotlib.use("Agg")  # no display; must precede pyplot's first use in this process
    import matplotlib.pyplot as plt
    import numpy as np

    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    n_runs = len(runs)
    width = 0.8 / n_runs
    out: dict[str, bytes] = {}

    # 1) success by memory type and by split
    aggs = [_aggregates(run) for run in runs]
    fig, axes = plt.subplots(
        1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [2.2, 1]}, squeeze=False
    )
    for ax, kind, title in (
        (axes[0][0], "memory_type", "Success rate by memory type"),
        (axes[0][1], "split", "Success rate by split"),
    ):
        keys: dict[str, None] = {}
        for a in aggs:
            keys.update(dict.fromkeys(a[kind]))
        names = list(keys)
        if kind == "split":
            names.sort(key=lambda s: _SPLIT_ORDER.index(s) if s in _SPLIT_ORDER else 99)
        x = np.arange(len(names))
        for i, (run, a) in enumerate(zip(runs, aggs, strict=False)):
            vals = [100 * a[kind].get(k, float("nan")) for k in names]
            bars = ax.bar(
                x + (i - (n_runs - 1) / 2) * width,
                vals,
                width,
                label=run.label,
                color=colors[i % len(colors)],
            )
            # Value labels: a 0 % bar is otherwise invisible.
            ax.bar_label(bars, labels=[format_percent(v / 100) for v in vals], fontsize=7, padding=1)
        ax.set_xticks(
            x,
            names,
            rotation=30 if len(names) > 3 else 0,
            ha="right" if len(names) > 3 else "center",
        )
        ax.set_ylim(0, 105)
        ax.set_ylabel("success rate (%)")
        ax.set_title(title)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].legend(fontsize=8)
    out["success_by_group.png"] = _png(fig)

    # 2) per-task success with Wilson 95 % intervals
    tasks = _task_order(runs)
    fig, ax = plt.subplots(figsize=(9, 0.9 + 0.32 * len(tasks) * max(1, n_runs) ** 0.5 + 0.4))
    y = np.arange(len(tasks))
    for i, run in enumerate(runs):
        by_id = _by_id(run)
        vals, err_lo, err_hi, ys = [], [], [], []
        for j, t in enumerate(tasks):
            r = by_id.get(t)
            if r is None:
                continue
            lo, hi = _ci(r)
            sr = float(r["sr"])
            vals.append(100 * sr)
            # max(0, .): float rounding can put a bound a hair past the estimate.
            err_lo.append(max(0.0, 100 * (sr - lo)))
            err_hi.append(max(0.0, 100 * (hi - sr)))
            ys.append(y[j] + (i - (n_runs - 1) / 2) * width)
        bars = ax.barh(
            ys,
            vals,
            height=width,
            xerr=[err_lo, err_hi],
            capsize=2,
            label=run.label,
            color=colors[i % len(colors)],
            error_kw={"elinewidth": 0.8, "alpha": 0.7},
        )
        ax.bar_label(bars, labels=[format_percent(v / 100) for v in vals], fontsize=7, padding=2)
    ax.set_yticks(y, tasks, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 112)
    ax.set_xlabel("success rate (%), whiskers: Wilson 95% CI")
    ax.set_title("Per-task success rate")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    out["per_task_success.png"] = _png(fig)

    # 3) episode lengths per task (box per run)
    fig, ax = plt.subplots(figsize=(9, 0.9 + 0.32 * len(tasks) * max(1, n_runs) ** 0.5 + 0.4))
    for i, run in enumerate(runs):
        by_id = _by_id(run)
        data, pos = [], []
        for j, t in enumerate(tasks):
            r = by_id.get(t)
            if r is None or not r.get("episode_lengths"):
                continue
            data.append(r["episode_lengths"])
            pos.append(y[j] + (i - (n_runs - 1) / 2) * width)
        if data:
            c = colors[i % len(colors)]
            ax.boxplot(
                data,
                positions=pos,
                widths=width * 0.9,
                vert=False,
                manage_ticks=False,
                patch_artist=True,
                boxprops={"facecolor": c, "alpha": 0.35},
                medianprops={"color": "black"},
                showfliers=False,
            )
            # Every episode as a dot (boxes collapse when all lengths are equal).
            rng = np.random.default_rng(0)
            for p, d in zip(pos, data, strict=False):
                jitter = rng.uniform(-0.25, 0.25, len(d)) * width
                ax.scatter(d, p + jitter, s=10, color=c, alpha=0.8, zorder=3)
            ax.plot([], [], color=c, lw=6, alpha=0.6, label=run.label)
    ax.set_yticks(y, tasks, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(left=0)
    ax.set_xlabel("episode length (steps)")
    ax.set_title("Episode lengths")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    out["episode_lengths.png"] = _png(fig)
    return out


# ------------------------------------------------------------------------------------
# Markdown / HTML
# ------------------------------------------------------------------------------------


def _run_info(run: RunData) -> list[tuple[str, str]]:
    s = run.summary or {}
    proto = s.get("protocol") or {}
    r0 = run.results[0]
    info = [
        ("results", run.source or str(run.run_dir)),
        ("policy", run.label),
        (
            "tasks",
            f"{len(run.results)}"
            + (
                ""
                if s.get("complete", True)
                else f" finished, {len(s.get('tasks_pending', []))} pending"
            ),
        ),
        ("episodes per task", str(proto.get("n_episodes", r0.get("n_episodes")))),
        ("start seed", str(proto.get("start_seed", r0.get("start_seed")))),
        (
            "obs / control / reward",
            f"{proto.get('obs_mode', r0.get('obs_mode'))} / "
            f"{proto.get('control_mode', r0.get('control_mode'))} / "
            f"{proto.get('reward_mode', r0.get('reward_mode', '?'))}",
        ),
        ("wrapper chain", str(proto.get("wrapper_chain", r0.get("wrapper_chain")))),
        ("action chunk size", str(r0.get("action_chunk_size"))),
    ]
    if proto:
        canon = "yes" if proto.get("canonical") else "no: " + "; ".join(proto.get("deviations", []))
        info.append(("canonical protocol", canon))
        info.append(("sim backend", str(proto.get("sim_backend"))))
        if proto.get("render_device"):
            info.append(("render device", str(proto["render_device"])))
        if proto.get("policy_batch", 1) > 1:
            info.append(("policy batch", f"{proto['policy_batch']} episodes in lockstep"))
    sel = s.get("selection") or {}
    if sel.get("skipped_unregistered"):
        info.append(("skipped (not registered)", ", ".join(sel["skipped_unregistered"])))
    if s.get("wall_time_s") is not None:
        info.append(("wall time", f"{float(s['wall_time_s']):.1f} s"))
    if s.get("benchmark_commit") or r0.get("benchmark_commit"):
        info.append(
            ("benchmark commit", str(s.get("benchmark_commit") or r0.get("benchmark_commit")))
        )
    versions = s.get("versions") or {}
    if versions:
        info.append(
            (
                "versions",
                ", ".join(f"{k} {v}" for k, v in versions.items() if v and k != "platform"),
            )
        )
    return info


def _task_rows(runs: Sequence[RunData]) -> tuple[list[str], list[list[str]]]:
    header = [
        "Task",
        "Split",
        "Memory type",
        "Policy",
        "SR",
        "95% CI",
        "Mean return",
        "Mean length",
        "Episodes",
    ]
    return header, _task_cells(runs, ci="{lo} – {hi}")


def _agg_rows(runs: Sequence[RunData]) -> tuple[list[str], list[list[str]]]:
    header = ["Group", *[run.label for run in runs]]
    rows = _group_cells(runs, titles=("Split", "Memory type"))
    rows.append(["**Overall (mean task SR)**", *[f"**{format_percent(_overall(run))}**" for run in runs]])
    return header, rows


def _video_rows(
    runs: Sequence[RunData], out_dir: Path
) -> list[tuple[str, str, list[tuple[str, str]]]]:
    """``(env_id, policy, [(episode label, link relative to out_dir)])`` for every task
    result that lists videos; links to files that do not exist are left out."""
    rows = []
    for env_id in _task_order(runs):
        for run in runs:
            r = _by_id(run).get(env_id)
            if r is None or not r.get("videos"):
                continue
            links = []
            for i, rel in enumerate(r["videos"]):
                if rel and (run.run_dir / rel).is_file():
                    link = os.path.relpath(run.run_dir / rel, out_dir).replace(os.sep, "/")
                    links.append((str(i), link))
            if links:
                rows.append((env_id, run.label, links))
    return rows


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    esc = [[str(c).replace("|", "\\|") for c in r] for r in rows]
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in esc]
    return "\n".join(lines)


_CAPTIONS = {
    "success_by_group.png": "Success rate by memory type and split",
    "per_task_success.png": "Per-task success rate (Wilson 95% CI)",
    "episode_lengths.png": "Episode lengths",
}


def _markdown(
    runs: Sequence[RunData],
    title: str,
    assets: str,
    videos: Sequence[tuple[str, str, list[tuple[str, str]]]] = (),
) -> str:
    parts = [f"# {title}", ""]
    for run in runs:
        if len(runs) > 1:
            parts.append(f"## Run: {run.label}")
        parts.append(_md_table(["Setting", "Value"], _run_info(run)))
        parts.append("")
    parts += [
        "## Summary",
        "",
        _md_table(*_agg_rows(runs)),
        "",
        "## Per task",
        "",
        _md_table(*_task_rows(runs)),
        "",
        "## Plots",
        "",
    ]
    for name, caption in _CAPTIONS.items():
        parts += [f"![{caption}]({assets}/{name})", ""]
    if videos:
        rows = [
            [env_id, label, " ".join(f"[{n}](<{link}>)" for n, link in links)]
            for env_id, label, links in videos
        ]
        parts += [
            "## Videos",
            "",
            "Scene view with the task's overlays beside the top and wrist cameras; one mp4 "
            "per episode.",
            "",
            _md_table(["Task", "Policy", "Episodes"], rows),
            "",
        ]
    parts.append(
        "SR: fraction of episodes with `success_once`; CI: Wilson score interval. "
        "Split and memory-type rows average task SRs. Mean return is a debug metric."
    )
    return "\n".join(parts) + "\n"


_CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;color:#222;padding:0 1em}
table{border-collapse:collapse;margin:1em 0;font-size:14px}
th,td{border:1px solid #ddd;padding:4px 8px;text-align:left}
th{background:#f3f3f3} td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;border:1px solid #eee;margin:0.5em 0}
.note{color:#666;font-size:13px}
"""


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]], num_from: int) -> str:
    def cell(i: int, c: str, tag: str) -> str:
        bold = c.startswith("**") and c.endswith("**")
        text = html.escape(c.strip("*") if bold else c)
        text = f"<b>{text}</b>" if bold else text
        cls = ' class="num"' if tag == "td" and i >= num_from else ""
        return f"<{tag}{cls}>{text}</{tag}>"

    head = "<tr>" + "".join(cell(i, h, "th") for i, h in enumerate(header)) + "</tr>"
    body = "".join(
        "<tr>" + "".join(cell(i, c, "td") for i, c in enumerate(r)) + "</tr>" for r in rows
    )
    return f"<table>{head}{body}</table>"


def _html(
    runs: Sequence[RunData],
    title: str,
    images: dict[str, bytes],
    videos: Sequence[tuple[str, str, list[tuple[str, str]]]] = (),
) -> str:
    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"
    ]
    for run in runs:
        if len(runs) > 1:
            parts.append(f"<h2>Run: {html.escape(run.label)}</h2>")
        parts.append(_html_table(["Setting", "Value"], _run_info(run), num_from=99))
    th, tr = _agg_rows(runs)
    parts += ["<h2>Summary</h2>", _html_table(th, tr, num_from=1)]
    th, tr = _task_rows(runs)
    parts += ["<h2>Per task</h2>", _html_table(th, tr, num_from=4), "<h2>Plots</h2>"]
    for name, caption in _CAPTIONS.items():
        b64 = base64.b64encode(images[name]).decode("ascii")
        parts.append(
            f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{b64}'>"
            f"<figcaption class='note'>{html.escape(caption)}</figcaption></figure>"
        )
    if videos:
        # Links, not embedded <video>s: a canonical run has thousands of episodes.
        parts.append("<h2>Videos</h2><table><tr><th>Task</th><th>Policy</th><th>Episodes</th></tr>")
        for env_id, label, links in videos:
            cells = " ".join(
                f"<a href='{html.escape(link, quote=True)}'>{html.escape(n)}</a>"
                for n, link in links
            )
            parts.append(
                f"<tr><td>{html.escape(env_id)}</td><td>{html.escape(label)}</td>"
                f"<td>{cells}</td></tr>"
            )
        parts.append("</table>")
    parts.append(
        "<p class='note'>SR: fraction of episodes with success_once; CI: Wilson score "
        "interval. Split and memory-type rows average task SRs. Mean return is a debug "
        "metric.</p></body></html>"
    )
    return "\n".join(parts) + "\n"


def write_report(
    runs: Sequence[RunData], out_dir: str | Path, title: str | None = None
) -> tuple[Path, Path]:
    """Write ``report.md`` (+ ``report_assets/*.png``) and the self-contained
    ``report.html`` into ``out_dir``; returns both paths."""
    if not runs:
        raise ValueError("no runs to report")
    out = Path(out_dir)
    title = title or (
        f"MIKASA-Robo evaluation: {runs[0].label}"
        if len(runs) == 1
        else "MIKASA-Robo evaluation: " + " vs ".join(r.label for r in runs)
    )
    images = _plots(runs)
    for name, data in images.items():
        atomic_write_bytes(out / ASSETS_DIR / name, data)
    md_path, html_path = out / REPORT_MD, out / REPORT_HTML
    videos = _video_rows(runs, out)
    atomic_write_bytes(md_path, _markdown(runs, title, ASSETS_DIR, videos).encode("utf-8"))
    atomic_write_bytes(html_path, _html(runs, title, images, videos).encode("utf-8"))
    return md_path, html_path
