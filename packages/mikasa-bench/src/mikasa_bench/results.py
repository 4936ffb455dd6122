"""Result files: per-task JSON, summary.json, the run store with its episode journal.

Layout of a run directory::

    <run_dir>/<env_id>.json        per-task result (benchmark.md §7.1 keys, then extensions)
    <run_dir>/summary.json         summary of the finished tasks (§7.2 keys, then extensions)
    <run_dir>/meta/run.json        what the run is: tasks, policy, protocol, sessions
    <run_dir>/meta/episodes.jsonl  journal: one line per finished episode (fsync'ed)
    <run_dir>/videos/<env_id>/episode_<i:04d>.mp4   with ``save_videos`` (written before
                                   the episode's journal line)

Every JSON file is replaced atomically (temp file + ``os.replace``), so a reader never
sees half a file. The journal makes ``--resume`` lossless even after ``kill -9``: episodes
of unfinished tasks are recovered from it, a torn last line is dropped, and an episode
already recorded is never run again.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from .episode import EpisodeResult
from .errors import BenchError
from .metrics import aggregate_by, summarize_task_results, wilson_interval
from .policies import PolicySpec
from .protocol import NUM_ENVS, BenchmarkConfig, package_versions, protocol_settings
from .tasks import BenchmarkTask

__all__ = [
    "SUMMARY_FILENAME",
    "META_DIRNAME",
    "atomic_write_json",
    "build_task_result",
    "build_summary",
    "write_benchmark_results",
    "RunStore",
    "RunData",
    "load_run",
]

SUMMARY_FILENAME = "summary.json"
META_DIRNAME = "meta"
RUN_META_FILENAME = "run.json"
JOURNAL_FILENAME = "episodes.jsonl"
RUN_FORMAT = "mikasa-bench-run/1"


def _now() -> str:
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="seconds")


def _json_safe(x: Any) -> Any:
    """NaN/inf are not JSON: write them as null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` via a temp file in the same directory, fsync, then ``os.replace``:
    readers (and a crash at any point) see the old file or the new one, never a mix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The temp name starts with '.' and ends in '.tmp': globs for *.json never see it.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp creates 0600; results and videos get the usual umask-based mode so
        # others can read a shared results directory.
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def atomic_write_json(path: str | Path, data: Any) -> None:
    """Write ``data`` atomically as indented UTF-8 JSON (keys in insertion order, trailing
    newline; NaN/inf become null)."""
    text = json.dumps(_json_safe(data), indent=2, ensure_ascii=False) + "\n"
    _atomic_write_bytes(path, text.encode("utf-8"))


def build_task_result(
    task: BenchmarkTask,
    config: BenchmarkConfig,
    episodes: Sequence[EpisodeResult],
    *,
    action_chunk_size: int = 1,
    model: Mapping[str, Any] | None = None,
    commit: str | None = None,
    wall_time_s: float | None = None,
    videos: Sequence[str | None] | None = None,
    restarts: Sequence[int] | None = None,
) -> dict[str, Any]:
    """The per-task result dict: the keys of benchmark.md §7.1 in order, then extensions
    (``sr_ci95``, ``mean_episode_length``, the remaining protocol settings, wall time,
    ``action_chunk_size_varied`` (whether the policy's chunks had more than one length K;
    ``action_chunk_size`` is the largest), ``episode_restarts`` (how often each episode was
    played again from its reset after its policy lost it, e.g. a dropped server
    connection) and, with videos, each episode's video path relative to the run
    directory)."""
    if len(episodes) != config.n_episodes:
        raise ValueError(f"{task.env_id}: {len(episodes)} episodes, expected {config.n_episodes}")
    successes = [bool(e.success_once) for e in episodes]
    returns = [float(e.episode_return) for e in episodes]
    lengths = [int(e.n_steps) for e in episodes]
    n = len(successes)
    chunk_sizes = {k for e in episodes for k in e.chunk_sizes}
    lo, hi = wilson_interval(sum(successes), n)
    settings = protocol_settings(config)
    out = {
        "env_id": task.env_id,
        "split": task.split.title(),
        "memory_type": task.memory_type,
        "start_seed": config.start_seed,
        "n_episodes": config.n_episodes,
        "successes": successes,
        "returns": returns,
        "sr": sum(successes) / n,
        "mean_return": sum(returns) / n,
        "benchmark_commit": commit,
        "control_mode": config.control_mode,
        "obs_mode": config.obs_mode,
        "wrapper_chain": config.wrapper_chain,
        "action_chunk_size": max(chunk_sizes | {int(action_chunk_size)}),
        "model": dict(model or {}),
        "episode_lengths": lengths,
        "episode_seeds": [int(e.seed) for e in episodes],
        # --- extensions (extra keys only, see benchmark.md §10) ---
        "sr_ci95": [lo, hi],
        "mean_episode_length": sum(lengths) / n,
        "reward_mode": config.reward_mode,
        "sim_backend": config.sim_backend,
        "include_overlays": config.include_overlays,
        "num_envs": NUM_ENVS,
        "render_device": settings["render_device"],
        "policy_batch": config.policy_batch,
        "canonical": settings["canonical"],
        "wall_time_s": wall_time_s,
        "action_chunk_size_varied": len(chunk_sizes) > 1,
        "episode_restarts": [int(r) for r in restarts] if restarts is not None else [0] * n,
    }
    if videos is not None:
        out["videos"] = list(videos)
    return out


def build_summary(results: Sequence[Mapping[str, Any]], **extensions: Any) -> dict[str, Any]:
    """`summarize_task_results` plus per-task CIs, per-split and per-split-per-memory-type
    success rates, then ``extensions`` (protocol, versions, wall time, ...) in order."""
    summary = summarize_task_results(results)
    per_task = {r["env_id"]: r for r in results}
    summary["per_task_sr_ci95"] = {
        k: list(wilson_interval(sum(bool(s) for s in r["successes"]), len(r["successes"])))
        for k, r in per_task.items()
    }
    uniq = list(per_task.values())
    summary["sr_per_split"] = aggregate_by(uniq, "split")
    summary["sr_per_split_memory_type"] = {
        s: dict(sorted(d.items())) for s, d in aggregate_by(uniq, "split", "memory_type").items()
    }
    summary["n_tasks"] = len(uniq)
    summary["n_episodes_total"] = sum(len(r["successes"]) for r in uniq)
    summary.update(extensions)
    return summary


def write_benchmark_results(
    output_dir: str | Path,
    task_results: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
) -> None:
    """Write every ``<env_id>.json`` and ``summary.json`` into ``output_dir``."""
    out = Path(output_dir)
    for r in task_results:
        atomic_write_json(out / f"{r['env_id']}.json", r)
    atomic_write_json(out / SUMMARY_FILENAME, summary)


# ------------------------------------------------------------------------------------
# run store (used by the runner: create / resume, journal, per-task files, summary)
# ------------------------------------------------------------------------------------


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
        meta = _read_json(meta_path)
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
            result = _read_json(path)
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
        from .video import video_relpath

        rel = video_relpath(env_id, episode)
        _atomic_write_bytes(self.run_dir / rel, data)
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


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise BenchError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BenchError(f"{path} is not valid JSON ({exc})") from None


# ------------------------------------------------------------------------------------
# reading finished runs (report / compare)
# ------------------------------------------------------------------------------------

_TASK_KEYS = ("env_id", "split", "memory_type", "successes", "returns", "sr")


@dataclass
class RunData:
    """A results directory as read back: per-task results (in run order), the summary."""

    run_dir: Path
    label: str
    results: list[dict[str, Any]]
    summary: dict[str, Any] | None
    source: str = ""  # how the user named it, where that is not the path (reference:<name>)

    @property
    def protocol(self) -> dict[str, Any]:
        """The summary's protocol record, or one reconstructed from the task files."""
        if self.summary and isinstance(self.summary.get("protocol"), dict):
            return self.summary["protocol"]
        r = self.results[0]
        return {k: r.get(k) for k in ("start_seed", "n_episodes", "obs_mode", "control_mode")}


def load_run(run_dir: str | Path, label: str | None = None) -> RunData:
    """Read a results directory (every ``*.json`` but ``summary.json`` is a task file), or a
    result set shipped with the package, named ``reference:<name>`` (`mikasa_bench.reference`).

    Raises `BenchError` if the directory is missing, unreadable, holds a malformed file, or
    has no task results, or if there is no reference set of that name.
    """
    from .reference import is_reference, resolve_reference

    source = str(run_dir) if is_reference(run_dir) else ""
    run_dir = resolve_reference(source) if source else Path(run_dir)
    if not run_dir.is_dir():
        raise BenchError(
            f"results directory {run_dir} does not exist; expected a directory written by "
            f"`mikasa-bench run` (with <env_id>.json files and summary.json)"
        )
    try:
        files = sorted(p for p in run_dir.glob("*.json") if p.name != SUMMARY_FILENAME)
    except OSError as exc:
        raise BenchError(f"cannot read results directory {run_dir}: {exc}") from None
    by_id: dict[str, dict[str, Any]] = {}
    for path in files:
        data = _read_json(path)
        if not isinstance(data, dict) or not all(k in data for k in _TASK_KEYS):
            continue  # not a task result (e.g. a user's note): ignored like upstream's loader
        by_id[data["env_id"]] = data
    if not by_id:
        raise BenchError(
            f"{run_dir} contains no per-task result files; expected <env_id>.json files with "
            f"keys {', '.join(_TASK_KEYS)} written by `mikasa-bench run`"
        )
    summary_path = run_dir / SUMMARY_FILENAME
    summary = _read_json(summary_path) if summary_path.exists() else None
    order: Iterable[str] = (summary or {}).get("tasks") or []
    ordered = [by_id[i] for i in order if i in by_id]
    ordered += [r for i, r in by_id.items() if i not in set(order)]
    if label is None:
        model = (summary or {}).get("model") or ordered[0].get("model") or {}
        label = model.get("name") or run_dir.name
    return RunData(run_dir, str(label), ordered, summary, source)
