"""Running episodes: the episode loop, the executors that spread episodes over workers and
the resumable runner that records them.

* `mikasa_bench.runners.episode`: `make_benchmark_env` and `run_episode`, the one place a
  policy meets an env;
* `mikasa_bench.runners.jobs`: `EpisodeJob`, `EpisodeOutcome` and the `Executor` interface;
* `mikasa_bench.runners.worker`: `EpisodeWorker`, what every executor runs per worker;
* `mikasa_bench.runners.scheduler`: `Scheduler`, which worker gets which job next;
* `mikasa_bench.runners.executor`: the local process pool and the inline executor,
  `make_executor`;
* `mikasa_bench.runners.ray_executor`: ``--executor ray`` (``pip install 'mikasa-bench[ray]'``);
* `mikasa_bench.runners.lockstep`: ``--policy-batch B``, B episodes in lockstep;
* `mikasa_bench.runners.runner`: `execute_runs` (parallel, resumable) and the sequential
  `evaluate_task` / `evaluate_benchmark`.

Import names from those modules; this package file imports nothing.
"""
