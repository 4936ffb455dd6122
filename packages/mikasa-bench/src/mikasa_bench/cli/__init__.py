"""The ``mikasa-bench`` command line (the console script calls `main`); see
`mikasa_bench.cli.main` for its modules."""

from mikasa_bench.cli.main import main
from mikasa_bench.cli.parser import QUICKSTART_POLICIES, QUICKSTART_TASKS, build_parser

__all__ = ["main", "build_parser", "QUICKSTART_TASKS", "QUICKSTART_POLICIES"]
