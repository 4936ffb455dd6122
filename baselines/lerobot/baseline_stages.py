"""The units of the LeRobot baseline driver and their records.

One unit = one task's collection, its conversion, one setting's training, or one policy's
evaluation (`baseline_eval`). Each runs the project's CLI (or ``lerobot_train.py``) as a subprocess under the
call's time limit, builds its output under a hidden ``.partial`` path (collection and
conversion: the CLIs' own per-episode / staging-directory protocol), renames it into place
when complete, and then writes a small JSON record under ``<out>/records/<task>/``: the
table is built from those records alone. A unit whose record exists and whose outputs later
units need are there is skipped.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from baseline_common import (
    DRIVER_CALL,
    HERE,
    Deadline,
    RunResult,
    TimeUp,
    UnitFailed,
    calls_wall_s,
    dir_size_mb,
    display,
    log,
    now,
    read_json,
    rel,
    run_until,
    write_json,
)
from baseline_eval import EvaluateStage
from baseline_memory import MemoryTrainStage
from baseline_settings import (
    Setting,
    dataset_name,
    flag_diff,
    make_settings,
    model_flags,
    train_flags,
)

__all__ = ["Driver", "TRAIN_WRAPPER"]

TRAIN_WRAPPER = HERE / "lerobot_train.py"
GUESS_STEPS_PER_S = {"cpu": 0.2, "cuda": 5.0}
"""Training steps/s assumed for `Driver.auto_save_freq` until one is measured (low on purpose:
too frequent checkpoints cost seconds, too rare ones lose training at a stop)."""


def _last(run_dir: Path) -> Path:
    """A lerobot-train run's last checkpoint."""
    return run_dir / "checkpoints" / "last"


def _step_file(run_dir: Path) -> Path:
    """The step count of a run's last checkpoint (there once the first one is saved)."""
    return _last(run_dir) / "training_state" / "training_step.json"


def _rate(calls: Sequence[Mapping[str, Any]]) -> float | None:
    """Training steps per second over the calls' training loops (start-ups excluded)."""
    steps = sum(c.get("steps") or 0 for c in calls)
    loop = sum(c.get("loop_s") or 0.0 for c in calls)
    return round(steps / loop, 3) if steps and loop > 0 else None


def _prune_checkpoints(run_dir: Path, stopped: bool = False) -> int | None:
    """Remove the run's numbered checkpoints before the one ``checkpoints/last`` points to
    (only ``last`` is resumed or evaluated; each holds the weights and the optimizer state)
    and, once the process has ``stopped``, any after it (a save cut short); the step of
    ``last``, or None before the first checkpoint."""
    last = _last(run_dir)
    step = read_json(_step_file(run_dir))
    if not isinstance(step, dict) or not last.is_symlink():
        return None
    keep = last.resolve().name
    for other in last.parent.iterdir():
        if other.name.isdigit() and other.name != keep and not other.is_symlink():
            if stopped or int(other.name) < int(keep):
                shutil.rmtree(other, ignore_errors=True)
    return int(step["step"])


_INFO_LINE = re.compile(r"INFO (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d) +\S+ (.*)")
_LOG_STEP = re.compile(r"step:\S+ .*\bloss:(\S+)")
_SAVED = re.compile(r"Checkpoint policy after step (\d+)")
_PARAMS = re.compile(r"num_total_params=(\d+)")


def parse_train_log(text: str, start_step: int, log_freq: int) -> dict[str, Any]:
    """What one lerobot-train call's output (from ``start_step``) says: the last step it is
    known to have reached (its ``log_freq`` lines and checkpoint lines; the step numbers of
    its log lines are rounded, "2K", so they are counted instead), the steps since
    ``start_step``, the last logged loss (an average over the log interval), the parameter
    count, and the training loop's time (from "Start offline training" to the last of those
    lines; lerobot's timestamps have 1 s resolution)."""
    step, loss, params, t0, t1, logged = start_step, None, None, None, None, 0
    for m in _INFO_LINE.finditer(text):
        t = dt.datetime.strptime(m[1], "%Y-%m-%d %H:%M:%S").timestamp()
        msg = m[2]
        if msg.startswith("Start offline training"):
            t0 = t
        elif (hit := _LOG_STEP.match(msg)) and log_freq > 0:
            logged += 1
            step = max(step, (start_step // log_freq + logged) * log_freq)
            loss, t1 = float(hit[1]), t
        elif hit := _SAVED.match(msg):
            step, t1 = max(step, int(hit[1])), t
        elif hit := _PARAMS.match(msg):
            params = int(hit[1])
    loop_s = t1 - t0 if t0 is not None and t1 is not None else None
    return {
        "step": step,
        "steps": step - start_step,
        "loss": loss,
        "num_params": params,
        "loop_s": loop_s,
    }


class Driver(EvaluateStage, MemoryTrainStage):
    """The configured run's layout under ``--out``, its records and its units."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.a = args
        self.out = Path(args.out).resolve()
        self.records = self.out / "records"
        self.deadline = Deadline(args.time_limit)
        self.settings = make_settings(args.history)
        self.python = args.python or sys.executable
        self.sim_python = args.sim_python or self.python
        self._device: str | None = None
        self._device_names: dict[str, str] = {}
        self.env = dict(os.environ)
        # Everything local: no Hub look-ups, caches inside the output root, not in ~.
        self.env.setdefault("HF_HUB_OFFLINE", "1")
        self.env.setdefault("HF_DATASETS_OFFLINE", "1")
        self.env.setdefault("HF_HOME", str(self.out / "hf"))
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        self.env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(HERE), self.env.get("PYTHONPATH", "")) if p
        )

    # ---------------------------------------------------------------- paths and records
    def record_path(self, task: str, unit: str) -> Path:
        return self.records / task / f"{unit}.json"

    def record(self, task: str, unit: str) -> dict[str, Any] | None:
        """A finished unit's record, or None."""
        rec = read_json(self.record_path(task, unit))
        return rec if isinstance(rec, dict) and rec.get("status") == "done" else None

    def wip_path(self, task: str, unit: str) -> Path:
        return self.records / task / f".{unit}.wip.json"

    def add_wip(
        self, task: str, unit: str, entry: dict[str, Any], fresh: bool = False
    ) -> list[dict]:
        """Append one call's entry to the unit's in-progress list (reset when ``fresh``)."""
        path = self.wip_path(task, unit)
        calls = [] if fresh else (read_json(path) or [])
        calls.append(entry)
        write_json(path, calls)
        return calls

    def save_record(self, task: str, unit: str, fields: Mapping[str, Any]) -> dict[str, Any]:
        """Write a finished unit's record (atomically), with the time and the driver call
        that finished it, and drop its in-progress list."""
        rec = {"status": "done", "unit": unit, "task": task, **fields, "finished": now()}
        write_json(self.record_path(task, unit), {**rec, "driver": DRIVER_CALL})
        self.wip_path(task, unit).unlink(missing_ok=True)
        return rec

    def npz_dir(self, task: str) -> Path:
        return self.out / "data" / "data_npz" / dataset_name(task)

    def lerobot_dir(self, task: str) -> Path:
        return self.out / "data" / "data_lerobot" / dataset_name(task)

    def train_dir(self, task: str, setting: str) -> Path:
        return self.out / "train" / task / setting

    def eval_dir(self, task: str, policy: str) -> Path:
        return self.out / "eval" / task / policy

    def log_path(self, task: str, unit: str) -> Path:
        path = self.out / "logs" / task / f"{unit}.log"
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    @staticmethod
    def partial(path: Path) -> Path:
        return path.with_name(f".{path.name}.partial")

    # ---------------------------------------------------------------- subprocesses
    def cli(self, python: str, script: str, module: str) -> list[str]:
        """The console script beside ``python``, else ``python -c`` calling its main."""
        exe = Path(python).parent / script
        if exe.is_file():
            return [str(exe)]
        return [python, "-c", f"import sys; from {module} import main; sys.exit(main())"]

    def run(
        self,
        task: str,
        unit: str,
        argv: Sequence[str],
        env: Mapping[str, str] | None = None,
        tick: Callable[[], None] | None = None,
    ) -> RunResult:
        """Run a unit's command (log in ``logs/<task>/<unit>.log``) under the time limit."""
        return run_until(
            argv,
            self.log_path(task, unit),
            env or self.env,
            self.deadline,
            self.a.grace_s,
            tick,
            self.a.progress_s,
        )

    def fail(self, task: str, unit: str, why: str) -> UnitFailed:
        """The failure of a unit, with its log's tail."""
        log_path = self.log_path(task, unit)
        lines = log_path.read_text(encoding="utf-8", errors="replace").splitlines()[-25:]
        tail = "\n".join("    " + line[-300:] for line in lines)
        return UnitFailed(f"{task} {unit}: {why}; log {rel(log_path)}:\n{tail}")

    def check_time(self, task: str, unit: str, need_s: float = 0.0) -> None:
        """Raise `TimeUp` unless at least ``--min-unit-s`` (and ``need_s``) are left."""
        if self.deadline.remaining() < max(self.a.min_unit_s, need_s):
            raise TimeUp(
                f"{task} {unit}: not started, {max(self.deadline.remaining(), 0):.0f} s left"
            )

    def _torch_says(self, code: str) -> str:
        """What ``code`` prints in the lerobot interpreter (with torch imported as ``torch``)."""
        argv = [self.python, "-c", f"import torch; print({code})"]
        return subprocess.run(argv, capture_output=True, text=True, env=self.env).stdout.strip()

    def device(self) -> str:
        """``--device``, with auto = cuda when the lerobot interpreter's torch sees one."""
        if self._device is None:
            auto = self.a.device == "auto"
            probe = "'cuda' if torch.cuda.is_available() else 'cpu'"
            self._device = (self._torch_says(probe) or "cpu") if auto else self.a.device
        return self._device

    def device_name(self, args: Mapping[str, str]) -> str:
        """The training device of ``args`` as records note it: ``cpu`` or the GPU's name."""
        dev = args["policy.device"]
        if dev not in self._device_names:
            cuda = dev.startswith("cuda")
            name = self._torch_says(f"torch.cuda.get_device_name({dev!r})") if cuda else ""
            self._device_names[dev] = name or dev
        return self._device_names[dev]

    # ---------------------------------------------------------------- collect
    def collected(self, task: str) -> int:
        meta = read_json(self.npz_dir(task) / "metadata.json")
        return int(meta.get("num_episodes", 0)) if isinstance(meta, dict) else 0

    def collect(self, task: str) -> None:
        """Oracle demonstrations as NPZ (mikasa-collect resumes by itself, episode by episode)."""
        unit, n = "collect", self.a.episodes
        if self.collected(task) >= n:
            if self.record(task, unit) is None:
                self._collect_record(task, [])
            return
        self.check_time(task, unit)
        argv = self.cli(self.sim_python, "mikasa-collect", "mikasa_oracles.collect_cli")
        argv += ["--env-id", task, "--num-episodes", str(n), "--out", str(self.out / "data")]
        argv += ["--workers", str(self.a.workers), "--no-progress"]
        fresh = not self.npz_dir(task).is_dir()
        log(f"{task}: collect {n} oracle episodes ({self.a.workers} workers)")
        res = self.run(task, unit, argv)
        calls = self.add_wip(task, unit, {"wall_s": round(res.wall_s, 1), "rc": res.rc}, fresh)
        if res.rc is None:
            raise TimeUp(f"{task} collect: stopped at {self.collected(task)}/{n} episodes")
        if res.rc != 0 or self.collected(task) < n:
            raise self.fail(task, unit, f"mikasa-collect exit {res.rc}")
        self._collect_record(task, calls, argv)

    def _collect_record(
        self, task: str, calls: list[dict], argv: Sequence[str] | None = None
    ) -> None:
        meta = read_json(self.npz_dir(task) / "metadata.json") or {}
        seeds = [int(s) for s in meta.get("episode_seeds", [])]
        lengths = [int(n) for n in meta.get("episode_lengths", [])]
        # Attempt k uses seed k (start seed 0) and episodes are the first successes in seed
        # order, so seeds 0..last were all tried: the oracle's yield on those seeds.
        attempts = (max(seeds) + 1) if seeds else 0
        rec = self.save_record(
            task,
            "collect",
            {
                "episodes": len(seeds),
                "frames": sum(lengths),
                "attempts": attempts,
                "yield": len(seeds) / attempts if attempts else None,
                "wall_s": calls_wall_s(calls) if calls else None,
                "calls": len(calls),
                "command": display(argv) if argv else None,
            },
        )
        log(
            f"{task}: collected {rec['episodes']} episodes, {rec['frames']} frames "
            f"(oracle yield {rec['episodes']}/{attempts} seeds)"
        )

    # ---------------------------------------------------------------- convert
    def converted(self, task: str) -> dict[str, Any] | None:
        """The LeRobot dataset's info.json when it holds the requested episodes (the NPZ
        source may be gone: a converted dataset does not need it)."""
        info = read_json(self.lerobot_dir(task) / "meta" / "info.json")
        if isinstance(info, dict) and int(info.get("total_episodes", -1)) >= self.a.episodes:
            return info
        return None

    def convert(self, task: str) -> None:
        """NPZ -> LeRobotDataset v3 (the CLI builds in a staging directory and renames)."""
        unit = "convert"
        if self.converted(task) is not None:
            if self.record(task, unit) is None:
                self._convert_record(task, None, None)
            return
        if self.collected(task) < self.a.episodes:
            raise UnitFailed(f"{task} convert: only {self.collected(task)} episodes collected")
        self.check_time(task, unit)
        argv = self.cli(self.python, "mikasa-datasets", "mikasa_datasets.cli")
        argv += ["to-lerobot", "--task", task, "--from", "npz", "--root", str(self.out / "data")]
        argv += ["--resume"]
        if self.a.convert_workers is not None:
            argv += ["--workers", str(self.a.convert_workers)]
        if self.a.vcodec:
            argv += ["--vcodec", self.a.vcodec]
        if self.a.no_videos:
            argv += ["--no-videos"]
        log(f"{task}: convert to LeRobot v3")
        res = self.run(task, unit, argv)
        if res.rc is None:
            raise TimeUp(f"{task} convert: stopped (it starts over next call)")
        if res.rc != 0 or self.converted(task) is None:
            raise self.fail(task, unit, f"to-lerobot exit {res.rc}")
        self._convert_record(task, res.wall_s, argv)

    def _convert_record(self, task: str, wall_s: float | None, argv: Sequence[str] | None) -> None:
        info = self.converted(task) or {}
        videos = (f for f in info.get("features", {}).values() if f.get("dtype") == "video")
        rec = self.save_record(
            task,
            "convert",
            {
                "dataset": rel(self.lerobot_dir(task)),
                "repo_id": dataset_name(task),
                "episodes": info.get("total_episodes"),
                "frames": info.get("total_frames"),
                "fps": info.get("fps"),
                "video_codec": next((f.get("info", {}).get("video.codec") for f in videos), None),
                "size_mb": dir_size_mb(self.lerobot_dir(task)),
                "wall_s": round(wall_s, 1) if wall_s is not None else None,
                "command": display(argv) if argv else None,
            },
        )
        log(
            f"{task}: LeRobot dataset {rec['episodes']} episodes, {rec['frames']} frames, "
            f"{rec['size_mb']} MB"
        )

    # ---------------------------------------------------------------- train
    def train_args(self, task: str, setting: Setting) -> dict[str, str]:
        """lerobot-train's flags (key -> value) for ``setting`` on ``task``, overrides applied
        (a memory setting's: the same keys, its dataset the NPZ episodes)."""
        flags = train_flags(self.a, task, setting, str(self.lerobot_dir(task)), self.device())
        return self.memory_train_args(task, setting, flags) if setting.trainer == "memory" else flags

    def check_train_record(self, task: str, setting: Setting) -> dict[str, str]:
        """The model-defining training flags; `UnitFailed` when the recorded training of
        this setting used others (its checkpoint and results would not match the request)."""
        model_key = model_flags(self.train_args(task, setting))
        rec = self.record(task, f"train-{setting.name}")
        if rec is not None and rec.get("model_args") != model_key:
            raise UnitFailed(
                f"{task} train-{setting.name}: recorded with other arguments "
                f"({flag_diff(rec.get('model_args') or {}, model_key)}); use another --out, or "
                f"remove {rel(self.train_dir(task, setting.name))} and the records "
                f"{rel(self.records / task)}/{{train,eval}}-{setting.name}.json to redo it"
            )
        return model_key

    def trained(self, task: str, setting: str) -> Path | None:
        """The final checkpoint's pretrained_model directory, if training finished."""
        if self.settings[setting].trainer == "memory":
            return self.memory_trained(task, setting)
        model = _last(self.train_dir(task, setting)) / "pretrained_model"
        return model if (model / "model.safetensors").is_file() else None

    def _resume_argv(self, run_dir: Path) -> list[str]:
        """lerobot-train resuming ``run_dir`` from its last checkpoint's own config."""
        cfg = _last(run_dir) / "pretrained_model" / "train_config.json"
        return [self.python, str(TRAIN_WRAPPER), f"--config_path={cfg}", "--resume=true"]

    def _rate_seen(self, setting: Setting, args: Mapping[str, str]) -> float | None:
        """Steps/s of a finished training of ``setting`` (any task) at the same batch size on
        the same device, from its record."""
        for path in sorted(self.records.glob(f"*/train-{setting.name}.json")):
            rec = read_json(path) or {}
            same = rec.get("batch_size") == int(args["batch_size"])
            if same and rec.get("device") == self.device_name(args) and rec.get("steps_per_s"):
                return float(rec["steps_per_s"])
        return None

    def auto_save_freq(self, setting: Setting, args: Mapping[str, str], calls: list) -> int:
        """lerobot's ``save_freq`` for about one checkpoint every ``--save-every-s`` of
        training: the rate measured by this run's earlier calls, else by a finished run of
        the setting, else `GUESS_STEPS_PER_S` for the device."""
        rate = _rate(calls) or self._rate_seen(setting, args)
        if rate is None:
            rate = GUESS_STEPS_PER_S["cpu" if args["policy.device"] == "cpu" else "cuda"]
        return max(1, min(int(args["steps"]), int(rate * self.a.save_every_s)))

    def train(self, task: str, setting: Setting) -> None:
        """lerobot-train from scratch into a ``.partial`` directory; stopped (SIGTERM) at the
        time limit and resumed from its last checkpoint by the next call (the steps after that
        checkpoint are lost); renamed into place when the last step is saved. A memory
        setting trains with baselines/memory's trainer instead (`MemoryTrainStage`)."""
        if setting.trainer == "memory":
            return self.train_memory(task, setting)
        unit = f"train-{setting.name}"
        args = self.train_args(task, setting)
        model_key = self.check_train_record(task, setting)
        if self.record(task, unit) is not None and self.trained(task, setting.name) is not None:
            return
        if self.converted(task) is None:
            raise UnitFailed(f"{task} {unit}: no LeRobot dataset")
        # Training is stopped --stop-margin-s before the limit: start only with time beyond it.
        self.check_time(task, unit, self.a.min_unit_s + self.a.stop_margin_s)
        final = self.train_dir(task, setting.name)
        part = self.partial(final)
        if final.exists():  # a finished run without its record (killed between the two)
            shutil.move(str(final), str(part))
        start = _prune_checkpoints(part, stopped=True) if part.exists() else None
        resume = start is not None
        if part.exists() and not resume:
            shutil.rmtree(part)  # stopped before its first checkpoint: start over
        start = start or 0
        earlier = (read_json(self.wip_path(task, unit)) or []) if resume else []
        args.setdefault("save_freq", str(self.auto_save_freq(setting, args, earlier)))
        args["output_dir"] = str(part)
        first = [self.python, str(TRAIN_WRAPPER), *(f"--{k}={v}" for k, v in args.items())]
        if resume:
            # The checkpoint's config is the run's; these may change between calls.
            keep = ("policy.device", "num_workers", "log_freq", "save_freq")
            argv = self._resume_argv(part) + [f"--{k}={args[k]}" for k in keep]
        else:
            argv = first
        final.parent.mkdir(parents=True, exist_ok=True)
        log(
            f"{task}: train {setting.name} ({setting.label}) "
            f"{f'resumed at step {start}' if resume else 'from scratch'}, {args['steps']} "
            f"steps x batch {args['batch_size']} on {args['policy.device']}, "
            f"checkpoint every {args['save_freq']} steps"
        )
        log_path = self.log_path(task, unit)
        offset = log_path.stat().st_size if log_path.exists() else 0

        def progress() -> dict[str, Any]:
            with open(log_path, encoding="utf-8", errors="replace") as fh:
                fh.seek(offset)
                return parse_train_log(fh.read(), start, int(args["log_freq"]))

        def tick() -> None:
            p = progress()
            if p["steps"] and p["loop_s"]:
                loss = "?" if p["loss"] is None else f"{p['loss']:.4f}"
                log(
                    f"{task}: train {setting.name} step ~{p['step']}/{args['steps']} loss {loss} "
                    f"({p['steps'] / p['loop_s']:.2f} steps/s, start-up excluded)"
                )

        def stop() -> bool:
            # Older checkpoints go while it runs (each holds the weights and optimizer state).
            saved = _prune_checkpoints(part)
            per_call = self.a.train_steps_per_call
            return bool(per_call) and saved is not None and saved >= start + per_call

        train_deadline = Deadline(self.deadline.remaining() - self.a.stop_margin_s)
        res = run_until(
            argv,
            log_path,
            self.env,
            train_deadline,
            self.a.grace_s,
            tick,
            self.a.progress_s,
            stop=stop,
            first_signal=signal.SIGTERM,
        )
        p = progress()
        saved = _prune_checkpoints(part, stopped=True)
        entry = {
            "wall_s": round(res.wall_s, 1),
            "rc": res.rc,
            "steps": p["steps"],  # trained in this call, lost ones included
            "loop_s": p["loop_s"],
            "step": saved,  # the last checkpoint's: where the next call resumes
            "lost_steps": max(p["step"] - (saved or 0), 0),
            "save_freq": int(args["save_freq"]),
            "device": self.device_name(args),
        }
        calls = self.add_wip(task, unit, entry, fresh=not resume)
        done = saved == int(args["steps"]) and res.rc in (0, None)
        if res.rc is None and not done:
            raise TimeUp(
                f"{task} {unit}: stopped at step ~{p['step']}; resumes from the checkpoint "
                f"at step {saved or 0}/{args['steps']}"
            )
        if not done:
            raise self.fail(task, unit, f"lerobot-train exit {res.rc}")
        part.rename(final)
        self.finish_training(
            task,
            setting,
            args,
            calls,
            {
                "steps_per_s": _rate(calls),
                "device": entry["device"],
                "num_params": p["num_params"],
                "final_loss": p["loss"],
                "checkpoint": rel(_last(final) / "pretrained_model"),
                "model_args": model_key,
                "command": display(first),
                "resume_command": display(self._resume_argv(final)),
            },
        )

    def finish_training(
        self,
        task: str,
        setting: Setting,
        args: Mapping[str, str],
        calls: list[dict],
        fields: Mapping[str, Any],
    ) -> None:
        """Save a finished training's record (what every setting's record holds, then
        ``fields``: rate, device, loss, checkpoint, commands) and log it."""
        rec = self.save_record(
            task,
            f"train-{setting.name}",
            {
                "setting": setting.name,
                "label": setting.label,
                "policy_type": setting.policy_type,
                "sees": setting.sees,
                "steps": int(args["steps"]),
                "batch_size": int(args["batch_size"]),
                "wall_s": calls_wall_s(calls),
                "calls": len(calls),
                "call_log": calls,
                **fields,
            },
        )
        log(
            f"{task}: trained {setting.name}: {rec['steps']} steps in {rec['wall_s']:.0f} s "
            f"({rec['calls']} call(s)), loss {rec['final_loss']}"
        )
