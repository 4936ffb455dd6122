"""The shell scripts that chain PPO runs over time-limited machines: side_by_side.sh resumes each run
from its newest resume.pt and packs each call's log lines apart; merge_call.sh merges what a
call returned into the run's directory here without losing the lines already there."""

from __future__ import annotations

import subprocess
import tarfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "docs/lab-notes/rl-ppo-runs/run_scripts"

# Stands in for the trainer: says how it was called, writes a resume.pt as a run does.
FAKE_TRAINER = """#!/usr/bin/env bash
echo "trainer called with: $*"
mkdir -p checkpoints/run && echo "state after $*" > checkpoints/run/resume.pt
"""


def _call(tmp_path: Path, work: Path, archive: Path) -> None:
    trainer = tmp_path / "fake_python"
    trainer.write_text(FAKE_TRAINER)
    trainer.chmod(0o755)
    runs_file = tmp_path / "runs.txt"
    runs_file.write_text("# a comment\nalpha ppo_memtasks.py --env-id X --num-workers 16\n")
    archive.mkdir(exist_ok=True)
    subprocess.run(["bash", str(SCRIPTS / "side_by_side.sh"), "5", str(runs_file), str(work), str(archive)],
                   cwd=ROOT, env={"PATH": "/usr/bin:/bin", "PYTHON": str(trainer), "NUM_WORKERS": "64"},
                   check=True, capture_output=True)


def test_calls_resume_and_merge_without_losing_log_lines(tmp_path):
    remote, here = tmp_path / "remote", tmp_path / "here/alpha"
    here.mkdir(parents=True)
    (here / "log.txt").write_text("a line written here before\n")
    _call(tmp_path, remote, tmp_path / "out1")
    _call(tmp_path, remote, tmp_path / "out2")  # the same (warm) machine: its log holds both calls

    log = (remote / "alpha/log.txt").read_text()
    assert "--num-workers 16 --num-workers 64 --time-limit 5" in log  # NUM_WORKERS wins, the last flag
    assert "--resume ./checkpoints/run/resume.pt" in log.split("start")[-1]  # the second call resumed
    with tarfile.open(tmp_path / "out2/alpha.tgz") as packed:
        names = packed.getnames()
        call_log = packed.extractfile("./log_call.txt").read().decode()
    assert "./log.txt" not in names and call_log.count(" start") == 1 and "--resume" in call_log

    copy = tmp_path / "committed_resume.pt"
    for out in ("out1", "out2"):
        result = subprocess.run(["bash", str(SCRIPTS / "merge_call.sh"), str(tmp_path / out / "alpha.tgz"), str(here),
                                 str(copy)], check=True, capture_output=True, text=True)
    merged = (here / "log.txt").read_text()
    assert merged.startswith("a line written here before\n") and merged.count(" start") == 2
    assert merged.count("trainer called with") == 2 and not (here / "log_call.txt").exists()
    assert "newest resume.pt" in result.stdout
    assert copy.read_text() == (here / "checkpoints/run/resume.pt").read_text()
    assert "--resume" in copy.read_text()
