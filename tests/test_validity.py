"""Chance rates (`mikasa_bench.results.chance`) and the validity table generator (`mikasa_bench.results.validity`)."""

from __future__ import annotations

import json
import math

import mikasa_envs
import numpy as np
import pytest
from mani_skill.utils.registration import REGISTERED_ENVS
from mikasa_bench.results import validity
from mikasa_bench.results.chance import task_chance
from mikasa_bench.results.leaks import LEAK_STATUSES, LEAKS
from mikasa_envs.tasks._batteries_checker import coupon_chance
from mikasa_envs.tasks._trace_shape_chance import trace_shape_guess_rate


def _cls(env_id: str) -> type:
    return REGISTERED_ENVS[env_id].cls


ALL_IDS = [t.env_id for t in mikasa_envs.list_tasks(include_extra=True)]


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_every_task_has_a_chance_rate_with_a_reason(env_id):
    c = task_chance(env_id)
    assert 0.0 <= c.rate <= 1.0 and c.reason


def test_every_family_declares_a_chance_rule():
    """The rule lives with the family (mikasa_envs.family.TaskFamily.chance)."""
    from mikasa_envs.family import get_family

    for env_id in ALL_IDS:
        assert get_family(mikasa_envs.get_task(env_id).family).chance is not None, env_id


def test_trace_shape_chance_is_the_guess_rate_the_table_gives():
    """The variants' GUESS_RATE is what the Monte Carlo gives (fewer samples here: within 4 σ)."""
    for env_id in ("TraceShapeEasy-VLA-v0", "TraceShapeHard-VLA-v0"):
        cls = _cls(env_id)
        rate = trace_shape_guess_rate(cls.SHAPE_SET, samples=4_000, seed=1, env=cls)
        expected = cls.GUESS_RATE
        assert rate == pytest.approx(expected, abs=4 * (expected * (1 - expected) / 4_000) ** 0.5)
        assert task_chance(env_id).rate == expected
    cls = _cls("TraceShapeSeqEasy-VLA-v0")
    expected = cls.GUESS_RATE
    rate = trace_shape_guess_rate(cls.SHAPE_SET, samples=2_000, seed=1, lengths=cls.SEQUENCE_LEN_RANGE,
                                  shapes_shown=True, env=cls)
    assert rate == pytest.approx(expected, abs=4 * (expected * (1 - expected) / 2_000) ** 0.5)


def test_rotate_threshold_is_the_env_default():
    import inspect

    from mikasa_envs.tasks._rotate import ANGLE_THRESHOLD, RotatePegVLABaseEnv

    default = inspect.signature(RotatePegVLABaseEnv.__init__).parameters["angle_threshold"].default
    assert default == ANGLE_THRESHOLD
    assert task_chance("RotateLenientPos-VLA-v0").rate == pytest.approx(ANGLE_THRESHOLD / math.pi)


def test_closed_form_chances():
    assert task_chance("RememberShapeAndColor5x3-VLA-v0").rate == pytest.approx(1 / 15)
    assert task_chance("BunchOfColors3-VLA-v0").rate == pytest.approx(1 / 84)
    assert task_chance("ChainOfColors5-VLA-v0").rate == pytest.approx(1 / 15120)
    assert task_chance("BlinkCountButtonPressMedium-Long-VLA-v0").rate == pytest.approx(1 / 11)
    assert task_chance("TimedTransferEasy-VLA-v0").rate == pytest.approx(11 / 108)
    assert coupon_chance(3, 3) == pytest.approx(2 / 9)
    assert coupon_chance(4, 3) == pytest.approx(0.0)
    assert coupon_chance(1, 5) == pytest.approx(1.0)


def test_take_it_back_chance_matches_a_simulation():
    rng = np.random.default_rng(0)
    n = 400_000
    x = rng.uniform(-0.05, 0.05, n)
    y = 0.1 * rng.integers(-1, 2, n) + rng.uniform(0, 0.05, n)
    guess_y = 0.1 * rng.integers(-1, 2, n) + 0.025
    simulated = np.mean(np.hypot(x, y - guess_y) < 0.08)
    rate = task_chance("TakeItBack-VLA-v0").rate
    assert rate == pytest.approx(simulated, abs=0.004)
    assert 1 / 3 < rate < 0.36


def test_leaks_list_is_well_formed():
    assert LEAKS and all(leak.status in LEAK_STATUSES and leak.tasks and leak.leak for leak in LEAKS)


# ------------------------------------------------------------------ the generator


def _write_run(run_dir, target: str, outcomes: dict[str, list[bool]], start_seed: int = 4242424242) -> None:
    """A minimal result directory as `mikasa-bench run` writes it (the keys validity reads)."""
    run_dir.mkdir(parents=True)
    for env_id, successes in outcomes.items():
        task = mikasa_envs.get_task(env_id)
        result = {
            "env_id": env_id,
            "split": task.split.title(),
            "memory_type": task.memory_type,
            "start_seed": start_seed,
            "n_episodes": len(successes),
            "successes": successes,
            "returns": [1.0] * len(successes),
            "sr": sum(successes) / len(successes),
            "model": {"name": target, "target": target, "config": {}},
            "episode_seeds": [start_seed + i for i in range(len(successes))],
        }
        (run_dir / f"{env_id}.json").write_text(json.dumps(result))
    (run_dir / "summary.json").write_text(json.dumps({"tasks": list(outcomes), "model": {"name": target}}))


def test_validity_table_from_synthetic_runs(tmp_path, capsys):
    ok, leaky = "RememberColor3-VLA-v0", "ShellGameTouch-VLA-v0"
    runs = tmp_path / "runs"
    _write_run(runs / "oracle", "oracle", {ok: [True] * 10, leaky: [True] * 9 + [False]})
    _write_run(runs / "memoryless", "oracle-memoryless", {ok: [True, False, False] * 3 + [False], leaky: [True] * 10})
    _write_run(runs / "random", "random", {ok: [False] * 10, leaky: [False] * 10})
    _write_run(runs / "zero", "zero", {ok: [False] * 10, leaky: [False] * 9 + [True]})
    # A second memoryless run: its new seeds add to the first, the repeated one is noted.
    _write_run(tmp_path / "more", "oracle-memoryless", {ok: [False, False]}, start_seed=4242424251)
    _write_run(tmp_path / "other", "my_pkg:Policy", {ok: [True]})
    out = tmp_path / "docs" / "VALIDITY.md"

    assert validity.main([str(runs), str(tmp_path / "more"), str(tmp_path / "other"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"{leaky}: oracle<95%, zero>0, memoryless>chance" in printed and "2 task(s), 1 flagged" in printed

    data = json.loads(out.with_suffix(".json").read_text())
    assert data["flagged"] == [leaky]
    rows = {r["env_id"]: r for r in data["tasks"]}
    assert [*rows] == [leaky, ok]  # manifest order
    memoryless = rows[ok]["policies"]["oracle-memoryless"]
    assert (memoryless["n"], memoryless["successes"]) == (11, 3)
    assert rows[ok]["chance"] == pytest.approx(1 / 3) and rows[ok]["flags"] == []
    lo, hi = rows[leaky]["policies"]["oracle-memoryless"]["sr_ci95"]
    assert lo > 1 / 3 and hi == pytest.approx(1.0)
    assert any("already counted" in n for n in data["notes"]) and any("my_pkg:Policy" in n for n in data["notes"])
    assert len(data["leaks"]) == len(LEAKS)

    md = out.read_text()
    assert "| Task | Chance | oracle | memoryless | random | zero | Flags |" in md
    assert f"| `{leaky}` | 33% | 90% [" in md and "**memoryless>chance**" in md
    assert "## Chance" in md and "## Leaks found" in md and "ShellGameColorLampTouch" in md
    assert math.isclose(rows[leaky]["policies"]["zero"]["sr"], 0.1)


def test_validity_rejects_bad_input(tmp_path, capsys):
    assert validity.main([str(tmp_path / "missing"), "--out", str(tmp_path / "v.md")]) == 2
    (tmp_path / "empty").mkdir()
    assert validity.main([str(tmp_path / "empty"), "--out", str(tmp_path / "v.md")]) == 2
    _write_run(tmp_path / "zero", "zero", {"RememberColor3-VLA-v0": [False]})
    bad = tmp_path / "leaks.json"
    bad.write_text(json.dumps([{"tasks": "x", "leak": "y", "evidence": "z", "status": "maybe"}]))
    assert validity.main([str(tmp_path / "zero"), "--out", str(tmp_path / "v.md"), "--leaks", str(bad)]) == 2
    assert "unknown leak status 'maybe'" in capsys.readouterr().err


def test_validity_update_keeps_the_rows_of_tasks_not_rerun(tmp_path, capsys):
    kept, rerun = "RememberColor3-VLA-v0", "ShellGameTouch-VLA-v0"
    first = tmp_path / "first"
    _write_run(first / "oracle", "oracle", {kept: [True] * 10, rerun: [True] * 10})
    _write_run(first / "memoryless", "oracle-memoryless", {kept: [False] * 10, rerun: [True] * 10})
    out = tmp_path / "docs" / "VALIDITY.md"
    assert validity.main([str(first), "--out", str(out)]) == 0
    # After a change to one task: rerun only that task, keep the other row.
    second = tmp_path / "second"
    _write_run(second / "memoryless", "oracle-memoryless", {rerun: [False] * 5})
    assert validity.main([str(second), "--out", str(out), "--update", str(out.with_suffix(".json"))]) == 0
    assert "2 task(s), 0 flagged" in capsys.readouterr().out
    data = json.loads(out.with_suffix(".json").read_text())
    rows = {r["env_id"]: r["policies"] for r in data["tasks"]}
    assert (rows[kept]["oracle"]["n"], rows[kept]["oracle-memoryless"]["successes"]) == (10, 0)
    # The rerun task's row is the new runs' alone: its old oracle cell is gone with it.
    assert [*rows[rerun]] == ["oracle-memoryless"] and rows[rerun]["oracle-memoryless"]["n"] == 5
    assert data["sources"] == [str(first), str(second)] and any("earlier table" in n for n in data["notes"])

    assert validity.main([str(second), "--out", str(out), "--update", str(tmp_path / "nope.json")]) == 2
    assert "cannot read the earlier table" in capsys.readouterr().err


def test_the_shipped_table_rewrites_from_its_json_alone(tmp_path):
    """``mikasa-bench validity --update docs/VALIDITY.json`` with no run directories rewrites
    the shipped table as it is: the same rows, opening with its headline."""
    from pathlib import Path

    shipped = Path(__file__).resolve().parents[1] / "docs" / "VALIDITY.json"
    earlier = tmp_path / "VALIDITY.json"
    earlier.write_text(shipped.read_text(encoding="utf-8"), encoding="utf-8")
    md, js, rows = validity.write_validity([], tmp_path / "VALIDITY.md", update=earlier)
    assert json.loads(js.read_text())["tasks"] == json.loads(shipped.read_text())["tasks"]
    text = md.read_text(encoding="utf-8")
    assert text.splitlines()[2].startswith("**The oracle reaches at least 95% on")
    assert len(rows) == 90
    with pytest.raises(validity.BenchError, match="give result directories"):
        validity.write_validity([], tmp_path / "x.md")
