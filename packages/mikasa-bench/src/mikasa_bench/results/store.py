"""The run store: all state of one run directory and the only writer of its files.

`RunStore` creates a run directory (or reopens one to resume it), journals every finished
episode (``meta/episodes.jsonl``, fsync'ed), writes a task's result file when its last
episode is in and rewrites the summary; file names and layout: `mikasa_bench.results.files`.
The journal makes ``--resume`` lossless even after ``kill -9``: episodes of unfinished
tasks are recovered from it, a torn last line is dropped, and an episode already recorded
is never run again.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.media.video import video_relpath
from mikasa_bench.policies.spec import PolicySpec
from mikasa_bench.protocol import BenchmarkConfig, package_versions, protocol_settings
from mikasa_bench.protocol.tasks import BenchmarkTask
from mikasa_bench.results.files import (
    JOURNAL_FILENAME,
    META_DIRNAME,
    RUN_META_FILENAME,
    SUMMARY_FILENAME,
    atomic_write_bytes,
    atomic_write_json,
    read_json,
)
from mikasa_bench.results.summary import build_summary, build_task_result
from mikasa_bench.runners.episode import EpisodeResult

__all__ = ["RunStore", "RUN_FORMAT"]

RUN_FORMAT = "mikasa-bench-run/1"


def _now() -> str:
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="seconds")


@dataclass
class _Session:
    started: str
    t0: float
    prior_wall_s: float


@dataclass
class RunStore:
    """All state of one run directory; the only writer of its files.

    Create with `RunStore.create` (fresh directory) or `RunStore.open` (resume).
    """

    run_dir: Path
    tasks: list[BenchmarkTask]
    policy: PolicySpec
    config: BenchmarkConfig
    selection: dict[str, Any]
    commit: str | None
    meta: dict[str, Any]
    finished: dict[str, dict[str, Any]] = field(default_factory=dict)
    partial: dict[str, dict[int, dict[str, Any]]] = field(default_factory=dict)
    _session: _Session | None = None

    # -- paths ---------------------------------------------------------------------
    @property
    def meta_dir(self) -> Path:
        """``<run_dir>/meta``."""
        return self.run_dir / META_DIRNAME

    @property
    def journal_path(self) -> Path:
        """The episode journal."""
        return self.meta_dir / JOURNAL_FILENAME

    # -- construction --------------------------------------------------------------
    @classmethod
    def create(
        cls,
        run_dir: str | Path,
        *,
        tasks: Sequence[BenchmarkTask],
        policy: PolicySpec,
        config: BenchmarkConfig,
        selection: Mapping[str, Any],
        commit: str | None,
    ) -> RunStore:
        """Start a fresh run in ``run_dir``, which must not exist or be empty (nothing
        already there is ever overwritten)."""
        run_dir = Path(run_dir)
        if run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())):
            raise BenchError(
                f"output directory {run_dir} already exists and is not empty; continue it "
                f"with `mikasa-bench run --resume {run_dir}` or choose another --out"
            )
        meta = {
            "format": RUN_FORMAT,
            "created": _now(),
            "policy": policy.to_dict(),
            "model": policy.model_record(),
            "config": config.to_dict(),
            "protocol": protocol_settings(config),
            "selection": dict(selection),
            "tasks": [t.to_dict() for t in tasks],
            "benchmark_commit": commit,
            "versions": package_versions(),
            "sessions": [],
        }
        store = cls(run_dir, list(tasks), policy, config, dict(selection), commit, meta)
        atomic_write_json(store.meta_dir / RUN_META_FILENAME, meta)
        store.journal_path.touch()
        return store

    @classmethod
    def open(cls, run_dir: str | Path) -> RunStore:
        """Reopen ``run_dir`` to resume it: its settings, finished tasks and journal."""
        run_dir = Path(run_dir)
        meta_path = run_dir / META_DIRNAME / RUN_META_FILENAME
        if not run_dir.is_dir():
            raise BenchError(f"cannot resume: {run_dir} is not a directory")
        if not meta_path.is_file():
            raise BenchError(
                f"cannot resume {run_dir}: it has no {META_DIRNAME}/{RUN_META_FILENAME}; "
                f"expected a run directory created by `mikasa-bench run`"
            )
        meta = read_json(meta_path)
        if meta.get("format") != RUN_FORMAT:
            raise BenchError(
                f"{meta_path}: unknown format {meta.get('format')!r}, expected {RUN_FORMAT}"
            )
        try:
            tasks = [BenchmarkTask(**t) for t in meta["tasks"]]
            policy = PolicySpec.from_dict(meta["policy"])
            config = BenchmarkConfig(**meta["config"])
        except (KeyError, TypeError) as exc:
            raise BenchError(f"{meta_path} is damaged: {exc}") from None
        store = cls(
            run_dir,
            tasks,
            policy,
            config,
            meta.get("selection", {}),
            meta.get("benchmark_commit"),
            meta,
        )
        store._load_existing()
        return store

    def _load_existing(self) -> None:
        seeds = self.config.episode_seeds()
        for task in self.tasks:
            path = self.run_dir / f"{task.env_id}.json"
            if not path.exists():
                continue
            result = read_json(path)
            if result.get("episode_seeds") != seeds or len(result.get("successes", [])) != len(
                seeds
            ):
                raise BenchError(
                    f"{path} does not match this run's protocol (expected {len(seeds)} episodes "
                    f"with seeds {seeds[0]}..{seeds[-1]}); refusing to mix results"
                )
            self.finished[task.env_id] = result
        known = {t.env_id for t in self.tasks}
        for rec in self._read_journal():
            env_id, idx = rec["env_id"], int(rec["episode"])
            if env_id not in known or env_id in self.finished:
                continue
            if not 0 <= idx < len(seeds) or int(rec["seed"]) != seeds[idx]:
                raise BenchError(
                    f"{self.journal_path}: episode {idx} of {env_id} has seed {rec['seed']}, "
                    f"which does not match this run's protocol"
                )
            # First record wins: an episode is never counted twice.
            self.partial.setdefault(env_id, {}).setdefault(idx, rec)

    def _read_journal(self) -> list[dict[str, Any]]:
        """Parse the journal, dropping (and truncating away) a torn last line."""
        path = self.journal_path
        if not path.exists():
            return []
        data = path.read_bytes()
        end = data.rfind(b"\n") + 1
        if end != len(data):
            # kill -9 during an append: cut the partial line so the next append starts
            # on a fresh line.
            with open(path, "r+b") as f:
                f.truncate(end)
            data = data[:end]
        out = []
        for n, line in enumerate(data.decode("utf-8").splitlines(), start=1):
            if not line.strip():
                continue
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                raise BenchError(f"{path}: line {n} is not valid JSON") from None
        return out

    # -- progress ------------------------------------------------------------------
    def pending(self) -> list[tuple[BenchmarkTask, int]]:
        """``(task, episode index)`` of every episode still to run, in task/seed order."""
        out = []
        for task in self.tasks:
            if task.env_id in self.finished:
                continue
            done = self.partial.get(task.env_id, {})
            out += [(task, i) for i in range(self.config.n_episodes) if i not in done]
        return out

    @property
    def n_done_episodes(self) -> int:
        """Episodes already recorded (finished tasks plus journal)."""
        return self.config.n_episodes * len(self.finished) + sum(
            len(v) for v in self.partial.values()
        )

    def begin_session(self, execution: Mapping[str, Any] | None = None) -> None:
        """Start timing this process's share of the run; ``execution`` (the executor's
        description: name, workers, Ray address) is recorded with the session."""
        prior = sum(float(s.get("wall_time_s", 0.0)) for s in self.meta.get("sessions", []))
        self._session = _Session(_now(), time.perf_counter(), prior)
        record: dict[str, Any] = {"started": self._session.started, "wall_time_s": 0.0}
        if execution is not None:
            record["execution"] = dict(execution)
        self.meta.setdefault("sessions", []).append(record)
        self._save_meta()  # on disk at once: a session killed before any task ends still counts

    def wall_time_s(self) -> float:
        """Wall time of all sessions so far, this one included."""
        if self._session is None:
            return sum(float(s.get("wall_time_s", 0.0)) for s in self.meta.get("sessions", []))
        return self._session.prior_wall_s + (time.perf_counter() - self._session.t0)

    def _save_meta(self) -> None:
        if self._session is not None:
            self.meta["sessions"][-1]["wall_time_s"] = time.perf_counter() - self._session.t0
            self.meta["sessions"][-1]["updated"] = _now()
        atomic_write_json(self.meta_dir / RUN_META_FILENAME, self.meta)

    # -- recording -----------------------------------------------------------------
    def save_video(self, env_id: str, episode: int, data: bytes) -> str:
        """Write an episode's mp4 atomically; returns its path relative to the run dir.

        Called before the episode is journalled: an episode that was recorded always has
        its video; a video without a journal line (crash in between) is simply replaced
        when ``--resume`` reruns the episode.
        """
        rel = video_relpath(env_id, episode)
        atomic_write_bytes(self.run_dir / rel, data)
        return rel

    def record_episode(
        self,
        env_id: str,
        episode: int,
        result: EpisodeResult,
        *,
        action_chunk_size: int,
        wall_s: float,
        video: str | None = None,
        render: str | None = None,
        restarts: int = 0,
    ) -> dict[str, Any] | None:
        """Journal one finished episode; when it completes its task, write the task file
        and the summary and return the task result (else None). ``video``: its path
        relative to the run dir; ``render``: where the worker rendered; ``restarts``: how
        often it was played again from its reset (`EpisodeOutcome.restarts`)."""
        if env_id in self.finished or episode in self.partial.get(env_id, {}):
            raise RuntimeError(f"episode {episode} of {env_id} recorded twice")
        rec = {
            "env_id": env_id,
            "episode": int(episode),
            "seed": int(result.seed),
            "success_once": bool(result.success_once),
            "episode_return": float(result.episode_return),
            "n_steps": int(result.n_steps),
            "action_chunk_size": int(action_chunk_size),
            "action_chunk_sizes": [int(k) for k in result.chunk_sizes],
            "restarts": int(restarts),
            "wall_s": float(wall_s),
        }
        if video is not None:
            rec["video"] = video
        if render is not None:
            rec["render"] = render
        if self._session is not None:
            # Which session ran it (index into run.json's sessions): per-session throughput.
            rec["session"] = len(self.meta["sessions"]) - 1
        with open(self.journal_path, "a", encoding="utf-8") as f:
            f.write(json.dumps(rec) + "\n")
            f.flush()
            os.fsync(f.fileno())
        done = self.partial.setdefault(env_id, {})
        done[int(episode)] = rec
        if len(done) < self.config.n_episodes:
            return None
        return self._finish_task(env_id)

    def _finish_task(self, env_id: str) -> dict[str, Any]:
        task = next(t for t in self.tasks if t.env_id == env_id)
        recs = [self.partial[env_id][i] for i in range(self.config.n_episodes)]
        episodes = [
            EpisodeResult(
                r["success_once"],
                r["episode_return"],
                r["n_steps"],
                r["seed"],
                tuple(r.get("action_chunk_sizes", ())),  # journals of older versions lack it
            )
            for r in recs
        ]
        result = build_task_result(
            task,
            self.config,
            episodes,
            action_chunk_size=max(r["action_chunk_size"] for r in recs),
            model=self.meta["model"],
            commit=self.commit,
            wall_time_s=sum(r["wall_s"] for r in recs),
            videos=[r.get("video") for r in recs] if self.config.save_videos else None,
            restarts=[r.get("restarts", 0) for r in recs],
        )
        atomic_write_json(self.run_dir / f"{env_id}.json", result)
        self.finished[env_id] = result
        self.partial.pop(env_id, None)
        self.write_summary()
        return result

    def ordered_results(self) -> list[dict[str, Any]]:
        """Finished task results in the run's task order."""
        return [self.finished[t.env_id] for t in self.tasks if t.env_id in self.finished]

    def summary(self) -> dict[str, Any] | None:
        """The summary of the finished tasks (None if none is finished)."""
        results = self.ordered_results()
        if not results:
            return None
        pending = [t.env_id for t in self.tasks if t.env_id not in self.finished]
        return build_summary(
            results,
            complete=not pending,
            tasks_pending=pending,
            benchmark_commit=self.commit,
            model=self.meta["model"],
            protocol=self.meta["protocol"],
            selection=self.selection,
            versions=self.meta["versions"],
            wall_time_s=self.wall_time_s(),
            created=self.meta["created"],
            updated=_now(),
        )

    def write_summary(self) -> dict[str, Any] | None:
        """Rewrite summary.json (and the session record) from all finished tasks."""
        self._save_meta()
        summary = self.summary()
        if summary is not None:
            atomic_write_json(self.run_dir / SUMMARY_FILENAME, summary)
        return summary
