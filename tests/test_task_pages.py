"""The task pages of the docs (``docs/tasks/``) are what ``scripts/gen_task_pages.py`` writes
today, name every canonical task, and show only images that exist."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType

import mikasa_envs
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "gen_task_pages.py"
TASKS_DIR = ROOT / "docs" / "tasks"
IMAGE_RE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")


@pytest.fixture(scope="module")
def generator() -> ModuleType:
    """The generator script, imported from its path (scripts/ is no package)."""
    spec = importlib.util.spec_from_file_location("gen_task_pages", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it executes
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    return module


def generated_pages() -> dict[str, str]:
    """File name -> text of every page in docs/tasks."""
    return {path.name: path.read_text(encoding="utf-8") for path in sorted(TASKS_DIR.glob("*.md"))}


def test_pages_are_up_to_date(generator: ModuleType, capsys: pytest.CaptureFixture[str]) -> None:
    status = generator.main(["--check"])
    assert status == 0, capsys.readouterr().err


def test_every_canonical_task_has_a_page() -> None:
    text = "\n".join(generated_pages().values())
    ids = mikasa_envs.canonical_env_ids()
    assert len(ids) == 90
    missing = [env_id for env_id in ids if f"`{env_id}`" not in text]
    assert not missing


def test_every_referenced_image_exists() -> None:
    references = [
        (name, target)
        for name, text in generated_pages().items()
        for target in IMAGE_RE.findall(text)
    ]
    assert references, "no page shows an animation"
    missing = [(name, t) for name, t in references if not (TASKS_DIR / t).resolve().is_file()]
    assert not missing


def test_check_names_the_pages_that_differ(generator: ModuleType, tmp_path: Path) -> None:
    pages = generator.render_pages()
    generator.write_pages(pages, tmp_path)
    assert generator.outdated(pages, tmp_path) == []
    (tmp_path / "remember_color.md").write_text("edited by hand\n", encoding="utf-8")
    (tmp_path / "old_family.md").write_text(generator.HEADER + "\n# Old\n", encoding="utf-8")
    (tmp_path / "notes.md").write_text("# Hand-written\n", encoding="utf-8")
    assert generator.outdated(pages, tmp_path) == ["remember_color.md", "old_family.md (stale)"]
    touched = generator.write_pages(pages, tmp_path)
    assert touched == ["remember_color.md", "old_family.md (removed)"]
    assert generator.outdated(pages, tmp_path) == []
    assert (tmp_path / "notes.md").is_file()  # not generated: left alone


def test_check_exits_1_naming_the_pages(
    generator: ModuleType,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    generator.write_pages(generator.render_pages(), tmp_path)
    (tmp_path / "intercept.md").unlink()
    monkeypatch.setattr(generator, "TASKS_DIR", tmp_path)
    assert generator.main(["--check"]) == 1
    assert "intercept.md" in capsys.readouterr().err
    assert not (tmp_path / "intercept.md").exists()  # --check writes nothing
    assert generator.main([]) == 0
    assert generator.main(["--check"]) == 0
