"""Chance rates (`mikasa_bench.chance`) and the validity table generator (`mikasa_bench.validity`)."""

from __future__ import annotations

import json
import math

import mikasa_envs
import numpy as np
import pytest
from mani_skill.utils.registration import REGISTERED_ENVS
from mikasa_bench import chance, validity
from mikasa_bench.chance import task_chance
from mikasa_bench.leaks import LEAK_STATUSES, LEAKS


def _cls(env_id: str) -> type:
    return REGISTERED_ENVS[env_id].cls


ALL_IDS = [t.env_id for t in mikasa_envs.list_tasks(include_extra=True)]


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_every_task_has_a_chance_rate_with_a_reason(env_id):
    c = task_chance(env_id)
    assert 0.0 <= c.rate <= 1.0 and c.reason


def test_chance_parameters_match_the_env_classes():
    """The constants copied into mikasa_bench.chance are the envs' own."""
    for env_id in ALL_IDS:
        family, cls = mikasa_envs.get_task(env_id).family, _cls(env_id)
        if family.startswith(("remember", "find_imposter")):
            n = getattr(cls, "SHAPES", None) if "shape" in family else cls.COLORS
            assert chance._selection_candidates(env_id) == n, env_id
        elif family in ("bunch_of_colors", "seq_of_colors", "chain_of_colors"):
            assert chance._sequence_length(env_id) == cls.SEQUENCE_LENGTH and cls.COLORS == chance.NUM_COLORS
        elif family == "blink_count_button_press":
            assert chance.BLINK_COUNT_RANGES[chance._variant(env_id, "BlinkCountButtonPress")] == cls.BLINK_COUNT_RANGE
        elif family == "timed_transfer":
            assert chance.TIMED_TRANSFER_DELAYS[chance._variant(env_id, "TimedTransfer")] == cls.DELAY_STEPS
            assert cls.WINDOW_TOLERANCE == chance.TIMED_TRANSFER_TOLERANCE
            assert cls.SIGNAL_STEP_RANGE == chance.TIMED_TRANSFER_SIGNAL_STEPS
        elif family == "take_it_back":
            assert cls.START_X == chance.TAKE_IT_BACK_START_X and cls.GOAL_RADIUS == chance.TAKE_IT_BACK_RADIUS
            assert (cls.START_Y_STEP, cls.START_Y_JITTER) == (chance.TAKE_IT_BACK_ROW_STEP, chance.TAKE_IT_BACK_ROW_JITTER)
        elif family.startswith("batteries_checker"):
            assert f"-{cls.ACTIVE_BATTERIES}-VLA" in env_id
        elif family == "trace_shape":
            assert chance.TRACE_SHAPE_SETS[chance._variant(env_id, "TraceShape")] == cls.SHAPE_SET
            assert cls.GREEN_CUBE_POSITION == chance.TRACE_SHAPE_CUBE_START
        elif family == "trace_shape_seq":
            assert chance.TRACE_SHAPE_SETS[chance._variant(env_id, "TraceShapeSeq")] == cls.SHAPE_SET
            assert chance.TRACE_SHAPE_SEQ_LENGTHS == cls.SEQUENCE_LEN_RANGE
            assert cls.GREEN_CUBE_POSITION == chance.TRACE_SHAPE_CUBE_START


def test_trace_shape_chance_is_the_guess_rate_the_table_gives():
    """The table's rates are what the Monte Carlo gives (fewer samples here: within 4 σ)."""
    for variant in ("Easy", "Hard"):
        rate = chance.trace_shape_guess_rate(chance.TRACE_SHAPE_SETS[variant], samples=4_000, seed=1)
        expected = chance.TRACE_SHAPE_GUESS_RATES[variant]
        assert rate == pytest.approx(expected, abs=4 * (expected * (1 - expected) / 4_000) ** 0.5)
    assert task_chance("TraceShapeEasy-VLA-v0").rate == chance.TRACE_SHAPE_GUESS_RATES["Easy"]
    expected = chance.TRACE_SHAPE_SEQ_GUESS_RATES["Easy"]
    rate = chance.trace_shape_guess_rate((0,), samples=2_000, seed=1, lengths=chance.TRACE_SHAPE_SEQ_LENGTHS,
                                         shapes_shown=True)
    assert rate == pytest.approx(expected, abs=4 * (expected * (1 - expected) / 2_000) ** 0.5)


def test_rotate_threshold_is_the_env_default():
    import inspect

    from mikasa_envs.tasks._rotate import RotatePegVLABaseEnv

    default = inspect.signature(RotatePegVLABaseEnv.__init__).parameters["angle_threshold"].default
    assert default == chance.ROTATE_ANGLE_THRESHOLD


def test_closed_form_chances():
    assert task_chance("RememberShapeAndColor5x3-VLA-v0").rate == pytest.approx(1 / 15)
    assert task_chance("BunchOfColors3-VLA-v0").rate == pytest.approx(1 / 84)
    assert task_chance("ChainOfColors5-VLA-v0").rate == pytest.approx(1 / 15120)
    assert task_chance("BlinkCountButtonPressMedium-Long-VLA-v0").rate == pytest.approx(1 / 11)
    assert task_chance("TimedTransferEasy-VLA-v0").rate == pytest.approx(11 / 108)
    assert chance.coupon_chance(3, 3) == pytest.approx(2 / 9)
    assert chance.coupon_chance(4, 3) == pytest.approx(0.0)
    assert chance.coupon_chance(1, 5) == pytest.approx(1.0)


def test_take_it_back_chance_matches_a_simulation():
    rng = np.random.default_rng(0)
    n = 400_000
    x = rng.uniform(-0.05, 0.05, n)
    y = 0.1 * rng.integers(-1, 2, n) + rng.uniform(0, 0.05, n)
    guess_y = 0.1 * rng.integers(-1, 2, n) + 0.025
    simulated = np.mean(np.hypot(x, y - guess_y) < 0.08)
    assert chance.take_it_back_chance() == pytest.approx(simulated, abs=0.004)
    assert 1 / 3 < chance.take_it_back_chance() < 0.36


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
