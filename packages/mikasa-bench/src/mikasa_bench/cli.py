"""The ``mikasa-bench`` command line: list, run, quickstart, report, compare, serve.

Exit codes: 0 success; 1 ``compare`` found a significant regression; 2 a usage or
input error (the message says what was expected); 130 interrupted (results so far are
kept; ``run --resume DIR`` continues).

The command line is split over modules: ``cli_parser`` (the argument parser and the
defaults of its options), ``cli_run`` (``run`` and ``quickstart``) and ``cli_commands``
(``list``, ``report``, ``compare``, ``serve``); every name is re-exported here.
"""

from __future__ import annotations

from collections.abc import Sequence

from mikasa_bench.media.gallery import add_gallery_parser, run_gallery  # noqa: F401  (re-exported)
from mikasa_bench.results.validity import add_validity_parser, run_validity  # noqa: F401  (re-exported)

from .cli_commands import _cmd_compare, _cmd_list, _cmd_report, _cmd_serve
from .cli_parser import (  # noqa: F401  (re-exported)
    DEFAULT_SIM_BACKEND,
    QUICKSTART_EPISODES,
    QUICKSTART_POLICIES,
    QUICKSTART_TASKS,
    QUICKSTART_WORKERS,
    _add_exec_args,
    build_parser,
)
from .cli_run import (  # noqa: F401  (re-exported)
    _RUN_DEFINING,
    _cmd_quickstart,
    _cmd_run,
    _config,
    _eprint,
    _execute_and_report,
    _executor_from,
    _lockstep_executor,
    _parse_kwargs,
    _resume_dirs,
    _resume_hint,
)
from .errors import BenchError
from .protocol import (  # noqa: F401  (re-exported)
    CONTROL_MODE,
    NUM_EPISODES_PER_TASK,
    OBS_MODE,
    RENDER_DEVICES,
    REWARD_MODE,
    START_SEED,
    SUPPORTED_OBS_MODES,
    SUPPORTED_SPLITS,
    BenchmarkConfig,
)

__all__ = ["main", "build_parser", "QUICKSTART_TASKS", "QUICKSTART_POLICIES"]

_COMMANDS = {
    "list": _cmd_list,
    "run": _cmd_run,
    "quickstart": _cmd_quickstart,
    "report": _cmd_report,
    "compare": _cmd_compare,
    "serve": _cmd_serve,
    "validity": run_validity,
    "gallery": run_gallery,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mikasa-bench`` script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return _COMMANDS[args.command](args)
    except BenchError as exc:
        _eprint(f"error: {exc}")
        return 2
    except KeyboardInterrupt:
        _eprint("interrupted")
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
