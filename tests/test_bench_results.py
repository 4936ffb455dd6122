"""Fast tests of mikasa-bench that need no simulator: result files and resume bookkeeping
(seed order, journal, scheduler), report, compare and CLI usage errors. The shared fakes
are in ``bench_helpers.py``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_helpers import FakeEnv, _result, _store, _task, _write_run
from mikasa_bench import cli
from mikasa_bench.errors import BenchError
from mikasa_bench.results.compare import compare_runs
from mikasa_bench.results.report import REPORT_HTML, REPORT_MD, write_report
from mikasa_bench.results.run_data import load_run
from mikasa_bench.results.store import RunStore
from mikasa_bench.runners.episode import EpisodeResult
from mikasa_bench.runners.executor import InlineExecutor
from mikasa_bench.runners.runner import _jobs_for
from mikasa_bench.runners.scheduler import Scheduler

# --------------------------------------------------------------------------------------
# run store: seed order, resume bookkeeping
# --------------------------------------------------------------------------------------


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
    sched = Scheduler(jobs)
    first = sched.next_for(None)
    assert sched.next_for(first).episode == 1  # stays on the env (and scene) it has


def test_scheduler_spreads_new_workers_over_tasks(tmp_path):
    jobs = _jobs_for([_store(tmp_path, n=3)])
    sched = Scheduler(jobs)
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
    sched = Scheduler(jobs)
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
    import mikasa_bench.runners.worker as ex

    monkeypatch.setattr(
        ex, "make_benchmark_env", lambda env_id, cfg: FakeEnv(horizon=2, success_step=2)
    )
    store = _store(tmp_path, n=2)
    from mikasa_bench.runners.runner import execute_runs

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
