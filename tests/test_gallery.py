"""`mikasa-bench gallery`: animations of the oracle, task cards, and the page as a headless
browser shows it (rgb on two short tasks; the browser is the Debian ``chromium`` that
scripts/setup.sh installs)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from browser import browse, wood_share
from mikasa_bench.cli import main
from mikasa_bench.media.gallery import FrameRecorder, compose_gallery_frame
from PIL import Image, ImageSequence

TASKS = ("RememberColor3-VLA-v0", "ShellGameTouch-VLA-v0")
CARD_FIELDS = {
    "env_id",
    "family",
    "instruction",
    "memory_type",
    "split",
    "horizon",
    "description",
    "hidden",
    "phases",
    "randomizations",
    "success_condition",
    "chance",
    "episode",
    "image",
}


@pytest.fixture(scope="module")
def gallery(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("gallery")
    assert main(["gallery", str(out), *(a for t in TASKS for a in ("--task", t))]) == 0
    return out


def test_gallery_writes_cards_and_animations(gallery: Path) -> None:
    index = json.loads((gallery / "gallery.json").read_text())
    assert sorted(c["env_id"] for c in index["tasks"]) == sorted(TASKS)  # manifest order
    for card in index["tasks"]:
        assert set(card) == CARD_FIELDS
        assert card["episode"]["success"], card["env_id"]
        assert card["hidden"] and card["success_condition"] and card["instruction"]
        assert 0 < card["chance"]["rate"] < 1
        with Image.open(gallery / card["image"]) as anim:
            frames = [f.convert("RGB") for f in ImageSequence.Iterator(anim)]
        # One frame per observation: the reset one, then one per step.
        assert len(frames) == card["episode"]["steps"] + 1 == card["episode"]["frames"]
        assert frames[0].size == (256, 128 + 22)


def test_gallery_resumes_without_rendering_again(gallery: Path) -> None:
    anim = gallery / "tasks" / f"{TASKS[0]}.webp"
    before = anim.stat().st_mtime_ns
    assert main(["gallery", str(gallery), "--task", TASKS[0]]) == 0
    assert anim.stat().st_mtime_ns == before


def test_gallery_page_in_a_headless_browser(gallery: Path, tmp_path: Path) -> None:
    url = (gallery / "index.html").as_uri()
    dom = browse("--dump-dom", url)
    assert 'data-loaded="2" data-total="2"' in dom, "not every animation loaded in the browser"
    for task in TASKS:
        assert f'id="{task}"' in dom
    shot = tmp_path / "page.png"
    browse("--window-size=1200,1400", f"--screenshot={shot}", url)
    pixels = np.asarray(Image.open(shot).convert("RGB"))
    assert pixels.shape == (1400, 1200, 3)
    # The animations' wood-coloured table is on the page, not a blank one.
    assert wood_share(pixels) > 0.02


def test_gallery_unknown_task_is_a_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["gallery", str(tmp_path), "--task", "RememberColour3-VLA-v0"]) == 2
    err = capsys.readouterr().err
    assert "RememberColour3-VLA-v0" in err and "RememberColor3-VLA-v0" in err
    assert not list(tmp_path.iterdir())


class _Env:
    """Stands in for the canonical env: each observation's frame holds its step number."""

    class unwrapped:  # noqa: N801  (the attribute name gym uses)
        elapsed_steps = 0
        cue, delay = 2, 3

        @classmethod
        def phase_masks(cls, t: int):
            return np.array([t < cls.cue]), None, np.array([t >= cls.cue + cls.delay])

    def _obs(self) -> dict:
        return {"rgb": np.full((1, 4, 4, 6), self.unwrapped.elapsed_steps, dtype=np.uint8)}

    def reset(self, **kwargs):
        self.unwrapped.elapsed_steps = 0
        return self._obs(), {}

    def step(self, action):
        self.unwrapped.elapsed_steps += 1
        success = self.unwrapped.elapsed_steps >= 30
        return self._obs(), 0.0, False, False, {"success": np.array([success])}


def test_frame_recorder_thins_long_episodes_and_keeps_the_last_frame() -> None:
    rec = FrameRecorder(_Env(), max_frames=8)
    rec.reset(seed=0)
    for _ in range(36):
        rec.step(None)
    kept = rec.kept_frames()
    steps = [t for _, _, t, _ in kept]
    assert steps == [0, 8, 16, 24, 32, 36] and rec.stride == 8
    assert [int(c[0, 0, 0]) for c, _, _, _ in kept] == steps
    assert [p for _, p, _, _ in kept] == ["cue", "action", "action", "action", "action", "action"]
    assert [s for _, _, _, s in kept] == [False, False, False, False, True, True]
    frame = compose_gallery_frame(np.zeros((4, 4, 6), np.uint8), "delay", 3, 36, False, scale=2)
    assert frame.shape == (8 + 22, 16, 3) and frame.dtype == np.uint8
