"""mikasa-bench: evaluate policies on MIKASA-Robo-VLA with the canonical protocol.

Command line: ``mikasa-bench quickstart | list | run | report | compare | serve | validity |
gallery`` (`mikasa_bench.cli`; see the README). Library: the protocol constants, task
selection, the policy interface, the episode loop, the parallel resumable runner and the
result helpers are re-exported here (the README's "Python API" table lists them).

Layout: `errors` at the top; the benchmark's definition in `protocol` (settings) and
`protocol.tasks` (the tasks of the manifest); the machinery in subpackages: `policies` (with
`policies.remote`), `runners`, `results` (with `metrics` and `chance`), `media`, `lerobot`,
`cli`, and the shipped result sets in `reference`.
"""

from .errors import (
    BenchError,
    EpisodeFailedError,
    EpisodeInterrupted,
    PolicyOutputError,
    UnknownTaskError,
)
from .policies.base import ChunkPolicy
from .policies.builtin import BUILTIN_POLICIES, DummyChunkPolicy, RandomPolicy, ZeroPolicy
from .policies.loading import build_policy, resolve_policy
from .policies.spec import PolicySpec
from .protocol import (
    CONTROL_MODE,
    NUM_EPISODES_PER_TASK,
    OBS_MODE,
    REWARD_MODE,
    START_SEED,
    SUPPORTED_SPLITS,
    WRAPPER_CHAIN,
    BenchmarkConfig,
)
from .protocol.tasks import (
    BenchmarkTask,
    benchmark_commit,
    load_benchmark_tasks,
    make_run_dir,
    repository_root,
    resolve_tasks,
    select_benchmark_tasks,
)
from .results.metrics import newcombe_difference_interval, summarize_task_results, wilson_interval
from .results.run_data import RunData, load_run
from .results.store import RunStore
from .results.summary import build_summary, build_task_result, write_benchmark_results
from .runners.episode import EpisodeResult, make_benchmark_env, normalize_action_chunk, run_episode
from .runners.executor import InlineExecutor, LocalExecutor, make_executor
from .runners.jobs import EpisodeJob, EpisodeOutcome, Executor
from .runners.runner import evaluate_benchmark, evaluate_task, execute_runs

__version__ = "0.2.0"

__all__ = [
    "START_SEED",
    "NUM_EPISODES_PER_TASK",
    "OBS_MODE",
    "CONTROL_MODE",
    "REWARD_MODE",
    "WRAPPER_CHAIN",
    "SUPPORTED_SPLITS",
    "BenchmarkConfig",
    "BenchmarkTask",
    "load_benchmark_tasks",
    "select_benchmark_tasks",
    "resolve_tasks",
    "repository_root",
    "make_run_dir",
    "benchmark_commit",
    "ChunkPolicy",
    "ZeroPolicy",
    "RandomPolicy",
    "DummyChunkPolicy",
    "PolicySpec",
    "BUILTIN_POLICIES",
    "resolve_policy",
    "build_policy",
    "EpisodeResult",
    "make_benchmark_env",
    "normalize_action_chunk",
    "run_episode",
    "evaluate_task",
    "evaluate_benchmark",
    "execute_runs",
    "EpisodeJob",
    "EpisodeOutcome",
    "Executor",
    "LocalExecutor",
    "InlineExecutor",
    "make_executor",
    "wilson_interval",
    "newcombe_difference_interval",
    "summarize_task_results",
    "build_summary",
    "build_task_result",
    "write_benchmark_results",
    "RunStore",
    "RunData",
    "load_run",
    "BenchError",
    "UnknownTaskError",
    "PolicyOutputError",
    "EpisodeInterrupted",
    "EpisodeFailedError",
    "__version__",
]
