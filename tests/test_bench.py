"""Fast tests of mikasa-bench that need no simulator: protocol constants, manifest and task
selection, the episode loop on a fake env (chunk queue, success latch, reset hook, output
shapes), Wilson intervals, result files and resume bookkeeping, report and compare."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from mikasa_bench import cli
from mikasa_bench.compare import compare_runs
from mikasa_bench.episode import EpisodeResult, normalize_action_chunk, run_episode
from mikasa_bench.errors import BenchError, PolicyOutputError, UnknownTaskError
from mikasa_bench.executor import EpisodeJob, InlineExecutor, _Scheduler
from mikasa_bench.metrics import (
    newcombe_difference_interval,
    summarize_task_results,
    wilson_interval,
)
from mikasa_bench.policies import PolicySpec, RandomPolicy, ZeroPolicy, resolve_policy
from mikasa_bench.protocol import BenchmarkConfig
from mikasa_bench.report import REPORT_HTML, REPORT_MD, write_report
from mikasa_bench.results import (
    RunStore,
    build_summary,
    build_task_result,
    load_run,
    write_benchmark_results,
)
from mikasa_bench.runner import _jobs_for, evaluate_benchmark
from mikasa_bench.tasks import (
    MANIFEST_HEADER,
    BenchmarkTask,
    default_task_csv_path,
    load_benchmark_tasks,
    manifest_csv_text,
    resolve_tasks,
    select_benchmark_tasks,
)

SPEC_TASK_KEYS = [
    "env_id",
    "split",
    "memory_type",
    "start_seed",
    "n_episodes",
    "successes",
    "returns",
    "sr",
    "mean_return",
    "benchmark_commit",
    "control_mode",
    "obs_mode",
    "wrapper_chain",
    "action_chunk_size",
    "model",
    "episode_lengths",
    "episode_seeds",
]
SPEC_SUMMARY_KEYS = [
    "split",
    "sr_split",
    "sr_per_memory_type",
    "tasks",
    "per_task_sr",
    "per_task_mean_return",
]


# --------------------------------------------------------------------------------------
# fakes
# --------------------------------------------------------------------------------------


class FakeEnv(gym.Env):
    """A batched (num_envs=1) torch env: obs carries the step count; success only at
    ``success_step``; truncates after ``horizon`` steps. Records every executed action."""

    def __init__(self, horizon: int = 3, success_step: int | None = None) -> None:
        self.action_space = gym.spaces.Box(-1.0, 1.0, (7,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (1, 1), np.float32)
        self.max_episode_steps = horizon
        self.success_step = success_step
        self.device = torch.device("cpu")
        self.actions: list[torch.Tensor] = []
        self.resets: list[int] = []
        self.t = 0

    def reset(self, *, seed=None, options=None):
        self.resets.append(seed)
        self.t = 0
        return {"t": torch.zeros(1, 1)}, {}

    def step(self, action):
        assert action.shape == (1, 7) and action.dtype == torch.float32
        self.actions.append(action.clone())
        self.t += 1
        success = torch.tensor([self.t == self.success_step])
        done = torch.tensor([self.t >= self.max_episode_steps])
        return (
            {"t": torch.full((1, 1), self.t)},
            torch.tensor([0.5]),
            torch.tensor([False]),
            done,
            {"success": success},
        )


class CountingChunkPolicy:
    """Returns chunks of 5 actions whose first entry is the chunk number (1, 2, ...)."""

    chunk_size = 5

    def __init__(self) -> None:
        self.calls = 0
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def forward(self, obs):
        self.calls += 1
        chunk = torch.zeros(self.chunk_size, 7)
        chunk[:, 0] = self.calls
        chunk[:, 1] = torch.arange(self.chunk_size)
        return chunk


def _task(env_id="RememberColor3-VLA-v0", split="short", memory="Object"):
    return BenchmarkTask(env_id, split, memory, 25, "", "PPO")


def _result(task, successes, *, returns=None, lengths=None, start_seed=100, label="p"):
    n = len(successes)
    config = BenchmarkConfig(start_seed=start_seed, n_episodes=n, sim_backend="cpu")
    returns = returns or [float(i) for i in range(n)]
    lengths = lengths or [25] * n
    eps = [
        EpisodeResult(s, r, ln, start_seed + i)
        for i, (s, r, ln) in enumerate(zip(successes, returns, lengths, strict=False))
    ]
    return build_task_result(task, config, eps, model={"name": label, "config": {}})


def _write_run(path: Path, results, label="p"):
    summary = build_summary(results, model={"name": label, "config": {}})
    write_benchmark_results(path, results, summary)
    return path


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


def test_shipped_manifest_matches_mikasa_envs_and_parses():
    path = default_task_csv_path()
    assert path.name == "mikasa_robo_vla_envs.csv"
    assert path.read_text(encoding="utf-8") == manifest_csv_text()
    header = next(csv.reader(io.StringIO(path.read_text(encoding="utf-8")), delimiter=";"))
    assert tuple(header) == MANIFEST_HEADER
    tasks = load_benchmark_tasks()
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
    assert result == EpisodeResult(True, 2.0, 4, 5)


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
    import mikasa_bench.executor as ex

    worker = ex._EpisodeWorker(0)
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


# --------------------------------------------------------------------------------------
# run store: seed order, resume bookkeeping
# --------------------------------------------------------------------------------------


def _store(tmp_path, n=3, tasks=None, policy="zero"):
    tasks = tasks or [_task(), _task("FindImposterColor3-VLA-v0", memory="Negative")]
    config = BenchmarkConfig(n_episodes=n, start_seed=1000, obs_mode="state", sim_backend="cpu")
    return RunStore.create(
        tmp_path / "run",
        tasks=tasks,
        policy=PolicySpec(policy, label=policy),
        config=config,
        selection={"env_ids": [t.env_id for t in tasks]},
        commit=None,
    )


def test_out_of_order_episodes_are_reassembled_in_seed_order(tmp_path):
    store = _store(tmp_path)
    for i in (2, 0, 1):  # completion order of a parallel run
        done = store.record_episode(
            "RememberColor3-VLA-v0",
            i,
            EpisodeResult(i == 1, 10.0 + i, 20 + i, 1000 + i),
            action_chunk_size=1,
            wall_s=0.1,
        )
    assert done is not None
    r = json.loads((store.run_dir / "RememberColor3-VLA-v0.json").read_text())
    assert r["episode_seeds"] == [1000, 1001, 1002]
    assert r["returns"] == [10.0, 11.0, 12.0] and r["successes"] == [False, True, False]
    assert r["episode_lengths"] == [20, 21, 22]
    summary = json.loads((store.run_dir / "summary.json").read_text())
    assert summary["tasks"] == ["RememberColor3-VLA-v0"] and summary["complete"] is False
    assert summary["tasks_pending"] == ["FindImposterColor3-VLA-v0"]


def test_jobs_are_task_major_and_seeded(tmp_path):
    store = _store(tmp_path, n=2)
    jobs = _jobs_for([store])
    assert [(j.task.env_id[:4], j.episode, j.seed) for j in jobs] == [
        ("Reme", 0, 1000),
        ("Reme", 1, 1001),
        ("Find", 0, 1000),
        ("Find", 1, 1001),
    ]
    sched = _Scheduler(jobs)
    first = sched.next_for(None)
    assert sched.next_for(first).episode == 1  # stays on the env (and scene) it has


def test_scheduler_spreads_new_workers_over_tasks(tmp_path):
    jobs = _jobs_for([_store(tmp_path, n=3)])
    sched = _Scheduler(jobs)
    a, b = sched.next_for(None), sched.next_for(None)
    assert a.task.env_id != b.task.env_id  # two workers, two envs: not both on task 1
    rest = [sched.next_for(a)]
    rest.append(sched.next_for(rest[-1]))
    rest.append(sched.next_for(b))
    rest.append(sched.next_for(rest[-1]))
    assert all(j is not None for j in rest) and sched.next_for(rest[1]) is None
    assert sorted((j.task.env_id, j.episode) for j in [a, b, *rest]) == sorted(
        (j.task.env_id, j.episode) for j in jobs
    )


def test_scheduler_keeps_each_scene_on_one_worker_in_order(tmp_path):
    jobs = _jobs_for([_store(tmp_path, n=12)])  # 2 tasks x 12 episodes: 3 scenes each
    sched = _Scheduler(jobs)
    workers: dict[int, list] = {w: [] for w in range(5)}
    last = dict.fromkeys(workers)
    while True:
        progressed = False
        for w in workers:
            job = sched.next_for(last[w])
            if job is not None:
                workers[w].append(job)
                last[w] = job
                progressed = True
        if not progressed:
            break
    played = [(j.task.env_id, j.episode) for js in workers.values() for j in js]
    assert sorted(played) == sorted((j.task.env_id, j.episode) for j in jobs)
    for js in workers.values():
        # Every scene a worker starts, it plays whole and in order before anything else.
        runs = [js[0:1]]
        for j in js[1:]:
            (runs[-1].append(j) if j.scene_key == runs[-1][-1].scene_key else runs.append([j]))
        for run in runs:
            first = run[0].episode
            assert first % 5 == 0 and [j.episode for j in run] == list(range(first, first + len(run)))
        assert len({tuple(r[0].scene_key) for r in runs}) == len(runs)


def test_resume_from_journal_neither_loses_nor_duplicates(tmp_path):
    store = _store(tmp_path)
    store.record_episode(
        "RememberColor3-VLA-v0",
        1,
        EpisodeResult(True, 1.5, 7, 1001),
        action_chunk_size=1,
        wall_s=0.1,
    )
    # Simulate kill -9 in the middle of the next journal append.
    with open(store.journal_path, "a") as f:
        f.write('{"env_id": "RememberColor3-VLA-v0", "episode": 0, "se')
    again = RunStore.open(store.run_dir)
    assert [(t.env_id[:4], i) for t, i in again.pending()] == [
        ("Reme", 0),
        ("Reme", 2),
        ("Find", 0),
        ("Find", 1),
        ("Find", 2),
    ]
    assert again.n_done_episodes == 1
    assert store.journal_path.read_text().endswith("}\n")  # torn line cut off
    with pytest.raises(RuntimeError, match="recorded twice"):
        again.record_episode(
            "RememberColor3-VLA-v0",
            1,
            EpisodeResult(True, 1.5, 7, 1001),
            action_chunk_size=1,
            wall_s=0.1,
        )


def test_run_audit_counts_sessions_and_flags_repeats(tmp_path, capsys):
    """benchmarks/run_audit.py: a run finished over two sessions audits clean, with each
    session's episodes; a journal line written twice or torn is flagged."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "run_audit.py"
    spec = importlib.util.spec_from_file_location("run_audit", path)
    run_audit = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(run_audit)
    store = _store(tmp_path, n=2)
    store.begin_session({"name": "local", "workers": 2})
    store.record_episode(_task().env_id, 0, EpisodeResult(True, 1.0, 7, 1000), action_chunk_size=1, wall_s=0.1)
    again = RunStore.open(store.run_dir)  # as after kill -9: the second session resumes
    again.begin_session({"name": "local", "workers": 4})
    for env_id, i in [(_task().env_id, 1), ("FindImposterColor3-VLA-v0", 0), ("FindImposterColor3-VLA-v0", 1)]:
        again.record_episode(env_id, i, EpisodeResult(False, 0.0, 5, 1000 + i), action_chunk_size=1, wall_s=0.1)
    report = run_audit.audit(store.run_dir)
    assert report["ok"] and report["missing"] == 0 and report["env_steps"] == 22
    assert [(s["workers"], s["episodes"], s["env_steps"]) for s in report["sessions"]] == [(2, 1, 7), (4, 3, 15)]
    lines = store.journal_path.read_text().splitlines()
    with open(store.journal_path, "a") as f:
        f.write(lines[0] + "\n" + '{"env_id": "Rem')
    assert run_audit.main([str(store.run_dir)]) == 1
    out = capsys.readouterr().out
    assert "1 recorded twice, 1 torn journal lines" in out and "NOT OK" in out


def test_fresh_run_refuses_non_empty_dir_and_resume_checks_protocol(tmp_path):
    store = _store(tmp_path)
    with pytest.raises(BenchError, match="--resume"):
        _store(tmp_path)
    bad = _result(_task(), [True, True], start_seed=5)  # different seeds
    (store.run_dir / "RememberColor3-VLA-v0.json").write_text(json.dumps(bad))
    with pytest.raises(BenchError, match="does not match this run's protocol"):
        RunStore.open(store.run_dir)
    with pytest.raises(BenchError, match="meta/run.json"):
        RunStore.open(tmp_path)


def test_inline_executor_runs_jobs_in_order(tmp_path, monkeypatch):
    import mikasa_bench.executor as ex

    monkeypatch.setattr(
        ex, "make_benchmark_env", lambda env_id, cfg: FakeEnv(horizon=2, success_step=2)
    )
    store = _store(tmp_path, n=2)
    from mikasa_bench.runner import execute_runs

    summaries = execute_runs([store], InlineExecutor(), progress=False)
    assert summaries[0]["complete"] and summaries[0]["sr_split"] == 1.0
    lines = store.journal_path.read_text().splitlines()
    assert [(json.loads(x)["env_id"][:4], json.loads(x)["episode"]) for x in lines] == [
        ("Reme", 0),
        ("Reme", 1),
        ("Find", 0),
        ("Find", 1),
    ]


# --------------------------------------------------------------------------------------
# report, compare, CLI errors
# --------------------------------------------------------------------------------------


def test_report_files_written(tmp_path):
    run = _write_run(
        tmp_path / "a",
        [
            _result(_task(), [True, False, True], lengths=[25, 20, 22]),
            _result(_task("RememberColor3-Long-VLA-v0", "medium"), [False, False, True]),
        ],
    )
    assert cli.main(["report", str(run)]) == 0
    md, html = (run / REPORT_MD).read_text(), (run / REPORT_HTML).read_text()
    assert "RememberColor3-Long-VLA-v0" in md and "| Split: Medium |" in md
    for name in ("success_by_group.png", "per_task_success.png", "episode_lengths.png"):
        assert f"report_assets/{name}" in md
        assert (run / "report_assets" / name).read_bytes()[:4] == b"\x89PNG"
    assert html.count("src='data:image/png;base64,") == 3 and "report_assets" not in html
    # Two runs side by side.
    other = _write_run(tmp_path / "b", [_result(_task(), [False, False, False])], label="q")
    md_path, _ = write_report([load_run(run), load_run(other)], tmp_path / "both")
    assert "| RememberColor3-VLA-v0 | Short | Object | q |" in md_path.read_text()


def test_report_and_compare_reject_unreadable_dirs(tmp_path, capsys):
    assert cli.main(["report", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cli.main(["compare", str(tmp_path / "empty"), str(tmp_path / "empty")]) == 2
    assert "no per-task result files" in capsys.readouterr().err
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "X.json").write_text("{not json")
    assert cli.main(["report", str(tmp_path / "broken")]) == 2
    assert "X.json is not valid JSON" in capsys.readouterr().err


def test_compare_exit_code(tmp_path, capsys):
    good = _write_run(
        tmp_path / "good",
        [
            _result(_task(), [True] * 10),
            _result(_task("FindImposterColor3-VLA-v0"), [True] * 5 + [False] * 5),
        ],
    )
    bad = _write_run(
        tmp_path / "bad",
        [
            _result(_task(), [False] * 10),
            _result(_task("FindImposterColor3-VLA-v0"), [True] * 4 + [False] * 6),
        ],
    )
    assert cli.main(["compare", str(good), str(bad)]) == 1
    out = capsys.readouterr().out
    assert "significantly worse than A on 1 task(s): RememberColor3-VLA-v0" in out
    assert "-100 pp" in out
    assert cli.main(["compare", str(bad), str(good)]) == 0
    assert cli.main(["compare", str(good), str(good)]) == 0
    comp = compare_runs(load_run(good), load_run(bad))
    assert [d.verdict for d in comp.deltas] == ["worse", "n.s."]


def test_reference_results_ship_and_compare(tmp_path, capsys):
    """The shipped canonical result sets load by name, compare against a run, and are
    never written into: a report of one needs --out."""
    ref = load_run("reference:oracle")
    assert ref.source == "reference:oracle" and ref.label == "oracle"
    assert len(ref.results) == 90 and ref.protocol["canonical"] is True
    assert ref.protocol["obs_mode"] == "rgb" and ref.summary["n_episodes_total"] == 4500
    mine = _write_run(tmp_path / "mine", [_result(_task(), [False] * 50)])
    assert cli.main(["compare", "reference:oracle", str(mine)]) == 1
    assert "significantly worse than A on 1 task(s): RememberColor3-VLA-v0" in capsys.readouterr().out
    assert cli.main(["compare", "reference:nope", str(mine)]) == 2
    assert "accepted: reference:oracle, reference:zero" in capsys.readouterr().err
    assert cli.main(["report", "reference:oracle"]) == 2
    assert "give --out DIR" in capsys.readouterr().err
    assert cli.main(["report", "reference:oracle", str(mine), "--out", str(tmp_path / "r")]) == 0
    assert "| results | reference:oracle |" in (tmp_path / "r" / REPORT_MD).read_text()
    assert cli.main(["validity", "reference:oracle", "--out", str(tmp_path / "v.md")]) == 0
    assert "RememberColor3-VLA-v0" in (tmp_path / "v.md").read_text()
    zero = load_run("reference:zero")
    assert zero.summary["complete"] and zero.summary["n_episodes_total"] == 4500
    assert [r["env_id"] for r in zero.results] == [r["env_id"] for r in ref.results]
    assert zero.protocol == ref.protocol
    assert not any(any(r["successes"]) for r in zero.results)


def test_cli_usage_errors(tmp_path, capsys):
    assert cli.main(["run", "--split", "tiny", "--policy", "zero"]) == 2
    assert "unknown split 'tiny'" in capsys.readouterr().err
    assert cli.main(["run", "--task", "NoSuchTask-VLA-v0", "--policy", "zero"]) == 2
    assert "not in the MIKASA-Robo-VLA manifest" in capsys.readouterr().err
    assert cli.main(["run", "--task", "RememberColor3-VLA-v0", "--policy", "nope"]) == 2
    assert "unknown policy 'nope'" in capsys.readouterr().err
    assert cli.main(["run", "--task", "RememberColor3-VLA-v0"]) == 2
    assert "choose a policy" in capsys.readouterr().err
    assert cli.main(["run", "--resume", str(tmp_path), "--policy", "zero"]) == 2
    assert "do not pass --policy" in capsys.readouterr().err
    assert cli.main(["run", "--resume", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    # A bad executor option is refused before anything is written.
    out = tmp_path / "never"
    argv = ["run", "--task", "RememberColor3-VLA-v0", "--policy", "zero", "--out", str(out)]
    assert cli.main([*argv, "--envs-per-worker", "0"]) == 2
    assert "--envs-per-worker must be >= 1" in capsys.readouterr().err
    assert cli.main([*argv, "--workers", "0", "--envs-per-worker", "2"]) == 2
    assert "only used by the local executor" in capsys.readouterr().err
    assert not out.exists()
