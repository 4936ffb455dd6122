"""The gallery's HTML page: one card per task, grouped by memory type, standalone (no
scripts or styles from elsewhere). A script run at the page's load event writes into
``#image-status`` how many animations loaded (``data-loaded`` / ``data-total``), so a
headless browser can check the page as a person would see it."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from mikasa_bench.results.files import atomic_write_bytes

__all__ = ["write_index"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5rem; background: #fafafa; color: #222; }
h1 { margin-bottom: 0.2rem; } h2 { margin-top: 2rem; border-bottom: 1px solid #ccc; }
.grid { display: flex; flex-wrap: wrap; gap: 1rem; }
.card { background: #fff; border: 1px solid #ddd; border-radius: 6px; padding: 0.8rem;
        width: 540px; box-sizing: border-box; }
.card img { width: 512px; image-rendering: pixelated; display: block; }
.card h3 { margin: 0.5rem 0 0.3rem; font-family: monospace; font-size: 1rem; }
.card dl { display: grid; grid-template-columns: 8.5rem 1fr; gap: 0.15rem 0.5rem;
           margin: 0; font-size: 0.85rem; }
.card dt { font-weight: 600; color: #555; }
.phase { display: inline-block; padding: 0 0.4rem; color: #fff; border-radius: 3px; }
.fail { color: #b00; font-weight: 600; }
#image-status { color: #555; }
"""

_CHECK_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  var el = document.getElementById("image-status");
  el.dataset.loaded = ok; el.dataset.total = imgs.length;
  el.textContent = ok + " of " + imgs.length + " animations loaded.";
});
"""


def _card(card: Mapping[str, Any]) -> str:
    e = html.escape
    ep = card.get("episode", {})
    outcome = (
        f"success in {ep.get('steps')} steps"
        if ep.get("success")
        else f"<span class='fail'>no success</span> in {ep.get('steps')} steps"
    )
    chance = card["chance"]
    rows = [
        ("Task", e(card["description"])),
        ("Instruction", e(card["instruction"])),
        ("Memory type", e(card["memory_type"])),
        ("Split / horizon", f"{e(card['split'])} / {card['horizon']} steps"),
        ("What is hidden", e(card["hidden"])),
        ("When", e(card["phases"])),
        ("Randomized", e(card["randomizations"])),
        ("Success", e(card["success_condition"])),
        ("Chance", f"{chance['rate']:.3g} ({e(chance['reason'])})"),
        ("Oracle, seed " + str(ep.get("seed")), outcome),
    ]
    body = "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in rows)
    src = e(card["image"])
    return (
        f"<div class='card' id='{e(card['env_id'])}'>"
        f"<img src='{src}' alt='the oracle solving {e(card['env_id'])}: top and wrist cameras'>"
        f"<h3>{e(card['env_id'])}</h3><dl>{body}</dl></div>"
    )


def write_index(
    path: str | Path,
    cards: Sequence[Mapping[str, Any]],
    phase_colors: Mapping[str, tuple[int, int, int]],
) -> None:
    """Write the page for ``cards`` to ``path`` (atomically)."""
    legend = " ".join(
        f"<span class='phase' style='background: rgb{tuple(rgb)}'>{html.escape(name)}</span>"
        for name, rgb in phase_colors.items()
    )
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for card in cards:
        groups.setdefault(card["memory_type"], []).append(card)
    sections = "".join(
        f"<h2>{html.escape(kind)} ({len(group)})</h2><div class='grid'>"
        + "".join(_card(c) for c in group)
        + "</div>"
        for kind, group in sorted(groups.items())
    )
    page = (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>MIKASA-Robo task gallery</title><style>{_STYLE}</style></head><body>"
        "<h1>MIKASA-Robo task gallery</h1>"
        f"<p>{len(cards)} tasks. Each animation is one episode of the scripted oracle: the top "
        f"camera (left) and the wrist camera (right) the policy sees, with the phase {legend}, "
        "the step and the success latch below.</p>"
        "<p id='image-status' data-loaded='0' data-total='0'>Loading animations...</p>"
        f"{sections}<script>{_CHECK_SCRIPT}</script></body></html>\n"
    )
    atomic_write_bytes(path, page.encode("utf-8"))
