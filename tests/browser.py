"""Debian's headless Chromium, for the tests that open a page as a browser shows it
(``scripts/setup.sh`` installs it; elsewhere ``apt install chromium``)."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np


def browser() -> str:
    """The path of a headless-capable Chromium."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    raise AssertionError("no headless browser: install Debian's chromium (scripts/setup.sh does)")


def browse(*args: str) -> str:
    """Run the browser headless with ``args`` (e.g. ``--dump-dom URL``); its stdout."""
    cmd = [browser(), "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True).stdout


def wood_share(pixels: np.ndarray) -> float:
    """The share of an RGB screenshot's pixels in the wood colour of the tasks' table (an
    animation of a task is on the page, not a blank box)."""
    wood = (
        (pixels[..., 0] > 150)
        & (pixels[..., 1] > 60)
        & (pixels[..., 1] < 140)
        & (pixels[..., 2] < 90)
    )
    return float(wood.mean())
