"""The evaluation unit of the LeRobot baseline driver: ``mikasa-bench run`` of a trained
setting or a reference policy, and its record.

Apart from `baseline_stages` because evaluation has concerns of its own (how the bench
spreads the episodes: lockstep batches on a GPU, a worker pool for the references; resuming
a cut run) and no part in collection, conversion or training. `Driver` inherits it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from baseline_common import TimeUp, UnitFailed, calls_wall_s, display, log, read_json, rel
from baseline_settings import Setting
from mikasa_bench.errors import BenchError
from mikasa_bench.results.metrics import wilson_interval
from mikasa_bench.results.run_data import load_run

__all__ = ["BENCH_INTERRUPTED", "EvaluateStage"]

BENCH_INTERRUPTED = 130
"""``mikasa-bench run``'s exit status when it stops early (the next call resumes the run)."""


def _bench_result(run_dir: Path, task: str) -> dict[str, Any] | None:
    """``task``'s result in a finished ``mikasa-bench run`` directory, or None."""
    try:
        results = load_run(run_dir).results
    except BenchError:
        return None
    return next((r for r in results if r.get("env_id") == task), None)


def _bench_lockstep(run_dir: Path) -> bool:
    """Whether a mikasa-bench run directory plays its episodes in lockstep (--policy-batch)."""
    meta = read_json(run_dir / "meta" / "run.json") or {}
    return int((meta.get("config") or {}).get("policy_batch", 1)) > 1


class EvaluateStage:
    """`baseline_stages.Driver`'s evaluation unit (it uses the driver's layout, records,
    ``run``, ``fail`` and ``check_time``)."""

    def eval_exec(self, setting: Setting | None) -> list[str]:
        """How ``mikasa-bench run`` spreads an evaluation: ``--workers`` from
        ``--eval-workers`` when given; else a learned policy on a GPU plays ``--eval-batch``
        episodes in lockstep with one batched policy call per step (``--policy-batch``),
        since one episode at a time leaves the GPU waiting and worker processes that each
        run a copy on one GPU slow each other down (the README's "Evaluate learned policies
        in batches"); the references run on ``--workers``."""
        if self.a.eval_workers is not None:
            return ["--workers", str(self.a.eval_workers)]
        if setting is not None and self.device().startswith("cuda"):
            if self.a.eval_batch > 1:
                return ["--policy-batch", str(self.a.eval_batch), *self.lockstep_envs()]
            return ["--workers", "0"]
        return ["--workers", str(self.a.workers)]

    def lockstep_envs(self) -> list[str]:
        """``--envs-per-worker`` of a lockstep evaluation, when ``--eval-envs-per-worker``
        sets it (the bench's default: 4 envs per env process on a GPU)."""
        n = self.a.eval_envs_per_worker
        return [] if n is None else ["--envs-per-worker", str(n)]

    def evaluate(self, task: str, name: str, setting: Setting | None) -> None:
        """``mikasa-bench run`` of a trained setting (``lerobot:<checkpoint>``) or a reference
        policy over ``--eval-episodes`` canonical episodes, into a ``.partial`` run directory."""
        unit = f"eval-{name}"
        train_rec = self.record(task, f"train-{name}") if setting else None
        rec = self.record(task, unit)
        if rec is not None:
            stale = rec.get("n_episodes") != self.a.eval_episodes or (
                train_rec is not None and rec.get("train_finished") != train_rec.get("finished")
            )
            if not stale:
                return
            raise UnitFailed(
                f"{task} {unit}: the recorded evaluation has other settings "
                f"({rec.get('n_episodes')} episodes / another training); remove "
                f"{rel(self.record_path(task, unit))} and {rel(self.eval_dir(task, name))} to redo it"
            )
        if setting is not None:
            ckpt = self.trained(task, name)
            if ckpt is None or train_rec is None:
                raise UnitFailed(f"{task} {unit}: not trained")
            target = f"lerobot:{ckpt}"  # the bench resolves `last` for its label
        else:
            target = name
        self.check_time(task, unit)
        final = self.eval_dir(task, name)
        part = self.partial(final)
        bench = self.cli(self.python, "mikasa-bench", "mikasa_bench.cli")
        common = ["--no-progress", "--no-report"]
        resume = (part / "meta" / "run.json").is_file()
        if resume:
            argv = bench + ["run", "--resume", str(part), *common]
            if _bench_lockstep(part):  # a lockstep run starts its own env processes
                argv += self.lockstep_envs()
            else:
                spread = self.eval_exec(setting)
                argv += spread if spread[0] == "--workers" else ["--workers", "0"]
        else:
            if part.exists():
                shutil.rmtree(part)
            argv = bench + ["run", "--task", task, "--policy", target]
            argv += ["--num-episodes", str(self.a.eval_episodes), "--out", str(part), *common]
            argv += self.eval_exec(setting)
            if setting is not None:
                argv += ["--policy-kwargs", json.dumps({"device": self.device()})]
            if self.a.render_device:
                argv += ["--render-device", self.a.render_device]
        log(f"{task}: evaluate {name} over {self.a.eval_episodes} episodes")

        def tick() -> None:
            journal = part / "meta" / "episodes.jsonl"
            if journal.is_file():
                n = sum(1 for _ in journal.open(encoding="utf-8"))
                log(f"{task}: evaluate {name}: {n}/{self.a.eval_episodes} episodes")

        res = self.run(task, unit, argv, tick=tick)
        entry = {"wall_s": round(res.wall_s, 1), "rc": res.rc, "command": display(argv)}
        calls = self.add_wip(task, unit, entry, fresh=not resume)
        if res.rc in (None, BENCH_INTERRUPTED):
            raise TimeUp(f"{task} {unit}: stopped; the next call resumes the run")
        result = _bench_result(part, task)
        if res.rc != 0 or result is None:
            raise self.fail(task, unit, f"mikasa-bench exit {res.rc}")
        if final.exists():
            shutil.rmtree(final)
        part.rename(final)
        successes = sum(bool(s) for s in result["successes"])
        n = len(result["successes"])
        rec = self.save_record(
            task,
            unit,
            {
                "policy": name,
                "model": (result.get("model") or {}).get("name"),
                "n_episodes": n,
                "successes": successes,
                "sr": result.get("sr"),
                "sr_ci95": list(wilson_interval(successes, n)),
                "mean_return": result.get("mean_return"),
                "mean_episode_length": result.get("mean_episode_length"),
                "canonical": result.get("canonical"),
                "render_device": result.get("render_device"),
                "wall_s": calls_wall_s(calls),
                "calls": len(calls),
                "result": rel(final / f"{task}.json"),
                "command": calls[0]["command"],
                "train_finished": train_rec.get("finished") if train_rec else None,
            },
        )
        lo, hi = rec["sr_ci95"]
        log(
            f"{task}: {name}: SR {rec['successes']}/{rec['n_episodes']} [{lo:.0%}, {hi:.0%}] "
            f"in {rec['wall_s']:.0f} s"
        )
