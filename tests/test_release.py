"""The release: versions agree everywhere, and the wheels install and run on their own.

The end-to-end test builds the wheels of mikasa-envs, mikasa-wrappers and mikasa-bench with
``scripts/build_release.sh``, installs those three alone into an empty venv (none of the
packages is on PyPI: pip sees only these files) and runs a short benchmark from a folder
outside the repository with PYTHONPATH unset, so whatever the run needs must be inside the
wheels. mikasa-oracles is the bench's ``oracles`` extra: without it the oracle policies
name the command that installs it.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import venv
import zipfile
from importlib import metadata
from pathlib import Path

import pytest
import tomllib
from mikasa_bench.cli import main as bench_main
from mikasa_bench.errors import BenchError
from mikasa_bench.policies.loading import check_policy_supports, resolve_policy
from mikasa_bench.policies.spec import PolicySpec

REPO = Path(__file__).resolve().parents[1]
BUILD_RELEASE = REPO / "scripts" / "build_release.sh"
INSTALL_ORACLES = "pip install 'mikasa-bench[oracles]'"
TASK = "RememberColor3-VLA-v0"

# Distribution -> (source folder, import package).
PACKAGES = {
    "mikasa-envs": ("packages/mikasa-envs", "mikasa_envs"),
    "mikasa-wrappers": ("packages/mikasa-wrappers", "mikasa_wrappers"),
    "mikasa-oracles": ("packages/mikasa-oracles", "mikasa_oracles"),
    "mikasa-datasets": ("packages/mikasa-datasets", "mikasa_datasets"),
    "mikasa-bench": ("packages/mikasa-bench", "mikasa_bench"),
    "mikasa-robo-rl": ("legacy/rl", "mikasa_robo_rl"),
}
PIN = re.compile(r"^(mikasa-[a-z-]+)\s*(.*)$")


def _project(folder: str) -> dict:
    return tomllib.loads((REPO / folder / "pyproject.toml").read_text())["project"]


@pytest.mark.parametrize("dist", sorted(PACKAGES))
def test_version_agrees_with_init_changelog_and_install(dist):
    folder, package = PACKAGES[dist]
    version = _project(folder)["version"]
    init = (REPO / folder / "src" / package / "__init__.py").read_text()
    assert re.search(rf'^__version__ = "{re.escape(version)}"$', init, re.M), package
    changelog = (REPO / folder / "CHANGELOG.md").read_text()
    assert re.search(rf"^## \[{re.escape(version)}\] - \d{{4}}-\d{{2}}-\d{{2}}$", changelog, re.M)
    # The editable install's metadata is the pyproject's (else: reinstall requirements/dev.txt).
    assert metadata.version(dist) == version


@pytest.mark.parametrize("dist", sorted(PACKAGES))
def test_pins_on_our_packages_allow_exactly_their_minor_release(dist):
    project = _project(PACKAGES[dist][0])
    requirements = list(project.get("dependencies", []))
    for extra in project.get("optional-dependencies", {}).values():
        requirements += extra
    for requirement in requirements:
        match = PIN.match(requirement)
        if not match:
            continue
        major, minor, _ = _project(PACKAGES[match[1]][0])["version"].split(".")
        assert match[2] == f">={major}.{minor},<{major}.{int(minor) + 1}", requirement


def test_without_mikasa_oracles_the_oracle_features_name_the_extra(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "mikasa_oracles", None)  # import raises ModuleNotFoundError
    for name in ("oracle", "oracle-memoryless"):
        with pytest.raises(BenchError, match=re.escape(INSTALL_ORACLES)):
            resolve_policy(name)
    with pytest.raises(BenchError, match=re.escape(INSTALL_ORACLES)):
        check_policy_supports(PolicySpec("oracle", {}, "oracle"), [TASK])
    assert resolve_policy("zero").target == "zero"

    assert bench_main(["list", "--registered-only"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith(TASK + " "))
    assert row.split()[-1] == "n/a" and INSTALL_ORACLES in out


def _wheel(dist_dir: Path, dist: str) -> Path:
    (wheel,) = (dist_dir / dist).glob("*.whl")
    return wheel


def _tracked_package_files(dist: str) -> set[str]:
    """The files of ``dist``'s import package in git, as wheel paths (``mikasa_bench/...``)."""
    folder, package = PACKAGES[dist]
    src = f"{folder}/src/"
    listed = subprocess.run(
        ["git", "ls-files", f"{src}{package}"], cwd=REPO, check=True, capture_output=True, text=True
    ).stdout.split()
    return {path[len(src) :] for path in listed}


def test_wheels_install_alone_and_run_the_bench(tmp_path):
    ours = ["mikasa-envs", "mikasa-wrappers", "mikasa-bench"]
    dist_dir = tmp_path / "dist"
    built = subprocess.run(
        ["bash", str(BUILD_RELEASE), "--out", str(dist_dir), *ours],
        env={**os.environ, "PYTHON": sys.executable},
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    assert "twine check passed" in built
    for dist in ours:
        # Every file of the package (the reference result sets included) is in its wheel.
        names = set(zipfile.ZipFile(_wheel(dist_dir, dist)).namelist())
        missing = _tracked_package_files(dist) - names
        assert not missing, f"{dist} wheel lacks {sorted(missing)[:5]}"
    assert any(n.startswith("mikasa_bench/reference/zero/") for n in names)

    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=True)
    python = env_dir / "bin" / "python"
    # torch==2.13.0: the CPU wheel this machine keeps locally (see README, dependency pins).
    wheels = [str(_wheel(dist_dir, dist)) for dist in ours]
    subprocess.run([python, "-m", "pip", "install", "-q", "torch==2.13.0", *wheels], check=True)
    listed = subprocess.run(
        [python, "-m", "pip", "list"], check=True, capture_output=True, text=True
    ).stdout
    installed = sorted(line.split()[0] for line in listed.splitlines() if line.startswith("mikasa"))
    assert installed == sorted(ours)

    # Outside the repository: nothing of it on the path.
    work = tmp_path / "work"
    work.mkdir()
    clean_env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    bench = str(env_dir / "bin" / "mikasa-bench")

    def run(*args: str, check: bool = True) -> subprocess.CompletedProcess:
        return subprocess.run(
            args, cwd=work, env=clean_env, check=check, capture_output=True, text=True, timeout=600
        )

    location = run(str(python), "-c", "import mikasa_bench; print(mikasa_bench.__file__)").stdout
    assert Path(location.strip()).is_relative_to(env_dir)

    run(bench, "run", "--task", TASK, "--policy", "zero", "--num-episodes", "2",
        "--obs-mode", "state", "--workers", "1", "--out", "run", "--no-progress")  # fmt: skip
    result = json.loads((work / "run" / f"{TASK}.json").read_text())
    assert result["env_id"] == TASK and result["n_episodes"] == 2 and result["sr"] == 0.0
    summary = json.loads((work / "run" / "summary.json").read_text())
    versions = summary["versions"]
    assert versions["mikasa-bench"] == _project("packages/mikasa-bench")["version"]
    assert versions["mikasa-oracles"] is None

    # The shipped reference results come with the wheel.
    assert "RememberColor3-VLA-v0" in run(bench, "compare", "reference:zero", "run").stdout

    # No oracles installed: the column says so, the oracle policy names the extra.
    listing = run(bench, "list").stdout
    assert f"Oracle n/a: mikasa-oracles is not installed ({INSTALL_ORACLES})" in listing
    refused = run(bench, "run", "--task", TASK, "--policy", "oracle", "--out", "o", check=False)
    assert refused.returncode == 2 and INSTALL_ORACLES in refused.stderr
