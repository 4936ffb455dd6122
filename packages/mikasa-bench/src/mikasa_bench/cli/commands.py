"""The ``list``, ``report``, ``compare`` and ``serve`` subcommands of ``mikasa-bench``."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

from mikasa_bench.cli.common import eprint, parse_policy_kwargs
from mikasa_bench.errors import BenchError
from mikasa_bench.policies.loading import resolve_policy
from mikasa_bench.policies.oracle_extra import ORACLES_INSTALL_COMMAND, require_oracles
from mikasa_bench.policies.remote.server import PolicyServer
from mikasa_bench.protocol.tasks import registered_env_ids, select_benchmark_tasks
from mikasa_bench.reference import is_reference
from mikasa_bench.results.compare import compare_runs, format_comparison
from mikasa_bench.results.report import text_table, write_report
from mikasa_bench.results.run_data import load_run
from mikasa_bench.results.text import format_rows

# ------------------------------------------------------------------------------------
# list
# ------------------------------------------------------------------------------------


def cmd_list(args: argparse.Namespace) -> int:
    """``mikasa-bench list``: the benchmark tasks, registered or not, with their oracle."""
    tasks = select_benchmark_tasks(split=args.split)
    if args.memory_type:
        known = sorted({t.memory_type for t in tasks})
        if args.memory_type not in known:
            raise BenchError(
                f"unknown memory type {args.memory_type!r}; expected one of {', '.join(known)}"
            )
        tasks = [t for t in tasks if t.memory_type == args.memory_type]
    registered = registered_env_ids()
    try:
        has_oracle = require_oracles().has_oracle
    except BenchError:
        has_oracle = None  # without the oracles extra the column says "n/a"
    rows = []
    for t in tasks:
        reg = t.env_id in registered
        if args.registered_only and not reg:
            continue
        rows.append(
            [
                t.env_id,
                t.split.title(),
                t.memory_type,
                str(t.max_episode_steps),
                "yes" if reg else "no",
                "n/a" if has_oracle is None else "yes" if has_oracle(t.env_id) else "no",
            ]
        )
    print(
        format_rows(
            ["Env id", "Split", "Memory type", "Max steps", "Registered", "Oracle"], rows, right={3}
        )
    )
    n_reg = sum(r[4] == "yes" for r in rows)
    print(f"\n{len(rows)} task(s), {n_reg} registered")
    if has_oracle is None:
        print(f"Oracle n/a: mikasa-oracles is not installed ({ORACLES_INSTALL_COMMAND})")
    return 0


# ------------------------------------------------------------------------------------
# report / compare
# ------------------------------------------------------------------------------------


def cmd_report(args: argparse.Namespace) -> int:
    """``mikasa-bench report``: the text table, then report.md and report.html."""
    if not args.out and any(is_reference(d) for d in args.dirs):
        raise BenchError("reference result sets are read-only: give --out DIR for the report")
    runs = [load_run(d) for d in args.dirs]
    labels = [r.label for r in runs]
    if len(set(labels)) != len(labels):
        # Same policy in several dirs: tell them apart by directory name.
        for r in runs:
            r.label = f"{r.label} ({r.run_dir.name})"
    if args.out:
        out = Path(args.out)
    elif len(runs) == 1:
        out = runs[0].run_dir
    else:
        out = Path(os.path.commonpath([str(r.run_dir.resolve()) for r in runs]))
    print(text_table(runs))
    md, html_path = write_report(runs, out, title=args.title)
    print(f"\nreport: {md}\n        {html_path}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """``mikasa-bench compare``: per-task deltas of B against A; 1 if B is significantly
    worse on any task."""
    a, b = load_run(args.dir_a), load_run(args.dir_b)
    if a.label == b.label:
        a.label, b.label = f"A: {a.label}", f"B: {b.label}"
    try:
        comp = compare_runs(a, b, alpha=args.alpha)
    except ValueError as exc:
        raise BenchError(str(exc)) from None
    print(format_comparison(comp))
    return 1 if comp.regressions else 0


def cmd_serve(args: argparse.Namespace) -> int:
    """``mikasa-bench serve``: serve a policy over a websocket until Ctrl-C."""
    spec = resolve_policy(args.policy, parse_policy_kwargs(args.policy_kwargs))
    server = PolicyServer(spec, host=args.host, port=args.port)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("websockets").setLevel(logging.WARNING)

    def ready(s: PolicyServer) -> None:
        eprint(
            f"serving policy {spec.label or spec.target!r} on {args.host}:{s.port}; "
            f"evaluate it with: mikasa-bench run --policy ws://HOST:{s.port} ... (Ctrl-C stops)"
        )

    try:
        server.serve_forever(on_ready=ready)
    except KeyboardInterrupt:
        eprint("stopped")
    return 0
