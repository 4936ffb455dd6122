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


@pytest.mark.slow
@pytest.mark.parametrize("env_id", REGISTERED_IDS)
def test_oracle_success_rate_50_seeds(make_env, env_id):
    env = make_env(env_id)
    seeds = range(BENCH_SEED, BENCH_SEED + 50)
    assert _success_count(env, make_oracle(env), seeds) >= 48  # ≥ 95 %
    assert _success_count(env, ZeroActions(7), seeds, stop_on_success=False) == 0
