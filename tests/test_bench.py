"""Fast tests of mikasa-bench that need no simulator: protocol constants, manifest and task
selection, the episode loop on a fake env (chunk queue, success latch, reset hook, output
shapes), Wilson intervals. Result files, resume bookkeeping, report and compare are in
``test_bench_results.py``; the shared fakes in ``bench_helpers.py``."""

from __future__ import annotations

import csv
import io
import json

import mikasa_envs
import numpy as np
import pytest
import torch
from bench_helpers import (
    SPEC_SUMMARY_KEYS,
    SPEC_TASK_KEYS,
    CountingChunkPolicy,
    FakeEnv,
    _result,
    _task,
)
from mikasa_bench.errors import BenchError, PolicyOutputError, UnknownTaskError
from mikasa_bench.policies import PolicySpec, RandomPolicy, ZeroPolicy, resolve_policy
from mikasa_bench.protocol import BenchmarkConfig
from mikasa_bench.protocol.tasks import (
    MANIFEST_HEADER,
    BenchmarkTask,
    load_benchmark_tasks,
    manifest_csv_text,
    resolve_tasks,
    select_benchmark_tasks,
)
from mikasa_bench.results.metrics import (
    newcombe_difference_interval,
    summarize_task_results,
    wilson_interval,
)
from mikasa_bench.results.summary import build_summary
from mikasa_bench.runners.episode import EpisodeResult, normalize_action_chunk, run_episode
from mikasa_bench.runners.jobs import EpisodeJob
from mikasa_bench.runners.runner import evaluate_benchmark

# --------------------------------------------------------------------------------------
# protocol, manifest, selection
# --------------------------------------------------------------------------------------


def test_protocol_constants_and_seeds():
    import mikasa_bench as mb

    assert mb.START_SEED == 4242424242 and mb.NUM_EPISODES_PER_TASK == 50
    assert (mb.OBS_MODE, mb.CONTROL_MODE, mb.REWARD_MODE) == (
        "rgb",
        "pd_ee_delta_pose",
        "normalized_dense",
    )
    assert mb.WRAPPER_CHAIN == "apply_mikasa_vla_wrappers(include_overlays=False)"
    assert mb.SUPPORTED_SPLITS == ("short", "medium", "long", "all")
    seeds = BenchmarkConfig().episode_seeds()
    assert seeds[0] == 4242424242 and seeds[-1] == 4242424291 and len(seeds) == 50
    with pytest.raises(ValueError):
        BenchmarkConfig(n_episodes=0)
    with pytest.raises(ValueError):
        BenchmarkConfig(start_seed=-1)


def test_manifest_is_mikasa_envs_and_its_csv_round_trips(tmp_path):
    text = manifest_csv_text()
    header = next(csv.reader(io.StringIO(text), delimiter=";"))
    assert tuple(header) == MANIFEST_HEADER
    tasks = load_benchmark_tasks()
    assert [t.env_id for t in tasks] == [t.env_id for t in mikasa_envs.list_tasks(split="all")]
    path = tmp_path / "manifest.csv"
    path.write_text(text, encoding="utf-8")
    assert load_benchmark_tasks(path) == tasks
    assert len(tasks) == 90
    counts = {s: sum(t.split == s for t in tasks) for s in ("short", "medium", "long")}
    assert counts == {"short": 38, "medium": 30, "long": 22}
    assert [t.env_id for t in select_benchmark_tasks(split=" Short ")] == [
        t.env_id for t in tasks if t.split == "short"
    ]
    custom = select_benchmark_tasks(env_ids=["RememberColor3-VLA-v0", "Foo-v0"])
    assert custom[1] == BenchmarkTask("Foo-v0", "custom", "Unknown", 0, "", "custom")
    with pytest.raises(ValueError):
        select_benchmark_tasks()


def test_resolve_tasks_split_skips_unregistered_with_warning():
    registered = {"RememberColor3-VLA-v0", "FindImposterColor3-VLA-v0"}
    warnings: list[str] = []
    sel = resolve_tasks(split="short", registered=registered, warn=warnings.append)
    assert [t.env_id for t in sel.tasks] == ["RememberColor3-VLA-v0", "FindImposterColor3-VLA-v0"]
    assert len(sel.skipped_unregistered) == 36 and "ShellGameTouch-VLA-v0" in warnings[0]
    assert sel.to_dict()["complete_split"] is False
    with pytest.raises(UnknownTaskError, match="not registered yet"):
        resolve_tasks(split="short", registered=registered, strict=True)


def test_resolve_tasks_errors_name_what_was_expected():
    registered = {"RememberColor3-VLA-v0"}
    with pytest.raises(BenchError, match="unknown split 'tiny'.*short, medium, long, all"):
        resolve_tasks(split="tiny", registered=registered)
    with pytest.raises(UnknownTaskError, match="Did you mean: RememberColor3-VLA-v0"):
        resolve_tasks(env_ids=["RememberColour3-VLA-v0"], registered=registered)
    with pytest.raises(UnknownTaskError, match="in the manifest but not registered yet"):
        resolve_tasks(env_ids=["ShellGameTouch-VLA-v0"], registered=registered)
    with pytest.raises(BenchError, match="more than once"):
        resolve_tasks(env_ids=["RememberColor3-VLA-v0"] * 2, registered=registered)


def test_unknown_policy_and_bad_kwargs(tmp_path):
    with pytest.raises(BenchError, match="unknown policy 'foo'.*zero, random, oracle"):
        resolve_policy("foo")
    with pytest.raises(BenchError, match="does not exist"):
        resolve_policy(str(tmp_path / "missing.py"))
    with pytest.raises(BenchError, match="cannot import policy module"):
        resolve_policy("no_such_module_xyz:Policy")
    with pytest.raises(BenchError, match="does not accept"):
        resolve_policy("zero", {"colour": 1})
    f = tmp_path / "mypol.py"
    f.write_text(
        "class Agent:\n    def __init__(self, env_id, k=1):\n        self.k = k\n"
        "    def forward(self, obs):\n        return [0.0] * 7\n"
    )
    spec = resolve_policy(f"{f}:Agent", {"k": 2})
    assert spec.label == "Agent" and spec.target == f"{f.resolve()}:Agent"
    with pytest.raises(BenchError, match="has no Nope"):
        resolve_policy(f"{f}:Nope")


# --------------------------------------------------------------------------------------
# episode loop
# --------------------------------------------------------------------------------------


def test_chunk_queue_is_emptied_at_every_episode_start():
    env, policy = FakeEnv(horizon=3), CountingChunkPolicy()
    run_episode(env, policy, 7)
    run_episode(env, policy, 8)
    # Episode 1 used actions 0..2 of chunk 1; episode 2 starts with a fresh chunk (2), not
    # the leftover actions 3..4 of chunk 1.
    got = [(int(a[0, 0]), int(a[0, 1])) for a in env.actions]
    assert got == [(1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (2, 2)]
    assert policy.calls == 2 and policy.resets == 2 and env.resets == [7, 8]


def test_chunk_size_one_queries_every_step_and_success_is_a_latch():
    env = FakeEnv(horizon=4, success_step=2)
    calls = []

    class P:
        def forward(self, obs):
            calls.append(int(obs["t"][0, 0]))
            return np.zeros(7, np.float32)

    result, frames = run_episode(env, P(), 5)
    assert calls == [0, 1, 2, 3] and frames is None
    assert result == EpisodeResult(True, 2.0, 4, 5, chunk_sizes=(1,))


def test_reset_hook_receives_seed_and_random_policy_is_reproducible():
    a, b = RandomPolicy(seed=3), RandomPolicy(seed=3)
    a.reset(seed=10)
    first = a.forward(None)
    a.forward(None)
    b.reset(seed=10)
    assert np.array_equal(first, b.forward(None))
    b.reset(seed=11)
    assert not np.array_equal(first, b.forward(None))
    env = FakeEnv(horizon=2)
    seen = []

    class P(ZeroPolicy):
        def reset(self, seed):
            seen.append(seed)

    run_episode(env, P(), 42)
    assert seen == [42]


@pytest.mark.parametrize(
    "output, n",
    [
        (np.zeros(7), 1),
        (torch.zeros(3, 7), 3),
        (np.zeros((1, 4, 7), np.float64), 4),
        ([0.0] * 7, 1),
    ],
)
def test_accepted_action_shapes(output, n):
    actions = normalize_action_chunk(output, (7,))
    assert len(actions) == n and all(a.shape == (7,) and a.dtype == torch.float32 for a in actions)


@pytest.mark.parametrize("shape", [(3,), (2, 2, 7), (7, 1), (1, 7, 1)])
def test_bad_action_shape_is_a_clear_error(shape):
    with pytest.raises(PolicyOutputError, match=r"expected one action of shape \(7,\)"):
        normalize_action_chunk(np.zeros(shape), (7,))


def test_empty_chunk_and_non_numeric_output():
    with pytest.raises(PolicyOutputError, match="empty action chunk"):
        normalize_action_chunk(np.zeros((0, 7)), (7,))
    with pytest.raises(PolicyOutputError, match="expected"):
        normalize_action_chunk({"a": 1}, (7,))


def test_bad_output_through_executor_names_task_episode_and_seed():
    class Bad:
        def forward(self, obs):
            return torch.zeros(3)

    task = _task()
    config = BenchmarkConfig(n_episodes=1, start_seed=9, sim_backend="cpu")
    job = EpisodeJob(0, task, 0, 9, config, PolicySpec("zero"))
    from mikasa_bench.runners.worker import EpisodeWorker

    worker = EpisodeWorker(0)
    worker.env, worker.env_key = FakeEnv(), job.env_key
    worker.policies[job.policy.key()] = Bad()
    out = worker.run(job)
    assert out.result is None and out.user_error
    assert "RememberColor3-VLA-v0 episode 0 (seed 9)" in out.describe_failure()
    assert "expected one action of shape (7,)" in out.describe_failure()


def test_evaluate_benchmark_in_process_with_fake_env(tmp_path):
    tasks = [_task(), _task("FindImposterColor3-VLA-v0", memory="Negative")]
    config = BenchmarkConfig(n_episodes=3, start_seed=5, sim_backend="cpu")
    messages: list[str] = []
    results, summary = evaluate_benchmark(
        tasks,
        ZeroPolicy(),
        config,
        output_dir=tmp_path,
        progress=messages.append,
        env_factory=lambda env_id, cfg: FakeEnv(
            horizon=2, success_step=1 if "Find" in env_id else None
        ),
    )
    assert messages[0] == "[1/2] RememberColor3-VLA-v0  (3 episodes)"
    assert [r["sr"] for r in results] == [0.0, 1.0]
    assert list(summary)[:6] == SPEC_SUMMARY_KEYS
    assert summary["sr_per_memory_type"] == {"Negative": 1.0, "Object": 0.0}
    on_disk = json.loads((tmp_path / "RememberColor3-VLA-v0.json").read_text())
    assert list(on_disk)[:17] == SPEC_TASK_KEYS
    assert on_disk["episode_seeds"] == [5, 6, 7] and on_disk["episode_lengths"] == [2, 2, 2]
    assert (tmp_path / "summary.json").read_text().endswith("}\n")


# --------------------------------------------------------------------------------------
# metrics
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "s, n, lo, hi",
    [
        (0, 2, 0.0, 0.657620),
        (2, 2, 0.342380, 1.0),
        (5, 10, 0.236593, 0.763407),
        (0, 50, 0.0, 0.071348),
        (50, 50, 0.928652, 1.0),
        (25, 50, 0.366445, 0.633555),
        (1, 3, 0.061492, 0.792340),
    ],
)
def test_wilson_interval_values(s, n, lo, hi):
    # Expected: roots of (p_hat - p)^2 = z^2 p (1 - p) / n, solved independently (mpmath).
    got = wilson_interval(s, n)
    assert got == pytest.approx((lo, hi), abs=1e-5)


def test_wilson_edge_cases_and_newcombe():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    # Exactly 0 at 0/n and 1 at n/n (a validity flag compares the lower end with a chance of 0).
    assert wilson_interval(0, 50)[0] == 0.0 and wilson_interval(50, 50)[1] == 1.0
    with pytest.raises(ValueError):
        wilson_interval(3, 2)
    d, lo, hi = newcombe_difference_interval(10, 10, 0, 10)
    assert d == -1.0 and lo == -1.0 and hi == pytest.approx(-0.607516, abs=1e-5)
    # Newcombe (1998), Table II example: 56/70 vs 48/80 -> 0.2 (0.0524, 0.3339).
    d, lo, hi = newcombe_difference_interval(48, 80, 56, 70)
    assert (d, lo, hi) == pytest.approx((0.2, 0.0524, 0.3339), abs=1e-4)
    d, lo, hi = newcombe_difference_interval(5, 10, 5, 10)
    assert d == 0 and lo < 0 < hi


def test_summary_keys_and_quirks():
    a = _result(_task(), [True, False])
    b = _result(_task("FindImposterColor3-VLA-v0", memory="Negative"), [True, True])
    s = summarize_task_results([a, b])
    assert list(s) == SPEC_SUMMARY_KEYS
    assert s["split"] == "Short" and s["sr_split"] == 0.75
    mixed = _result(BenchmarkTask("X-v0", "custom", "Unknown", 0), [False, False])
    assert summarize_task_results([a, mixed])["split"] == "Custom"
    with pytest.raises(ValueError):
        summarize_task_results([])
    full = build_summary([a, b])
    assert full["sr_per_split"] == {"Short": 0.75}
    assert full["per_task_sr_ci95"]["FindImposterColor3-VLA-v0"] == pytest.approx(
        [0.34238, 1.0], abs=1e-5
    )
