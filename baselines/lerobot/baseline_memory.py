"""The training unit of the memory setting: baselines/memory's whole-episode trainer.

The memory policy (``memory_gru``, a LeRobot policy plugin under ``baselines/memory``) trains
on whole episodes of the NPZ demonstrations (``mikasa-memory-train``), not through
lerobot-train; it writes the same pretrained-policy directory, which the evaluation unit
loads as ``lerobot:<train>/pretrained_model``. The trainer saves at ``--time-limit`` and on
SIGINT/SIGTERM and resumes with ``--resume``, so a stop loses no steps.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from baseline_common import (
    TimeUp,
    UnitFailed,
    display,
    log,
    read_json,
    rel,
    run_until,
)
from baseline_settings import Setting, memory_train_argv

MEMORY_TRAINER = "lerobot_policy_memory_gru.train"
MEMORY_MODEL = "pretrained_model"
MEMORY_STATE = "training_state.pt"
MEMORY_LOG = "train_log.json"
MEMORY_EXIT_TIME = 3  # the trainer saved at its time limit or a signal


class MemoryTrainStage:
    """`Driver`'s training of settings whose ``trainer`` is ``"memory"``."""

    def memory_trained(self, task: str, setting: str) -> Path | None:
        """The pretrained_model directory of a finished memory training, if any."""
        model = self.train_dir(task, setting) / MEMORY_MODEL
        return model if (model / "model.safetensors").is_file() else None

    def memory_train_args(self, task: str, setting: Setting, flags: dict[str, str]) -> dict:
        """`train_flags` for the memory trainer: the first ``--episodes`` NPZ episodes are its
        dataset."""
        return {**flags, "dataset.root": str(self.npz_dir(task)), "episodes": str(self.a.episodes)}

    def train_memory(self, task: str, setting: Setting) -> None:
        """``mikasa-memory-train`` into a ``.partial`` directory, resumed by the next call when
        the time limit stops it; renamed into place when the last step is saved."""
        unit = f"train-{setting.name}"
        args = self.train_args(task, setting)
        model_key = self.check_train_record(task, setting)
        if self.record(task, unit) is not None and self.trained(task, setting.name) is not None:
            return
        if self.collected(task) < self.a.episodes:
            raise UnitFailed(f"{task} {unit}: {self.collected(task)}/{self.a.episodes} episodes")
        self.check_time(task, unit, self.a.min_unit_s + self.a.stop_margin_s)
        final = self.train_dir(task, setting.name)
        part = self.partial(final)
        if final.exists():  # a finished run without its record (killed between the two)
            shutil.move(str(final), str(part))
        resume = (part / MEMORY_STATE).is_file()
        if part.exists() and not resume:
            shutil.rmtree(part)  # stopped before its first save: start over
        base = [self.python, "-m", MEMORY_TRAINER, *memory_train_argv(args), "--out", str(part)]
        limit = self.deadline.remaining() - self.a.stop_margin_s
        argv = base + ["--save-every-s", str(self.a.save_every_s)]
        argv += ["--resume"] if resume else []
        argv += [] if limit == float("inf") else ["--time-limit", str(int(limit))]
        final.parent.mkdir(parents=True, exist_ok=True)
        log(
            f"{task}: train {setting.name} ({setting.label}) "
            f"{'resumed' if resume else 'from scratch'}, {args['steps']} steps x "
            f"{args['batch_size']} episodes on {args['policy.device']}"
        )
        train_log = part / MEMORY_LOG

        def progress() -> dict[str, Any]:
            return read_json(train_log) or {}

        def tick() -> None:
            p = progress()
            if p.get("log"):
                last = p["log"][-1]
                log(
                    f"{task}: train {setting.name} step {last['step']}/{args['steps']} "
                    f"loss {last['loss']:.4f} ({p.get('steps_per_s')} steps/s)"
                )

        before = progress().get("step", 0)
        res = run_until(
            argv,
            self.log_path(task, unit),
            self.env,
            self.deadline,
            self.a.grace_s,
            tick,
            self.a.progress_s,
        )
        p = progress()
        entry = {
            "wall_s": round(res.wall_s, 1),
            "rc": res.rc,
            "steps": p.get("step", 0) - before,
            "loop_s": p.get("train_s"),
            "step": p.get("step"),
            "lost_steps": 0,
            "device": p.get("device"),
        }
        calls = self.add_wip(task, unit, entry, fresh=not resume)
        done = p.get("step") == int(args["steps"]) and res.rc == 0
        if res.rc in (None, MEMORY_EXIT_TIME) and not done:
            raise TimeUp(f"{task} {unit}: saved at step {p.get('step')}; the next call resumes")
        if not done:
            raise self.fail(task, unit, f"mikasa-memory-train exit {res.rc}")
        part.rename(final)
        self.finish_training(
            task,
            setting,
            args,
            calls,
            {
                "batch_unit": "episodes",
                "episodes": p.get("episodes"),
                "frames": p.get("frames"),
                "steps_per_s": p.get("steps_per_s"),
                "device": p.get("device"),
                "num_params": p.get("parameters"),
                "final_loss": p.get("final_loss"),
                "checkpoint": rel(final / MEMORY_MODEL),
                "model_args": model_key,
                "command": display(base),
                "resume_command": display([*base, "--resume"]),
            },
        )
