"""LeRobot baselines on MIKASA-Robo, trained from scratch, in one resumable command.

    python baselines/lerobot/run_baselines.py [--tasks ...] [--policies ...] [--time-limit S]

For each task: collect oracle demonstrations (``mikasa-collect``), convert them to a
LeRobotDataset v3 (``mikasa-datasets to-lerobot --from npz``), train each policy setting
from scratch (``lerobot-train`` through ``lerobot_train.py`` beside this file), evaluate each
trained policy and the reference policies (``oracle``, ``oracle-memoryless``) with
``mikasa-bench run`` over the canonical episodes, then write the table
(``docs/BASELINES.md`` + ``.json``) from the records. See README.md beside this file.

Resumable: a unit (one task's collection, one policy's training, ...) is skipped when its
record under ``<out>/records`` exists and the outputs that later units need are there;
each unit builds its output under a hidden ``.partial`` path and renames it into place when
complete (collection and conversion: the CLIs' own per-episode / staging-directory
protocol). ``--time-limit S`` stops the call cleanly before S seconds: no unit starts without
``--min-unit-s`` left, a running one is stopped (training is terminated and resumes from its
last checkpoint: the steps after it are lost) and the next call with the same arguments goes
on. Exit status: 0 all done, 3 stopped
at the time limit (run again), 1 a unit failed (the others went on), 2 bad arguments.

This file is the command line and the order of the units; beside it: ``baseline_settings``
(the policy settings and their lerobot-train flags), ``baseline_stages`` (the units and
their records), ``baseline_table`` (the table and the pack), ``baseline_common`` (paths,
logging, files, running a command under the time limit). The driver runs the project's
CLIs and lerobot-train in subprocesses; itself it needs the standard library,
``mikasa_datasets`` (dataset names) and ``mikasa_bench`` (chance, Wilson interval, result
files), and imports the simulator only to write the table (the task manifest).
"""

from __future__ import annotations

import argparse
import fcntl
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

from baseline_common import REPO, TimeUp, UnitFailed, log, rel, write_json, write_text
from baseline_settings import (
    DEFAULT_REFERENCES,
    DEFAULT_SETTINGS,
    DEFAULT_TASKS,
    Setting,
    make_settings,
)
from baseline_stages import Driver
from baseline_table import build_table, pack, render_markdown, restore_records

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_TIME = 0, 1, 2, 3
WAIT_S = 10.0  # how often a driver looks again at data another driver is preparing
STAGES = ("collect", "convert", "train", "eval", "table")


def lock(d: Driver, task: str, setting: str | None = None) -> IO[str] | None:
    """An exclusive non-blocking flock (an open file; None when another driver holds it) on
    a task's data and references (``setting`` None) or on one setting's training and
    evaluation: drivers started side by side share the units out."""
    path = d.records / task / (".lock" if setting is None else f".lock-{setting}")
    path.parent.mkdir(parents=True, exist_ok=True)
    fh = open(path, "w")  # noqa: SIM115  # kept open as the lock's handle
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        return None
    return fh


def needs_training(d: Driver, task: str, setting: Setting) -> bool:
    """Whether the setting still has to be trained (no checkpoint, and its evaluation or
    its training record missing)."""
    return d.trained(task, setting.name) is None and (
        d.record(task, f"eval-{setting.name}") is None
        or d.record(task, f"train-{setting.name}") is None
    )


def prepare_task(d: Driver, task: str, stages: set[str]) -> None:
    """A task's shared units that ``stages`` asks for and the records lack, in order:
    collect -> convert (when a setting still needs the data) -> the references' evaluations."""
    settings = [d.settings[s] for s in d.a.policies]
    if stages & {"train", "eval"}:
        for s in settings:
            d.check_train_record(task, s)
    to_train = [s for s in settings if "train" in stages and needs_training(d, task, s)]
    # lerobot-train reads the LeRobot dataset, the memory trainer the NPZ episodes.
    need_lerobot = any(s.trainer != "memory" for s in to_train)
    need_npz = any(s.trainer == "memory" for s in to_train)
    # Collection is only needed for a dataset that is not converted yet; with "collect"
    # asked for explicitly it runs anyway (a no-op when the episodes are there).
    if "collect" in stages or (need_lerobot and d.converted(task) is None) or need_npz:
        d.collect(task)
    if "convert" in stages or need_lerobot:
        d.convert(task)
    if "eval" in stages:
        for ref in d.a.references:
            d.evaluate(task, ref, None)


def run_setting(d: Driver, task: str, setting: Setting, stages: set[str]) -> None:
    """One setting's training and evaluation, as ``stages`` asks and the records lack."""
    if "train" in stages and needs_training(d, task, setting):
        d.train(task, setting)
    # Without "train" in --stages an untrained setting stays pending.
    trained = d.trained(task, setting.name) is not None
    if "eval" in stages and (trained or d.record(task, f"eval-{setting.name}") is not None):
        d.evaluate(task, setting.name, setting)


def run_units(d: Driver, stages: set[str]) -> tuple[list[str], list[str]]:
    """Every task's shared units, then each setting's, each under its lock; drivers side by
    side take different units (one prepares a task's data while another trains a setting of
    a task whose data is there). A driver waits while another prepares the data a setting it
    could train needs, and leaves units that another driver is training. Returns the
    failures and the units held by other drivers; raises `TimeUp`."""
    settings = [d.settings[s] for s in d.a.policies]
    failures: list[str] = []
    finished: set[tuple[str, str | None]] = set()
    broken: set[str] = set()  # tasks whose shared units failed: their settings wait for a rerun
    while True:
        busy: list[str] = []
        waiting = False  # a unit here needs data that another driver is preparing
        for task in d.a.tasks:
            if task in broken:
                continue
            if (task, None) not in finished:
                held = lock(d, task)
                if held is None:
                    busy.append(task)
                    waiting = waiting or bool(settings)
                    continue
                try:
                    prepare_task(d, task, stages)
                    finished.add((task, None))
                except UnitFailed as exc:
                    failures.append(str(exc))
                    broken.add(task)
                    log(f"FAILED {exc}")
                    continue
                finally:
                    held.close()  # releases the flock
            for s in settings:
                if (task, s.name) in finished:
                    continue
                held = lock(d, task, s.name)
                if held is None:
                    busy.append(f"{task} {s.name}")
                    continue
                try:
                    run_setting(d, task, s, stages)
                    finished.add((task, s.name))
                except UnitFailed as exc:
                    failures.append(str(exc))
                    finished.add((task, s.name))
                    log(f"FAILED {exc}")
                finally:
                    held.close()
        if not waiting:
            return failures, busy
        d.check_time("waiting", "for another driver", need_s=WAIT_S)
        log(f"waiting for another driver: {', '.join(busy)}")
        time.sleep(WAIT_S)


def drive(d: Driver) -> int:
    """Every unit (`run_units`), then the table and the pack; the exit status."""
    stages = set(d.a.stages)
    timed_out: str | None = None
    failures: list[str] = []
    busy: list[str] = []
    log(
        f"output root {rel(d.out)}; tasks {', '.join(d.a.tasks)}; policies "
        f"{', '.join(d.a.policies)}; references {', '.join(d.a.references) or '-'}; "
        f"time limit {d.a.time_limit or 'none'}"
    )
    if d.a.records_from:
        restore_records(d, Path(d.a.records_from))
    if stages - {"table"}:
        try:
            failures, busy = run_units(d, stages - {"table"})
        except TimeUp as exc:
            timed_out = str(exc)
    if "table" in stages:
        table = build_table(d)
        write_text(Path(d.a.doc), render_markdown(table))
        write_json(Path(d.a.doc).with_suffix(".json"), table)
        log(f"table: {rel(d.a.doc)} ({table['done']}/{table['total']} results)")
    if d.a.pack:
        pack(d, Path(d.a.pack))
    if failures:
        log(f"{len(failures)} unit(s) failed")
        return EXIT_FAILED
    if timed_out or busy:
        why = timed_out or f"{', '.join(busy)} held by another driver"
        log(f"not finished: {why}; run the same command again to go on")
        return EXIT_TIME
    log("all done")
    return EXIT_OK


# ------------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------------


def _csv(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description="Collect -> convert -> train (lerobot-train, from scratch) -> evaluate "
        "(mikasa-bench) -> docs/BASELINES.md, resumable and time-limited.",
    )
    add = p.add_argument

    def csv(flag: str, default: Sequence[str], text: str) -> None:
        add(flag, type=_csv, default=list(default), help=text)

    def number(flag: str, kind: type, default: float | None, text: str, **kw: Any) -> None:
        add(flag, type=kind, default=default, help=text, **kw)

    cpus = os.cpu_count() or 1
    csv("--tasks", DEFAULT_TASKS, "comma-separated env ids (default: the six baseline tasks)")
    csv(
        "--policies",
        DEFAULT_SETTINGS,
        "comma-separated settings: act, act-chunk, diffusion, diffusion-hist, memory-gru "
        "(default: act,diffusion,diffusion-hist,memory-gru)",
    )
    csv(
        "--references",
        DEFAULT_REFERENCES,
        "bench policies evaluated beside them (default: oracle,oracle-memoryless; '' for none)",
    )
    csv("--stages", STAGES, f"comma-separated subset of {','.join(STAGES)}")
    add(
        "--scale",
        choices=("full", "tiny"),
        default="full",
        help="tiny: minute-sized models for smoke tests on a CPU",
    )
    number("--history", int, 8, "observation steps of diffusion-hist (default 8)")
    number("--episodes", int, 200, "oracle demonstrations per task (default 200)")
    number("--steps", int, 3000, "training steps per policy (default 3000)")
    number("--batch-size", int, 32, "training batch size (default 32)")
    add(
        "--train-arg",
        action="append",
        default=[],
        metavar="[SETTING:]KEY=VALUE",
        help="extra lerobot-train flag, e.g. policy.optimizer_lr=1e-5 or "
        "diffusion:batch_size=64 (repeatable)",
    )
    number(
        "--save-freq",
        int,
        None,
        "checkpoint every N steps (default: from the training rate, see --save-every-s)",
    )
    number(
        "--save-every-s",
        float,
        60.0,
        "without --save-freq: checkpoint about this often (default 60; a stop loses the "
        "steps since the last checkpoint)",
    )
    number(
        "--train-steps-per-call",
        int,
        None,
        "stop a training call once it has checkpointed N steps beyond its start (the next "
        "call resumes; a deterministic split, e.g. for tests)",
    )
    number("--log-freq", int, 100, "lerobot-train's log interval (default 100)")
    number("--seed", int, 1000, "training seed (default 1000, lerobot's)")
    number("--eval-episodes", int, 50, "evaluation episodes (default 50, canonical)")
    add(
        "--device",
        default="auto",
        help="training/inference device: auto (cuda if available), cuda, cpu",
    )
    number(
        "--workers", int, cpus, "collection and evaluation worker processes (default: CPU count)"
    )
    number(
        "--eval-workers",
        int,
        None,
        "mikasa-bench run --workers of every evaluation (default: learned policies on a GPU "
        "in lockstep batches, see --eval-batch; the references and CPU policies on --workers)",
    )
    number(
        "--eval-batch",
        int,
        10,
        "episodes a learned policy on a GPU plays in lockstep, one batched policy call per "
        "step (mikasa-bench run --policy-batch; default 10: the 10 scenes of 50 episodes; 1: "
        "one episode at a time, in the bench's own process)",
    )
    number(
        "--eval-envs-per-worker",
        int,
        None,
        "envs per env process of a lockstep evaluation (mikasa-bench run --envs-per-worker; "
        "default the bench's: 4 on a GPU, stepped in threads; 1 or 2 spread the B envs of a "
        "batch over more cores)",
    )
    number(
        "--train-workers",
        int,
        min(8, cpus),
        "lerobot-train data loader workers (default min(8, CPUs))",
    )
    number("--convert-workers", int, None, "to-lerobot writer processes (default: its own)")
    add("--vcodec", default=None, help="to-lerobot --vcodec (default: its own)")
    add(
        "--no-videos",
        action="store_true",
        help="to-lerobot --no-videos (PNG frames; no video decoding in training)",
    )
    add(
        "--video-backend",
        default=None,
        help="lerobot-train --dataset.video_backend (default: lerobot's, torchcodec)",
    )
    add(
        "--render-device",
        default=None,
        choices=("auto", "cpu", "gpu"),
        help="mikasa-bench --render-device",
    )
    add(
        "--out",
        default=str(REPO / "runs" / "lerobot_baselines"),
        help="output root (default runs/lerobot_baselines)",
    )
    add(
        "--doc",
        default=str(REPO / "docs" / "BASELINES.md"),
        help="table path (default docs/BASELINES.md; JSON beside it)",
    )
    add(
        "--records-from",
        default=str(REPO / "docs" / "BASELINES.json"),
        metavar="TABLE.json",
        help="restore the records this table JSON holds and <out>/records lacks, so a fresh "
        "clone goes on where the committed table stands (default docs/BASELINES.json; '' for "
        "none)",
    )
    add(
        "--pack",
        default=None,
        metavar="FILE.tar.gz",
        help="also pack records, table and log tails into this file",
    )
    number("--time-limit", float, None, "stop cleanly before S seconds", metavar="S")
    number("--min-unit-s", float, 30.0, "start no unit with less time left (default 30)")
    number(
        "--stop-margin-s",
        float,
        15.0,
        "training is stopped (SIGTERM, SIGKILL after 10 s) this long before the limit (default 15)",
    )
    number("--grace-s", float, 20.0, "SIGINT -> SIGTERM delay when stopping a non-training command")
    number("--progress-s", float, 60.0, "progress line interval during long units (default 60)")
    add(
        "--python",
        default=None,
        help="interpreter with lerobot, the envs and mikasa-bench (default: this one)",
    )
    add("--sim-python", default=None, help="interpreter for mikasa-collect (default: --python)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; the exit status is in the module docstring."""
    args = build_parser().parse_args(argv)
    known = make_settings(args.history)
    bad = [s for s in args.policies if s not in known] + [s for s in args.stages if s not in STAGES]
    if bad or args.history < 1 or args.episodes < 1 or args.steps < 1 or args.eval_episodes < 1:
        print(
            f"run_baselines: bad arguments {bad or ''} (settings: {', '.join(known)}; stages: "
            f"{', '.join(STAGES)}; counts must be >= 1)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    return drive(Driver(args))


if __name__ == "__main__":
    sys.exit(main())
