"""The argument parser of ``mikasa-bench`` (every subcommand and its options) and the
defaults those options show: quickstart's tasks, policies, episodes and workers, and the
sim backend of a run."""

from __future__ import annotations

import argparse

from mikasa_bench.media.gallery import add_gallery_parser
from mikasa_bench.protocol import (
    CONTROL_MODE,
    NUM_EPISODES_PER_TASK,
    OBS_MODE,
    RENDER_DEVICES,
    REWARD_MODE,
    START_SEED,
    SUPPORTED_OBS_MODES,
    SUPPORTED_SPLITS,
)
from mikasa_bench.results.validity import add_validity_parser

QUICKSTART_TASKS: tuple[str, ...] = (
    "RememberColor3-VLA-v0",
    "FindImposterColor3-VLA-v0",
    "RememberShape3-VLA-v0",
)
QUICKSTART_POLICIES: tuple[str, ...] = ("oracle", "zero")
QUICKSTART_EPISODES = 2
QUICKSTART_WORKERS = 2
DEFAULT_SIM_BACKEND = "cpu"  # the local executor's workers each simulate one env on the CPU


# ------------------------------------------------------------------------------------
# parser
# ------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of all subcommands."""
    p = argparse.ArgumentParser(
        prog="mikasa-bench",
        description="Evaluate policies on MIKASA-Robo-VLA with the canonical protocol.",
    )
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    ls = sub.add_parser("list", help="list the benchmark tasks (registered or not)")
    ls.add_argument("--split", choices=SUPPORTED_SPLITS, default="all")
    ls.add_argument("--memory-type", default=None, help="only this memory type (e.g. Object)")
    ls.add_argument("--registered-only", action="store_true", help="hide unregistered ids")

    run = sub.add_parser(
        "run",
        help="evaluate a policy on a split or on given tasks",
        description="Evaluate one or more policies. Canonical defaults: 50 episodes per task, "
        f"seeds {START_SEED}+i, obs {OBS_MODE}, control {CONTROL_MODE}, reward {REWARD_MODE}.",
    )
    sel = run.add_mutually_exclusive_group()
    sel.add_argument("--split", default=None, help=f"one of {', '.join(SUPPORTED_SPLITS)}")
    sel.add_argument(
        "--task", action="append", default=None, metavar="ENV_ID", help="an env id (repeatable)"
    )
    sel.add_argument(
        "--resume",
        default=None,
        metavar="DIR",
        help="continue an interrupted run directory (or a directory of runs)",
    )
    run.add_argument(
        "--policy",
        action="append",
        default=None,
        metavar="POLICY",
        help="zero | random | oracle | oracle-memoryless | module:Class | path/file.py[:Class] | ws://HOST:PORT "
        "(a policy server) | lerobot:DIR (a LeRobot pretrained_model directory; repeatable: "
        "each policy gets its own run directory)",
    )
    run.add_argument(
        "--policy-kwargs",
        default=None,
        metavar="JSON",
        help="keyword arguments for the policy, e.g. '{\"seed\": 1}'",
    )
    run.add_argument(
        "--num-episodes",
        type=int,
        default=None,
        help=f"episodes per task (canonical {NUM_EPISODES_PER_TASK})",
    )
    run.add_argument(
        "--start-seed", type=int, default=None, help=f"seed of episode 0 (canonical {START_SEED})"
    )
    run.add_argument(
        "--obs-mode",
        choices=SUPPORTED_OBS_MODES,
        default=None,
        help="rgb (canonical) or state (fast, NON-canonical, recorded as such)",
    )
    run.add_argument(
        "--sim-backend", default=None, help=f"ManiSkill sim backend (default {DEFAULT_SIM_BACKEND})"
    )
    run.add_argument(
        "--video",
        action="store_true",
        default=None,
        help="record every episode as videos/<env_id>/episode_<i>.mp4 (scene view with the "
        "task's overlays beside the top and wrist cameras); results are unchanged",
    )
    run.add_argument(
        "--render-device",
        choices=RENDER_DEVICES,
        default=None,
        help="where workers render: auto (GPU if any, else CPU; default), cpu (lavapipe, "
        "also on a machine with a GPU) or gpu",
    )
    run.add_argument(
        "--gpu-render-workers",
        type=int,
        default=None,
        metavar="N",
        help="mixed pool, with --render-device cpu: the first N workers render on the GPU, "
        "the others on the CPU",
    )
    run.add_argument(
        "--policy-batch",
        type=int,
        default=None,
        metavar="B",
        help="play B episodes in lockstep with one policy call per step for all, the policy in "
        "this process and the envs in processes of --envs-per-worker each: for learned "
        "policies on a GPU (lerobot:DIR, or a class with forward_batch); replaces --workers; a "
        "stochastic policy's results depend on B",
    )
    out = run.add_mutually_exclusive_group()
    out.add_argument("--out", default=None, metavar="DIR", help="exact run directory")
    out.add_argument(
        "--output-dir",
        default=None,
        metavar="BASE",
        help="base directory; the run goes to BASE/<split>/<timestamp> (default results)",
    )
    run.add_argument("--csv", default=None, metavar="PATH", help="task manifest override")
    _add_exec_args(run, default_workers=None)
    run.add_argument(
        "--strict",
        action="store_true",
        help="error (instead of skipping) on unregistered tasks of a split",
    )
    run.add_argument("--no-report", action="store_true", help="skip the Markdown/HTML report")

    qs = sub.add_parser(
        "quickstart",
        help="oracle and zero policies on 3 short tasks, 2 episodes each; table + report",
    )
    qs.add_argument("--out", default="results/quickstart", metavar="DIR")
    qs.add_argument("--episodes", type=int, default=QUICKSTART_EPISODES)
    qs.add_argument("--obs-mode", choices=SUPPORTED_OBS_MODES, default=OBS_MODE)
    _add_exec_args(qs, default_workers=QUICKSTART_WORKERS)

    rep = sub.add_parser("report", help="write report.md and report.html for result dirs")
    rep.add_argument(
        "dirs", nargs="+", metavar="DIR", help="result dirs, or shipped sets (reference:NAME)"
    )
    rep.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="where to write (default: the run dir, or the runs' common parent)",
    )
    rep.add_argument("--title", default=None)

    add_validity_parser(sub)
    add_gallery_parser(sub)
    cmp_ = sub.add_parser(
        "compare",
        help="per-task deltas of B against A; exit 1 if B is significantly worse on any task",
    )
    cmp_.add_argument(
        "dir_a", metavar="DIR_A", help="baseline: a result dir, or a shipped reference:NAME"
    )
    cmp_.add_argument("dir_b", metavar="DIR_B", help="candidate: a result dir (or reference:NAME)")
    cmp_.add_argument("--alpha", type=float, default=0.05, help="significance level (0.05)")

    srv = sub.add_parser(
        "serve",
        help="serve a policy over a websocket (openpi's protocol) for run --policy ws://HOST:PORT",
        description="Serve a policy to `mikasa-bench run --policy ws://HOST:PORT`: msgpack over "
        "a websocket, one policy instance per connection (pip install 'mikasa-bench[remote]').",
    )
    srv.add_argument(
        "--policy",
        required=True,
        metavar="POLICY",
        help="zero | random | module:Class | path/file.py[:Class] | lerobot:DIR (not oracle or "
        "oracle-memoryless: they read the env's state)",
    )
    srv.add_argument(
        "--policy-kwargs", default=None, metavar="JSON", help="keyword arguments for the policy"
    )
    srv.add_argument("--port", type=int, default=8000, help="port to listen on (default 8000)")
    srv.add_argument(
        "--host", default="0.0.0.0", help="address to listen on (default 0.0.0.0: every one)"
    )
    return p


def _add_exec_args(p: argparse.ArgumentParser, default_workers: int | None) -> None:
    p.add_argument(
        "--workers",
        type=int,
        default=default_workers,
        help="worker processes (default: CPU count; 0 = run in this process)",
    )
    p.add_argument(
        "--executor",
        default="local",
        choices=("local", "ray"),
        help="local: worker processes on this machine (default); ray: Ray actors spread "
        "over a cluster (pip install 'mikasa-bench[ray]')",
    )
    p.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="Ray cluster to join (default: $RAY_ADDRESS, else start Ray locally); "
        "with --executor ray, --workers defaults to the cluster's CPU count",
    )
    p.add_argument(
        "--envs-per-worker",
        type=int,
        default=None,
        metavar="K",
        help="envs each local worker process runs, one thread each; their cameras render in "
        "shared GPU passes (default: 4 for a worker rendering on the GPU, 1 on the CPU)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
