"""The ``mikasa-bench`` command line: list, run, quickstart, report, compare, serve,
validity, gallery.

Exit codes: 0 success; 1 ``compare`` found a significant regression; 2 a usage or
input error (the message says what was expected); 130 interrupted (results so far are
kept; ``run --resume DIR`` continues).

The command line is split over modules: `mikasa_bench.cli.parser` (the argument parser and
the defaults of its options), `mikasa_bench.cli.run` (``run`` and ``quickstart``),
`mikasa_bench.cli.commands` (``list``, ``report``, ``compare``, ``serve``) and
`mikasa_bench.cli.common` (what they share); ``validity`` and ``gallery`` live with their
code (`mikasa_bench.results.validity`, `mikasa_bench.media.gallery`).
"""

from __future__ import annotations

from collections.abc import Sequence

from mikasa_bench.cli.commands import cmd_compare, cmd_list, cmd_report, cmd_serve
from mikasa_bench.cli.common import eprint
from mikasa_bench.cli.parser import build_parser
from mikasa_bench.cli.run import cmd_quickstart, cmd_run
from mikasa_bench.errors import BenchError
from mikasa_bench.media.gallery import run_gallery
from mikasa_bench.results.validity import run_validity

__all__ = ["main"]

_COMMANDS = {
    "list": cmd_list,
    "run": cmd_run,
    "quickstart": cmd_quickstart,
    "report": cmd_report,
    "compare": cmd_compare,
    "serve": cmd_serve,
    "validity": run_validity,
    "gallery": run_gallery,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mikasa-bench`` script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return _COMMANDS[args.command](args)
    except BenchError as exc:
        eprint(f"error: {exc}")
        return 2
    except KeyboardInterrupt:
        eprint("interrupted")
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
