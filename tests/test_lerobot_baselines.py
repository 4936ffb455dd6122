"""The LeRobot baseline driver (baselines/lerobot/run_baselines.py).

The end-to-end test needs lerobot 0.4.x next to the MIKASA envs: in the main environment
this file contributes one test that runs it inside `.venv-datasets` (tests/test_validate.py's
mechanism, as tests/test_lerobot_policy.py does), plus checks of the driver's pure parts
(settings, flags, the table) that need neither lerobot nor the simulator.

Inside `.venv-datasets`, at tiny scale on one task (RememberColor3-VLA-v0, 3 oracle
episodes, a 1+1-layer ACT of width 64 for 6 steps on the CPU, 2 evaluation episodes):
collect -> convert -> oracle evaluation; a training call (checkpoint every 2 steps) that the
driver terminates once a checkpoint 2 steps in is saved (exit 3; steps after that checkpoint
are lost); the next call resumes it from that checkpoint with lerobot's --resume, finishes
and evaluates; a last call finds everything done and only rewrites the table.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# The driver's directory, as `python baselines/lerobot/run_baselines.py` has it on sys.path.
sys.path.insert(0, str(REPO / "baselines" / "lerobot"))

import baseline_settings as bs  # noqa: E402
import baseline_stages as bst  # noqa: E402
import baseline_table as bt  # noqa: E402
import run_baselines as rb  # noqa: E402
from baseline_stages import Driver  # noqa: E402

IN_LEROBOT_ENV = all(
    importlib.util.find_spec(m) is not None for m in ("lerobot", "mikasa_bench", "mani_skill")
)
TASK = "RememberColor3-VLA-v0"


# ----------------------------------------------------------------------- pure parts (both)
def test_settings_memoryless_and_history() -> None:
    """Memoryless settings see one frame and re-plan every step; the history setting's
    horizon fits its window and the U-Net's down-sampling."""
    settings = bs.make_settings(history=8)
    assert set(bs.DEFAULT_SETTINGS) <= set(settings)
    for name in ("act", "diffusion"):
        s = settings[name]
        assert s.memoryless
        assert s.args["policy.n_obs_steps"] == "1" and s.args["policy.n_action_steps"] == "1"
        assert s.args["policy.pretrained_backbone_weights"] == "null"
    hist = settings["diffusion-hist"]
    assert not hist.memoryless and hist.args["policy.n_obs_steps"] == "8"
    horizon = int(hist.args["policy.horizon"])
    assert horizon % 8 == 0 and horizon >= 8 - 1 + 8
    assert (
        settings["act-chunk"].args["policy.n_action_steps"]
        == settings["act"].args["policy.chunk_size"]
    )
    assert bs.horizon(12, 8, 8) == 24 and bs.horizon(1, 8, 8) == 8


def test_train_args_overrides(tmp_path: Path) -> None:
    """--train-arg applies to every setting or, with SETTING:, to one; values may hold ':'."""
    args = rb.build_parser().parse_args(
        [
            "--out", str(tmp_path), "--device", "cpu", "--scale", "tiny",
            "--train-arg", "policy.optimizer_lr=3e-4",
            "--train-arg", "diffusion:batch_size=64",
            "--train-arg", "act:policy.device=cuda:1",
        ]
    )  # fmt: skip
    d = Driver(args)
    act = d.train_args(TASK, d.settings["act"])
    diff = d.train_args(TASK, d.settings["diffusion"])
    assert act["policy.optimizer_lr"] == diff["policy.optimizer_lr"] == "3e-4"
    assert diff["batch_size"] == "64" and act["batch_size"] == "32"
    assert act["policy.device"] == "cuda:1" and diff["policy.device"] == "cpu"
    assert act["policy.dim_model"] == "64"  # tiny scale
    assert act["dataset.repo_id"] == "remember_color_3_vla_v0"
    assert act["policy.push_to_hub"] == "false" and act["wandb.enable"] == "false"


def test_eval_spread(tmp_path: Path) -> None:
    """Learned policies on a GPU evaluate in lockstep batches (--eval-batch; 1: in the
    bench's own process) unless --eval-workers says otherwise; references and CPU policies
    use --workers."""

    def driver(*extra: str, device: str) -> Driver:
        args = rb.build_parser().parse_args(
            ["--out", str(tmp_path), "--workers", "6", "--device", device, *extra]
        )
        return Driver(args)

    on_gpu, on_cpu = driver(device="cuda"), driver(device="cpu")
    act = on_gpu.settings["act"]
    assert on_gpu.eval_exec(act) == ["--policy-batch", "10"]
    assert on_gpu.eval_exec(None) == ["--workers", "6"]
    assert on_cpu.eval_exec(act) == on_cpu.eval_exec(None) == ["--workers", "6"]
    assert driver("--eval-batch", "1", device="cuda").eval_exec(act) == ["--workers", "0"]
    spread = driver("--eval-envs-per-worker", "2", device="cuda")
    assert spread.eval_exec(act) == ["--policy-batch", "10", "--envs-per-worker", "2"]
    assert spread.eval_exec(None) == ["--workers", "6"]
    given = driver("--eval-workers", "2", device="cuda")
    assert given.eval_exec(act) == given.eval_exec(None) == ["--workers", "2"]


def test_records_restored_from_the_table(tmp_path: Path) -> None:
    """Finished records the table JSON holds and <out>/records lacks are written; records
    already there, unfinished ones and malformed names are left alone."""
    d = Driver(rb.build_parser().parse_args(["--out", str(tmp_path / "out")]))
    kept = {"status": "done", "unit": "collect", "task": TASK, "episodes": 7}
    d.record_path(TASK, "collect").parent.mkdir(parents=True)
    d.record_path(TASK, "collect").write_text(json.dumps(kept))
    records = [
        {"status": "done", "unit": "collect", "task": TASK, "episodes": 200},
        {"status": "done", "unit": "eval-act", "task": TASK, "successes": 3},
        {"status": "running", "unit": "train-act", "task": TASK},
        {"status": "done", "unit": "../x", "task": TASK},
    ]
    table = tmp_path / "BASELINES.json"
    table.write_text(json.dumps({"records": records}))
    assert bt.restore_records(d, table) == 1
    assert d.record(TASK, "eval-act") == records[1]
    assert json.loads(d.record_path(TASK, "collect").read_text()) == kept
    assert d.record(TASK, "train-act") is None
    assert bt.restore_records(d, tmp_path / "missing.json") == 0


def test_eval_spread_from_the_command() -> None:
    """The runs table says how each evaluation ran, from its recorded command."""
    assert bt._eval_spread({"command": "mikasa-bench run --policy-batch 10 --x"}) == "lockstep 10"
    batched = {"command": "run --policy-batch 10 --envs-per-worker 2"}
    assert bt._eval_spread(batched) == "lockstep 10, 2 envs/process"
    alone = {"command": "run --policy-batch 10 --envs-per-worker 1"}
    assert bt._eval_spread(alone) == "lockstep 10, 1 env/process"
    assert bt._eval_spread({"command": "run --workers 0 --no-report"}) == "in-process"
    assert bt._eval_spread({"command": "run --workers 5"}) == "5 workers"
    assert bt._eval_spread({}) == "?"


def test_vs_chance() -> None:
    """The verdict compares chance with the record's (mikasa-bench's Wilson) interval."""
    rec = {"status": "done", "sr_ci95": [0.05, 0.3]}
    assert bt._vs_chance(rec, 1 / 3) == "below"
    assert bt._vs_chance(rec, 0.1) == "at chance"
    assert bt._vs_chance(rec, 0.0) == "above"
    assert bt._vs_chance(None, 0.5) is None


def test_train_log_and_checkpoint_pruning(tmp_path: Path) -> None:
    """Progress comes from lerobot-train's own log lines (tqdm noise around them; rounded
    step numbers counted instead); pruning keeps the checkpoint `last` points to."""
    text = (
        "INFO 2026-01-01 10:00:00 ot_train.py:339 num_total_params=1234 (1K)\n"
        "Training:   0%|  | 0/3000 [00:00<?, ?step/s]INFO 2026-01-01 10:00:02 ot_train.py:403 "
        "Start offline training on a fixed dataset, with effective batch size: 4\n"
        "Training: 50%|  | 1500/3000 [00:01<00:01]INFO 2026-01-01 10:00:12 ot_train.py:435 "
        "step:2K smpl:8 ep:1 epch:0.18 loss:0.741 grdn:34.0 lr:1.0e-04\n"
        "INFO 2026-01-01 10:00:13 ot_train.py:455 Checkpoint policy after step 1500\n"
        "INFO 2026-01-01 10:00:22 ot_train.py:435 step:2K smpl:8 ep:1 epch:0.2 loss:0.5 grdn:1\n"
    )
    p = bst.parse_train_log(text, 1000, 500)
    assert p == {"step": 2000, "steps": 1000, "loss": 0.5, "num_params": 1234, "loop_s": 20.0}
    ckpts = tmp_path / "checkpoints"
    for step in (2, 4, 6):  # 6: a save cut short by the stop
        (ckpts / f"{step:06d}" / "training_state").mkdir(parents=True)
    (ckpts / "000004" / "training_state" / "training_step.json").write_text('{"step": 4}')
    assert bst._prune_checkpoints(tmp_path) is None  # no `last` yet
    (ckpts / "last").symlink_to("000004")
    assert bst._prune_checkpoints(tmp_path) == 4
    assert sorted(c.name for c in ckpts.iterdir()) == ["000004", "000006", "last"]
    assert bst._prune_checkpoints(tmp_path, stopped=True) == 4
    assert sorted(c.name for c in ckpts.iterdir()) == ["000004", "last"]


def test_bad_arguments_exit_2(capsys) -> None:
    assert rb.main(["--policies", "act,nope", "--out", "/nonexistent"]) == rb.EXIT_USAGE
    assert "nope" in capsys.readouterr().err


if not IN_LEROBOT_ENV:
    from test_validate import run_suite_in_datasets_env

    def test_lerobot_baselines_suite_in_datasets_env() -> None:
        """The end-to-end test below, run inside `.venv-datasets`."""
        run_suite_in_datasets_env(__file__)

else:

    def _driver(out: Path, *extra: str) -> int:
        argv = [
            "--tasks", TASK, "--policies", "act", "--references", "oracle", "--scale", "tiny",
            "--episodes", "3", "--steps", "6", "--batch-size", "4", "--eval-episodes", "2",
            "--device", "cpu", "--workers", "1", "--eval-workers", "0", "--train-workers", "0",
            "--log-freq", "2", "--out", str(out), "--doc", str(out / "BASELINES.md"),
            "--records-from", "", *extra,
        ]  # fmt: skip
        return rb.main(argv)

    def _commands_run(out: Path) -> int:
        """Commands the driver started so far (each is logged as a '$ ' line)."""
        return sum(
            line.startswith("$ ")
            for log in (out / "logs").rglob("*.log")
            for line in log.read_text(encoding="utf-8").splitlines()
        )

    def test_tiny_end_to_end(tmp_path: Path) -> None:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        out = tmp_path / "run"
        records = out / "records" / TASK

        # 1) data and the oracle; the learned policy stays pending without "train".
        assert _driver(out, "--stages", "collect,convert,eval") == rb.EXIT_OK
        collect = json.loads((records / "collect.json").read_text())
        convert = json.loads((records / "convert.json").read_text())
        assert collect["episodes"] == convert["episodes"] == 3
        assert convert["frames"] == collect["frames"] > 0
        oracle = json.loads((records / "eval-oracle.json").read_text())
        assert oracle["n_episodes"] == 2 and oracle["successes"] == 2
        assert not (records / "eval-act.json").exists()

        # 2) the driver terminates training once it has checkpointed 2 steps.
        rc = _driver(out, "--stages", "train,eval", "--save-freq", "2",
                     "--train-steps-per-call", "2", "--time-limit", "600")  # fmt: skip
        assert rc == rb.EXIT_TIME
        partial = out / "train" / TASK / ".act.partial"
        last = partial / "checkpoints" / "last"
        step = json.loads((last / "training_state" / "training_step.json").read_text())["step"]
        assert step in (2, 4)
        cfg = json.loads((last / "pretrained_model" / "train_config.json").read_text())
        assert cfg["save_freq"] == 2 and cfg["steps"] == 6
        # Only the checkpoint `last` points to is kept (a save cut short included).
        assert sorted(p.name for p in last.parent.iterdir()) == [f"{step:06d}", "last"]
        assert not (records / "train-act.json").exists()
        wip = json.loads((records / ".train-act.wip.json").read_text())
        assert wip[0]["rc"] is None and wip[0]["step"] == step and wip[0]["steps"] >= step

        # 3) resumed from that checkpoint, finished, evaluated; the table written.
        assert _driver(out) == rb.EXIT_OK
        train = json.loads((records / "train-act.json").read_text())
        assert train["steps"] == 6 and train["calls"] == 2
        assert train["call_log"][1]["steps"] == 6 - step and train["call_log"][1]["step"] == 6
        assert train["num_params"] > 0 and train["final_loss"] is not None
        assert train["device"] == "cpu" and train["steps_per_s"] > 0
        assert not partial.exists()
        ckpts = [p.name for p in (out / "train" / TASK / "act" / "checkpoints").iterdir()]
        assert sorted(ckpts) == ["000006", "last"]  # older checkpoints pruned
        ev = json.loads((records / "eval-act.json").read_text())
        assert ev["n_episodes"] == 2 and ev["model"].startswith("lerobot-act-act-")
        table = json.loads((out / "BASELINES.json").read_text())
        assert table["done"] == table["total"] == 2 and not table["pending"]
        md = (out / "BASELINES.md").read_text()
        assert "| RememberColor3-VLA-v0 | Object | 0.333 | 2/2 = 100% [34%, 100%] |" in md
        assert "lerobot_train.py --dataset.repo_id=remember_color_3_vla_v0" in md
        assert "mikasa-bench run --task RememberColor3-VLA-v0 --policy lerobot:" in md

        # 4) everything done: no command runs again, the table is rewritten.
        before = _commands_run(out)
        assert _driver(out, "--pack", str(tmp_path / "pack.tar.gz")) == rb.EXIT_OK
        assert _commands_run(out) == before
        assert (tmp_path / "pack.tar.gz").stat().st_size > 0

        # 4b) records lost (a fresh clone has only the committed table): restored from the
        # table's JSON, nothing is redone.
        shutil.rmtree(out / "records")
        assert _driver(out, "--records-from", str(out / "BASELINES.json")) == rb.EXIT_OK
        assert _commands_run(out) == before
        assert json.loads((records / "eval-act.json").read_text()) == ev

        # 5) other training arguments are refused, not silently mixed with the records.
        assert _driver(out, "--steps", "7", "--stages", "train,eval") == rb.EXIT_FAILED

    def test_memory_setting_trains_from_npz(tmp_path: Path) -> None:
        """``memory-gru``: trained from the collected NPZ episodes (no LeRobot dataset is
        made), evaluated as a LeRobot policy directory, shown with its own data size; its
        trainer's stop and exact resume are tested in tests/test_memory_policy.py."""
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        out = tmp_path / "run"
        records = out / "records" / TASK
        memory = ["--policies", "memory-gru", "--references", "", "--stages",
                  "collect,train,eval,table", "--batch-size", "2"]  # fmt: skip
        assert _driver(out, *memory) == rb.EXIT_OK
        assert not (out / "data" / "data_lerobot").exists()
        train = json.loads((records / "train-memory-gru.json").read_text())
        assert train["steps"] == 6 and train["episodes"] == 3 and train["batch_unit"] == "episodes"
        assert "lerobot_policy_memory_gru.train" in train["command"]
        ev = json.loads((records / "eval-memory-gru.json").read_text())
        assert ev["n_episodes"] == 2 and ev["model"].startswith("lerobot-memory_gru")
        md = (out / "BASELINES.md").read_text()
        assert f"| 3 / {train['frames']} / NPZ | 6 steps x 2 episodes |" in md

    def test_drivers_side_by_side_share_the_settings(tmp_path: Path) -> None:
        """Two drivers on one task: one prepares the data while the other waits, then each
        setting is trained exactly once (by whichever driver took its lock)."""
        out = tmp_path / "run"
        argv = [
            sys.executable, rb.__file__, "--tasks", TASK, "--policies", "act,act-chunk",
            "--references", "", "--stages", "collect,convert,train", "--scale", "tiny",
            "--episodes", "2", "--steps", "4", "--batch-size", "4", "--device", "cpu",
            "--workers", "1", "--train-workers", "0", "--out", str(out), "--records-from", "",
            "--doc", str(out / "BASELINES.md"),
        ]  # fmt: skip
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        drivers = [subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
        time.sleep(1)
        drivers.append(subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
        logs = [p.communicate(timeout=900)[0] for p in drivers]
        assert all(p.returncode in (rb.EXIT_OK, rb.EXIT_TIME) for p in drivers), logs
        assert any("waiting for another driver" in log for log in logs), logs
        records = out / "records" / TASK
        for setting in ("act", "act-chunk"):
            train = json.loads((records / f"train-{setting}.json").read_text())
            assert train["calls"] == 1 and train["steps"] == 4
        assert sum(log.count(": trained ") for log in logs) == 2

    @pytest.fixture(autouse=True)
    def _quiet_torch() -> None:
        import torch

        torch.set_num_threads(1)
