"""The documentation site: ``mkdocs build --strict`` (no broken link, no missing page) from
the repository root, and its pages as headless Chromium shows them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import mikasa_envs
import numpy as np
import pytest
from browser import browse, wood_share
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
MKDOCS = Path(sys.executable).parent / "mkdocs"


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [str(MKDOCS), "build", "--strict", "--site-dir", str(out)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-5000:]
    return out


def test_every_canonical_task_is_on_a_task_page(site: Path) -> None:
    pages = "".join(p.read_text(encoding="utf-8") for p in (site / "tasks").rglob("index.html"))
    missing = [env_id for env_id in mikasa_envs.canonical_env_ids() if env_id not in pages]
    assert not missing, f"task ids on no page of the site: {missing}"


def test_home_page_in_a_headless_browser(site: Path) -> None:
    dom = browse("--dump-dom", (site / "index.html").as_uri())
    assert "A benchmark of memory-intensive robot manipulation" in dom
    for section in ("Getting started", "Tasks", "Evaluate a policy", "Results", "Contributing"):
        assert section in dom, section


def test_task_page_shows_its_animation(site: Path, tmp_path: Path) -> None:
    page = site / "tasks" / "remember_color" / "index.html"
    dom = browse("--dump-dom", page.as_uri())
    assert "RememberColor3-VLA-v0" in dom and ".webp" in dom
    shot = tmp_path / "page.png"
    browse("--window-size=1200,4000", f"--screenshot={shot}", page.as_uri())
    pixels = np.asarray(Image.open(shot).convert("RGB"))
    assert wood_share(pixels) > 0.002, "the task's animation did not load"
