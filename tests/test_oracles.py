"""The scripted oracles solve every task; a zero-action policy solves none."""

from __future__ import annotations

import pytest
from conftest import CANONICAL_IDS, LONG_IDS, REGISTERED_IDS, SHORT_IDS
from mikasa_oracles import ZeroActions, make_oracle, rollout
from mikasa_wrappers import apply_mikasa_vla_wrappers

BENCH_SEED = 4242424242


def _success_count(env, policy, seeds, stop_on_success=True) -> int:
    return sum(rollout(env, policy, s, stop_on_success).success_once for s in seeds)


# Extra variants (non-canonical; BatteriesChecker-9/12/15 run for thousands of steps) are
# rolled out only in the slow run.
EXTRA_IDS = [i for i in REGISTERED_IDS if i not in CANONICAL_IDS]


def _param_ids(ids: list[str]) -> list:
    return [pytest.param(i, marks=pytest.mark.slow) if i in EXTRA_IDS else i for i in ids]


@pytest.mark.parametrize("env_id", _param_ids(REGISTERED_IDS))
def test_oracle_solves_first_seeds(make_env, env_id):
    env = make_env(env_id)
    n = 3 if env_id in SHORT_IDS else 2
    assert _success_count(env, make_oracle(env), range(BENCH_SEED, BENCH_SEED + n)) == n


@pytest.mark.parametrize("env_id", _param_ids(SHORT_IDS))
def test_zero_actions_never_succeed_short(make_env, env_id):
    env = make_env(env_id)
    assert _success_count(env, ZeroActions(7), range(BENCH_SEED, BENCH_SEED + 3)) == 0


@pytest.mark.parametrize("env_id", _param_ids(LONG_IDS))
def test_zero_actions_never_succeed_long(make_env, env_id):
    env = make_env(env_id)
    assert _success_count(env, ZeroActions(7), [BENCH_SEED]) == 0


def test_oracle_unchanged_in_rgb_through_canonical_wrappers(make_env):
    env = apply_mikasa_vla_wrappers(make_env("FindImposterShape5-VLA-v0", obs_mode="rgb"))
    assert _success_count(env, make_oracle(env), [BENCH_SEED]) == 1


def test_oracle_learns_answer_from_the_cue(make_env):
    """Changing the env's answer after the cue does not change where the oracle goes."""
    env = make_env("RememberColor5-VLA-v0")
    base = env.unwrapped
    oracle = make_oracle(env)
    obs, _ = env.reset(seed=BENCH_SEED)
    oracle.reset()
    shown = int(base.answer_index[0])
    for t in range(25):
        if t == int(base.cue_steps_per_env[0]):
            base.answer_index[0] = (shown + 1) % base.num_objects
            base.oracle_info = base.answer_index.to(base.oracle_info.dtype)
        obs, _, _, _, info = env.step(oracle.forward(obs))
    tcp = base.agent.tcp.pose.p[0]
    assert (tcp - base.object_positions()[0, shown]).norm() < 0.05
    assert not bool(info["success"][0])


def test_no_oracle_for_unknown_family(make_env, monkeypatch):
    import dataclasses

    import mikasa_envs.manifest as manifest

    env = make_env("RememberColor3-VLA-v0")
    real_get_task = manifest.get_task
    # Present the task as one of a family that has no oracle.
    monkeypatch.setattr(
        manifest, "get_task", lambda env_id: dataclasses.replace(real_get_task(env_id), family="family_without_oracle")
    )
    with pytest.raises(ValueError, match=r"no oracle for 'RememberColor3-VLA-v0' \(family 'family_without_oracle'\)"):
        make_oracle(env)


# --------------------------------------------------------------------------- the registry
class _OutsideOracle:
    """An oracle class defined outside mikasa_oracles (never rolled out here)."""

    def __init__(self, env, **kwargs):
        self.env = env


def test_second_oracle_for_a_family_is_rejected():
    from mikasa_oracles import ORACLES, DuplicateOracleError, register_oracle

    existing = ORACLES["remember_color"]
    with pytest.raises(
        DuplicateOracleError,
        match=r"family 'remember_color' already has the oracle "
        r"mikasa_oracles\.families\.selection\.SelectionOracle; cannot register "
        r"test_oracles\._OutsideOracle",
    ):
        register_oracle("family_from_a_test", "remember_color")(_OutsideOracle)
    # Nothing changed, not even the family that had no oracle yet.
    assert ORACLES["remember_color"] is existing and "family_from_a_test" not in ORACLES
    register_oracle("remember_color")(existing)  # the same class again: a no-op


def test_unknown_family_names_the_known_ones():
    from mikasa_oracles import MEMORYLESS_ORACLES, ORACLES, UnknownFamilyError, oracle_class

    for memoryless, table, kind in ((False, ORACLES, "oracle"), (True, MEMORYLESS_ORACLES, "memoryless oracle")):
        with pytest.raises(UnknownFamilyError, match=f"no {kind} for family 'no_such_family'; they exist for: ") as err:
            oracle_class("no_such_family", memoryless)
        assert str(err.value).endswith(", ".join(sorted(table))) and "remember_color" in table


def test_oracle_registered_outside_the_package_is_found(make_env, monkeypatch):
    """A module outside mikasa_oracles (this one) registers an oracle for a manifest family;
    make_oracle (the bench), has_oracle and mikasa-collect's task check find it."""
    import mikasa_oracles
    from mikasa_oracles import has_oracle, oracle_class, register_oracle
    from mikasa_oracles.collect import resolve_task

    # Take the family's built-in oracle out for this test (put back afterwards).
    monkeypatch.delitem(mikasa_oracles.ORACLES, "shell_game_touch")
    assert not has_oracle("ShellGameTouch-VLA-v0")
    register_oracle("shell_game_touch")(_OutsideOracle)
    assert has_oracle("ShellGameTouch-VLA-v0") and oracle_class("shell_game_touch") is _OutsideOracle
    assert resolve_task("ShellGameTouch-VLA-v0").family == "shell_game_touch"
    assert isinstance(make_oracle(make_env("ShellGameTouch-VLA-v0")), _OutsideOracle)


def test_entry_point_registers_an_oracle_in_a_fresh_process(tmp_path):
    """An installed distribution's entry point (group mikasa_oracles.families) is imported
    by ``import mikasa_oracles``: worker processes find its oracle too."""
    import os
    import subprocess
    import sys

    (tmp_path / "outside_oracles.py").write_text(
        "from mikasa_oracles import register_oracle\n"
        "from mikasa_oracles.scripted import ScriptedOracle\n\n\n"
        "@register_oracle('family_from_a_plugin')\n"
        "class PluginOracle(ScriptedOracle):\n"
        "    pass\n"
    )
    dist_info = tmp_path / "outside_oracles-0.1.dist-info"
    dist_info.mkdir()
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: outside-oracles\nVersion: 0.1\n")
    (dist_info / "entry_points.txt").write_text("[mikasa_oracles.families]\noutside = outside_oracles\n")
    code = "import mikasa_oracles; print(mikasa_oracles.oracle_class('family_from_a_plugin').__name__)"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "PluginOracle"


@pytest.mark.slow
@pytest.mark.parametrize("env_id", REGISTERED_IDS)
def test_oracle_success_rate_50_seeds(make_env, env_id):
    env = make_env(env_id)
    seeds = range(BENCH_SEED, BENCH_SEED + 50)
    assert _success_count(env, make_oracle(env), seeds) >= 48  # ≥ 95 %
    assert _success_count(env, ZeroActions(7), seeds, stop_on_success=False) == 0
