"""docs/BASELINES.md (+ .json) from the LeRobot baseline driver's records, and the pack of
records, table and log tails that travels back from an offline machine with a GPU.

`build_table` gathers everything the table shows into a JSON-ready dict (chance from
``mikasa_bench.results.chance``, the memory type from the task manifest); `render_markdown` writes
it as Markdown. The JSON holds every record, so `restore_records` can bring a fresh clone's
(or a fresh machine's) records back from the committed table.
"""

from __future__ import annotations

import io
import os
import re
import tarfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from baseline_common import DRIVER_CALL, log, now, read_json, rel, write_json
from baseline_settings import DEFAULT_REFERENCES, DEFAULT_TASKS
from baseline_stages import Driver
from mikasa_bench.results.chance import task_chance

__all__ = ["build_table", "render_markdown", "pack", "restore_records"]

REFERENCE_LABELS = {
    "oracle": "oracle",
    "oracle-memoryless": "memoryless oracle",
    "zero": "zero",
    "random": "random",
}


def _fmt_sr(rec: Mapping[str, Any] | None) -> str:
    if rec is None:
        return "pending"
    lo, hi = rec["sr_ci95"]
    return f"{rec['successes']}/{rec['n_episodes']} = {rec['sr']:.0%} [{lo:.0%}, {hi:.0%}]"


def _vs_chance(rec: Mapping[str, Any] | None, chance: float) -> str | None:
    """'at chance' when chance lies in the Wilson interval, else 'above' / 'below'."""
    if rec is None:
        return None
    lo, hi = rec["sr_ci95"]
    return "below" if hi < chance else "above" if lo > chance else "at chance"


def _hms(s: float | None) -> str:
    if s is None:
        return "–"
    s = int(round(s))
    return (
        f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
    )


def build_table(d: Driver) -> dict[str, Any]:
    """Everything docs/BASELINES.md shows, from the records (JSON-ready)."""
    from mikasa_envs.manifest import get_task  # loads the simulator: only when writing

    rows = []
    done = total = 0
    pending: dict[str, list[str]] = {}
    # Every task and setting asked for or recorded (drivers side by side, or earlier calls
    # with other --tasks, all land in one table).
    recorded = (
        sorted(p.name for p in d.records.iterdir() if p.is_dir()) if d.records.is_dir() else []
    )
    tasks = [t for t in DEFAULT_TASKS if t in d.a.tasks or t in recorded]
    tasks += [t for t in [*d.a.tasks, *recorded] if t not in tasks]
    units = {f.stem for t in recorded for f in (d.records / t).glob("*.json")}
    policies = [s for s in d.settings if s in d.a.policies or f"eval-{s}" in units]
    references = list(d.a.references) + [
        r for r in DEFAULT_REFERENCES if r not in d.a.references and f"eval-{r}" in units
    ]
    names = references + policies
    all_records = [
        r
        for t in recorded
        for f in sorted((d.records / t).glob("*.json"))
        if isinstance(r := read_json(f), dict)
    ]
    for task in tasks:
        chance = task_chance(task)
        cells = {}
        for n in names:
            r = d.record(task, f"eval-{n}")
            total += 1
            done += r is not None
            if r is None:
                pending.setdefault(task, []).append(n)
            cells[n] = {"sr": _fmt_sr(r), "vs_chance": _vs_chance(r, chance.rate), "record": r}
        rows.append(
            {
                "task": task,
                "memory_type": get_task(task).memory_type,
                "chance": chance.rate,
                "chance_reason": chance.reason,
                "collect": d.record(task, "collect"),
                "convert": d.record(task, "convert"),
                "train": {s: d.record(task, f"train-{s}") for s in policies},
                "cells": cells,
            }
        )
    return {
        "generated": now(),
        "generated_by": DRIVER_CALL,
        "out": rel(d.out),
        "scale": d.a.scale,
        "episodes_per_task": d.a.episodes,
        "steps": d.a.steps,
        "batch_size": d.a.batch_size,
        "eval_episodes": d.a.eval_episodes,
        "history": d.a.history,
        "settings": {
            s: {
                "label": d.settings[s].label,
                "policy_type": d.settings[s].policy_type,
                "sees": d.settings[s].sees,
                "memoryless": d.settings[s].memoryless,
                "whole_episode": d.settings[s].trainer == "memory",
            }
            for s in policies
        },
        "references": references,
        "rows": rows,
        "records": all_records,
        "done": done,
        "total": total,
        "pending": pending,
    }


def render_markdown(t: Mapping[str, Any]) -> str:
    """docs/BASELINES.md from `build_table`'s dict."""
    settings = t["settings"]
    cols = [(r, REFERENCE_LABELS.get(r, r)) for r in t["references"]]
    cols += [(s, v["label"]) for s, v in settings.items()]
    parts = [
        _headline(t),
        _results(t, cols),
        _finding(t),
        _runs(t),
        _commands(t, cols),
        _left(t),
    ]
    return "\n".join(line for part in parts for line in part) + "\n"


def _headline(t: Mapping[str, Any]) -> list[str]:
    """The title and one sentence: where the memoryless and the history policies stand."""
    memoryless = [0, 0]  # (at or below chance, evaluated)
    history = [0, 0]  # (above chance, evaluated)
    episode = [0, 0]  # (above chance, evaluated)
    for row in t["rows"]:
        for s, v in t["settings"].items():
            verdict = row["cells"][s]["vs_chance"]
            if not verdict:
                continue
            if v["memoryless"]:
                memoryless[0] += verdict in ("at chance", "below")
                memoryless[1] += 1
            else:
                tally = episode if v.get("whole_episode") else history
                tally[0] += verdict == "above"
                tally[1] += 1
    sentence = (
        f"**Policies that see one frame stay at or below chance on {memoryless[0]} of their "
        f"{memoryless[1]} task results"
    )
    if history[1]:
        sentence += f"; with a history of frames they rise above chance on {history[0]} of {history[1]}"
    if episode[1]:
        sentence += (
            f"; a recurrent policy that keeps the whole episode is above chance on {episode[0]} "
            f"of {episode[1]}"
        )
    return ["# LeRobot baselines on MIKASA-Robo-VLA (trained from scratch)\n", sentence + ".**\n"]


def _results(t: Mapping[str, Any], cols: list[tuple[str, str]]) -> list[str]:
    """The title, what the numbers mean, the results table and the settings' legend."""
    settings = t["settings"]
    status = (
        "complete" if t["done"] == t["total"] else f"{t['done']} of {t['total']} results so far"
    )
    out = [
        f"Generated {t['generated']} by `baselines/lerobot/run_baselines.py` from the records in "
        f"`{t['out']}/records` ({status}; scale `{t['scale']}`). Do not edit by hand: re-run "
        f"the driver (`--stages table` rewrites this file from the records alone).\n",
        f"Success rate over {t['eval_episodes']} canonical episodes per task (`mikasa-bench run`, "
        "seeds 4242424242 + i, rgb, `pd_ee_delta_pose`, canonical wrapper chain) as successes/episodes "
        "= rate [Wilson 95 % interval]. **chance**: what a policy without memory gets by guessing "
        "(`mikasa_bench.results.chance`; reasons below). Learned policies: LeRobot 0.4.4 policies trained "
        f"from scratch (no pretrained weights) on {t['episodes_per_task']} oracle demonstrations per "
        f"task, {t['steps']} steps at batch {t['batch_size']} unless a row says otherwise "
        "(the GRU's batch is whole episodes: `mikasa-memory-train`, `baselines/memory`). "
        "*at chance* / *above* / *below*: where chance lies relative to the interval.\n",
        "| task | memory | chance | " + " | ".join(label for _, label in cols) + " |",
        "|---|---|---|" + "---|" * len(cols),
    ]
    for row in t["rows"]:
        cells = []
        for name, _ in cols:
            c = row["cells"][name]
            verdict = c["vs_chance"] if name in settings else None
            cells.append(c["sr"] + (f" *{verdict}*" if verdict else ""))
        out.append(
            f"| {row['task']} | {row['memory_type'] or '–'} | {row['chance']:.3g} | "
            + " | ".join(cells)
            + " |"
        )
    out += ["", "Policy settings (what each learned policy sees when it acts):\n"]
    for s, v in settings.items():
        out.append(f"- **{v['label']}** (`{s}`, lerobot `{v['policy_type']}`): {v['sees']}.")
    if "oracle" in t["references"]:
        out.append(
            "- **oracle**: the scripted privileged-state solver (`mikasa-bench run --policy oracle`)."
        )
    if "oracle-memoryless" in t["references"]:
        out.append(
            "- **memoryless oracle**: the same controller with its memory of the answer wiped "
            "every step (`--policy oracle-memoryless`)."
        )
    return [*out, ""]


def _finding(t: Mapping[str, Any]) -> list[str]:
    """Per task, every learned policy's verdict against chance; memoryless ones counted."""
    out = ["## Finding\n"]
    lines = []
    counts: dict[str, int] = {}
    for row in t["rows"]:
        verdicts = []
        for s, v in t["settings"].items():
            verdict = row["cells"][s]["vs_chance"]
            if verdict:
                kind = (
                    "memoryless"
                    if v["memoryless"]
                    else "whole episode"
                    if v.get("whole_episode")
                    else "with history/chunks"
                )
                verdicts.append(f"{v['label']} ({kind}) {verdict}")
                if v["memoryless"]:
                    counts[verdict] = counts.get(verdict, 0) + 1
        if verdicts:
            oracle = row["cells"].get("oracle", {}).get("sr", "–")
            lines.append(
                f"- {row['task']} ({row['memory_type']} memory; chance {row['chance']:.3g}; "
                f"oracle {oracle}): " + "; ".join(verdicts)
            )
    if not lines:
        return [*out, "No learned policy has been evaluated yet.\n"]
    summary = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    so_far = "" if t["done"] == t["total"] else " so far"
    out.append(
        "Does memoryless imitation sit at chance where memory is required? Per task, each "
        "learned policy's interval against chance (memoryless = one frame in, re-planning "
        f"every step). Memoryless (task, policy) results{so_far}: {summary or 'none'}.\n"
    )
    return [*out, *lines, ""]


def _runs(t: Mapping[str, Any]) -> list[str]:
    """Per run the dataset, training and evaluation; per task the oracle's yield."""
    settings = t["settings"]
    out = [
        "## Runs\n",
        "| task | policy | dataset (episodes / frames / MB) | training | training wall time "
        "(calls) | steps/s | device | final loss | eval wall time (how) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in t["rows"]:
        conv = row["convert"] or {}
        data = (
            f"{conv.get('episodes', '–')} / {conv.get('frames', '–')} / {conv.get('size_mb', '–')}"
            if conv
            else "pending"
        )
        for s in settings:
            tr = row["train"].get(s)
            ev = row["cells"][s]["record"]
            # The memory trainer reads NPZ episodes, not the converted dataset: its own count.
            own_data = tr and tr.get("episodes")
            data_s = f"{tr['episodes']} / {tr['frames']} / NPZ" if own_data else data
            if tr:
                unit = f" {tr['batch_unit']}" if tr.get("batch_unit") else ""
                training = f"{tr['steps']} steps x {tr['batch_size']}{unit}"
                wall = f"{_hms(tr['wall_s'])} ({tr['calls']})"
                loss = f"{tr['final_loss']:.4f}" if tr.get("final_loss") is not None else "–"
                device = tr.get("device") or "–"
                rate = f"{tr['steps_per_s']:.2f}" if tr.get("steps_per_s") else "–"
            else:
                training, wall, loss, device, rate = "pending", "–", "–", "–", "–"
            evw = "–"
            if ev:
                how = _eval_spread(ev)
                if ev.get("calls", 1) > 1:  # a cut lockstep call replays its rounds
                    how += f"; {ev['calls']} calls"
                evw = f"{_hms(ev.get('wall_s'))} ({how})"
            out.append(
                f"| {row['task']} | {settings[s]['label']} | {data_s} | {training} | {wall} | "
                f"{rate} | {device} | {loss} | {evw} |"
            )
    out += [
        "",
        "Oracle demonstrations: the oracle's yield while collecting (successful episodes / seeds "
        "tried; failed attempts are not kept) and collection wall time:\n",
        "| task | episodes | yield | collection wall time | chance: why |",
        "|---|---|---|---|---|",
    ]
    for row in t["rows"]:
        col = row["collect"] or {}
        y = f"{col['episodes']}/{col['attempts']}" if col.get("attempts") else "–"
        out.append(
            f"| {row['task']} | {col.get('episodes', '–')} | {y} | {_hms(col.get('wall_s'))} "
            f"| {row['chance_reason']} |"
        )
    return [*out, ""]


def _eval_spread(rec: Mapping[str, Any]) -> str:
    """How an evaluation ran, from its command: lockstep batches, in-process or workers."""
    cmd = str(rec.get("command", ""))
    if m := re.search(r"--policy-batch (\d+)", cmd):
        per = re.search(r"--envs-per-worker (\d+)", cmd)
        if per is None:
            return f"lockstep {m.group(1)}"
        return (
            f"lockstep {m.group(1)}, {per.group(1)} env{'' if per.group(1) == '1' else 's'}/process"
        )
    m = re.search(r"--workers (\d+)", cmd)
    if m is None:
        return "?"
    return "in-process" if m.group(1) == "0" else f"{m.group(1)} workers"


def _commands(t: Mapping[str, Any], cols: list[tuple[str, str]]) -> list[str]:
    """The driver calls behind the records, then every unit's commands per task."""
    out = ["## Commands\n"]
    calls = sorted({r["driver"] for r in t["records"] if r.get("driver")})
    out.append(
        "The driver calls that produced the records (repeat a call until it exits 0; see "
        "`baselines/lerobot/README.md`):\n"
    )
    if calls:
        out += ["```bash", *calls, "```\n"]
    out.append(
        "Each unit ran these commands (paths relative to the repository; `lerobot_train.py` "
        "is lerobot-train with a clean stop at the time limit):\n"
    )
    for row in t["rows"]:
        cmds = [
            row[key]["command"] for key in ("collect", "convert") if (row[key] or {}).get("command")
        ]
        for s in t["settings"]:
            r = row["train"].get(s)
            if r:
                cmds.append(r["command"])
                if r["calls"] > 1:
                    cmds.append(f"# resumed {r['calls'] - 1} time(s) with: {r['resume_command']}")
        for name, _ in cols:
            r = row["cells"][name]["record"]
            if r and r.get("command"):
                cmds.append(r["command"])
        if cmds:
            out += [f"<details><summary>{row['task']}</summary>\n\n```bash", *cmds]
            out.append("```\n</details>\n")
    return out


def _left(t: Mapping[str, Any]) -> list[str]:
    """What is not evaluated yet."""
    out = ["## What is left\n"]
    if not t["pending"]:
        return [*out, "Nothing: every configured task and policy has its result.\n"]
    out.append("Not yet evaluated:\n")
    out += [f"- {task}: {', '.join(names)}" for task, names in t["pending"].items()]
    return [*out, ""]


def restore_records(d: Driver, table_json: Path) -> int:
    """Write the finished records of a table JSON (``docs/BASELINES.json``) that
    ``<out>/records`` lacks; returns how many. The records directory is not committed, the
    table is: this lets a fresh clone add rows to the committed table and skip the units it
    already shows (units whose outputs a later unit needs, e.g. a dataset for a training,
    are redone when those outputs are missing)."""
    table = read_json(table_json)
    if not isinstance(table, dict):
        return 0
    restored = 0
    for rec in table.get("records") or []:
        if not (isinstance(rec, dict) and rec.get("status") == "done"):
            continue
        task, unit = str(rec.get("task", "")), str(rec.get("unit", ""))
        if not task or not unit or "/" in task + unit or d.record_path(task, unit).exists():
            continue
        write_json(d.record_path(task, unit), rec)
        restored += 1
    if restored:
        log(f"restored {restored} record(s) from {rel(table_json)}")
    return restored


def pack(d: Driver, path: Path) -> None:
    """A .tar.gz of the records, the table (md + json) and the logs' tails, for the trip back
    from an offline machine with a GPU (the records are small; datasets and checkpoints stay behind)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    doc = Path(d.a.doc)
    with tarfile.open(tmp, "w:gz") as tar:
        if d.records.is_dir():
            tar.add(d.records, arcname="records")
        for f in (doc, doc.with_suffix(".json")):
            if f.is_file():
                tar.add(f, arcname=f"docs/{f.name}")
        logs = d.out / "logs"
        if logs.is_dir():
            for f in sorted(logs.rglob("*.log")):
                data = f.read_bytes()[-200_000:]  # the tail: tracebacks and summaries
                info = tarfile.TarInfo(f"logs/{f.relative_to(logs)}")
                info.size = len(data)
                info.mtime = int(f.stat().st_mtime)
                tar.addfile(info, io.BytesIO(data))
    os.replace(tmp, path)
    log(f"packed {rel(path)} ({path.stat().st_size / 1e6:.2f} MB)")
