"""Batched evaluation (`mikasa-bench run --policy-batch B`, `mikasa_bench.runners.lockstep`): which
episodes share a round, the checks of a batched policy's output, and that a deterministic
policy gets the same per-episode results in lockstep as one episode at a time (state
observations, one short task), also after a resume. The policies are loaded from this file
by path."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from mikasa_bench import cli
from mikasa_bench.cli.run import cmd_run
from mikasa_bench.errors import BenchError, PolicyOutputError
from mikasa_bench.protocol import BenchmarkConfig, protocol_settings
from mikasa_bench.runners.lockstep import scene_groups, split_action_batch

TASK = "RememberColor3-VLA-v0"
HERE = str(Path(__file__).resolve())
PER_EPISODE = ("successes", "returns", "episode_lengths", "episode_seeds")


class StatePolicy:
    """Deterministic and stateless: steers the gripper towards the first state values."""

    def forward(self, obs):
        p, s = obs["proprio"][0], obs["state"][0]
        a = torch.zeros(7)
        a[:3] = torch.tanh(4 * (s[:3] - p[:3]))
        a[6] = torch.sign(s[3])
        return a

    def forward_batch(self, observations):
        return torch.stack([self.forward(o) for o in observations])


class CountingChunkPolicy:
    """Deterministic and recurrent (a call counter cleared by reset), chunks of 2; its
    batched form keeps one counter for the batch, as a LeRobot policy keeps one queue."""

    chunk_size = 2

    def __init__(self) -> None:
        self.calls = 0

    def reset(self, seed=None) -> None:
        self.calls = 0

    def _chunk(self, obs, calls):
        p = obs["proprio"][0].numpy()
        a = np.zeros((2, 7), dtype=np.float32)
        a[:, :3] = np.clip(-p[:3], -1, 1)
        a[:, 6] = 1.0 if calls % 4 < 2 else -1.0
        return a

    def forward(self, obs):
        self.calls += 1
        return self._chunk(obs, self.calls - 1)

    def forward_batch(self, observations):
        self.calls += 1
        return np.stack([self._chunk(o, self.calls - 1) for o in observations])


class NoBatchPolicy:
    def forward(self, obs):
        return np.zeros(7, dtype=np.float32)


def _run(out: Path, policy: str, *extra: str, episodes: int = 7) -> int:
    argv = ["run", "--task", TASK, "--num-episodes", str(episodes), "--obs-mode", "state"]
    argv += ["--no-progress", "--no-report", "--policy", policy, "--out", str(out), *extra]
    return cli.main(argv)


def _episodes(out: Path) -> dict:
    r = json.loads((out / f"{TASK}.json").read_text())
    return {k: r[k] for k in PER_EPISODE}


def test_rounds_take_episode_r_of_b_consecutive_scenes():
    assert scene_groups(7, 3) == [[[0, 5], [1, 6], [2], [3], [4]]]
    assert scene_groups(12, 2) == [
        [[0, 5], [1, 6], [2, 7], [3, 8], [4, 9]],
        [[10], [11]],
    ]
    assert scene_groups(3, 1) == [[[0], [1], [2]]]
    # Every episode exactly once.
    for n, b in [(50, 10), (50, 4), (13, 3)]:
        played = sorted(e for g in scene_groups(n, b) for r in g for e in r)
        assert played == list(range(n))


def test_batched_outputs_are_checked():
    out = split_action_batch(torch.ones(3, 7), 3, (7,))
    assert [len(c) for c in out] == [1, 1, 1] and out[0][0].dtype == torch.float32
    chunks = split_action_batch(np.zeros((2, 4, 7)), 2, (7,))
    assert [len(c) for c in chunks] == [4, 4] and chunks[1][3].shape == (7,)
    for bad in (np.zeros((2, 7)), np.zeros(7), np.zeros((3, 6)), np.zeros((3, 2, 2, 7))):
        with pytest.raises(PolicyOutputError, match=r"expected \(3, 7\) or \(3, K, 7\)"):
            split_action_batch(bad, 3, (7,))


def test_policy_batch_is_a_recorded_setting():
    assert protocol_settings(BenchmarkConfig())["policy_batch"] == 1
    p = protocol_settings(BenchmarkConfig(policy_batch=4))
    assert p["policy_batch"] == 4 and "lockstep" in p["policy_reset"]
    with pytest.raises(ValueError, match="policy_batch must be >= 1"):
        BenchmarkConfig(policy_batch=0)
    with pytest.raises(ValueError, match="--video"):
        BenchmarkConfig(policy_batch=2, save_videos=True)


def test_bad_combinations_are_refused(tmp_path, capsys):
    assert _run(tmp_path / "w", f"{HERE}:StatePolicy", "--policy-batch", "2", "--workers", "2") == 2
    assert "do not pass --workers" in capsys.readouterr().err
    assert _run(tmp_path / "n", f"{HERE}:NoBatchPolicy", "--policy-batch", "2", episodes=2) == 2
    err = capsys.readouterr().err
    assert "no forward_batch" in err and "NoBatchPolicy" in err


@pytest.mark.parametrize(
    "policy, envs_per_process", [("StatePolicy", "1"), ("CountingChunkPolicy", "2")]
)
def test_lockstep_matches_one_episode_at_a_time(tmp_path, policy, envs_per_process):
    """Also with two envs per env process, stepped in threads."""
    target = f"{HERE}:{policy}"
    assert _run(tmp_path / "inline", target, "--workers", "0") == 0
    extra = ("--policy-batch", "3", "--envs-per-worker", envs_per_process)
    assert _run(tmp_path / "batch", target, *extra) == 0
    assert _episodes(tmp_path / "batch") == _episodes(tmp_path / "inline")
    run = json.loads((tmp_path / "batch" / "meta" / "run.json").read_text())
    assert run["config"]["policy_batch"] == 3 and run["protocol"]["policy_batch"] == 3
    result = json.loads((tmp_path / "batch" / f"{TASK}.json").read_text())
    assert result["policy_batch"] == 3


def test_lockstep_resume_replays_the_group_and_records_the_missing(tmp_path):
    target = f"{HERE}:CountingChunkPolicy"
    full = tmp_path / "full"
    assert _run(full, target, "--policy-batch", "2") == 0
    part = tmp_path / "part"
    assert _run(part, target, "--policy-batch", "2") == 0
    # Forget episodes 1 and 6 (rounds 1 of the group) as if the run had stopped there.
    (part / f"{TASK}.json").unlink()
    journal = part / "meta" / "episodes.jsonl"
    lines = [
        ln for ln in journal.read_text().splitlines() if json.loads(ln)["episode"] not in (1, 6)
    ]
    journal.write_text("\n".join(lines) + "\n")
    assert cli.main(["run", "--resume", str(part), "--no-progress", "--no-report"]) == 0
    assert _episodes(part) == _episodes(full)
    with pytest.raises(BenchError, match="do not pass --policy-batch"):
        cmd_run(
            cli.build_parser().parse_args(["run", "--resume", str(part), "--policy-batch", "2"])
        )
