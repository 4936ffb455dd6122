"""``mikasa-datasets``: convert and validate MIKASA-Robo datasets.

Subcommands::

    mikasa-datasets to-rlds    (--task T ... | --all) [--root DIR] [--overwrite | --resume]
    mikasa-datasets to-lerobot (--task T ... | --all) [--from auto|rlds|npz] [--fps 10] ...
    mikasa-datasets validate   PATH ... [--format npz|rlds|lerobot] [--quick]

Paths follow datasets spec §2: ``<root>/data_npz/<name>``, ``<root>/data_rlds/<name>/1.0.0``,
``<root>/data_lerobot/<repo id>`` with ``--root`` defaulting to ``data_mikasa_robo``. A
task is given by env id or dataset name (normalised with ``env_id_to_dataset_name``).
``to-lerobot`` reads RLDS or NPZ; ``--from auto`` (the default) takes, per ``--task``, the
RLDS task directory when it holds a version directory and the NPZ one otherwise (so it runs
straight after ``mikasa-collect``, which writes NPZ only); with ``--all``, the RLDS root
if it holds any RLDS task directory, else the NPZ root. Each task's line says which source
was read (``to-lerobot <name>: from NPZ <path>``). ``validate`` also accepts the RL
release's episodes (``mikasa-rl-collect``:
``<path>/MIKASA-Robo/unbatched/<env_id>/`` or one of its files), told apart by their keys.

Exit status: 0 success, 1 a conversion or validation failed (the message names the file),
2 bad usage, 3 a format library is missing (the message says how to install it).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from mikasa_datasets.conversion import (
    DatasetFormatError,
    MissingDependencyError,
    OutputExistsError,
)
from mikasa_datasets.loaders import find_task_dir
from mikasa_datasets.npz import DATA_NPZ_DIRNAME, EpisodeFormatError, list_episode_files

__all__ = ["build_parser", "main"]

DEFAULT_ROOT = "data_mikasa_robo"
RLDS_DIRNAME = "data_rlds"
LEROBOT_DIRNAME = "data_lerobot"


def _add_selection(p: argparse.ArgumentParser) -> None:
    sel = p.add_mutually_exclusive_group(required=True)
    sel.add_argument(
        "--task", action="append", metavar="TASK", help="env id or dataset name (repeatable)"
    )
    sel.add_argument("--all", action="store_true", help="every task directory of the source root")
    p.add_argument("--root", default=DEFAULT_ROOT, help="dataset root (default: %(default)s)")
    p.add_argument("--npz-root", help="NPZ root (default: <root>/data_npz)")
    p.add_argument("--rlds-root", help="RLDS root (default: <root>/data_rlds)")
    p.add_argument(
        "--max-episodes", type=int, help="convert only the first N episodes (smoke tests)"
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--overwrite",
        "--overwrite-dest",
        action="store_true",
        help="replace an existing output (the old one is removed only once the new one is complete)",
    )
    mode.add_argument(
        "--resume",
        "--skip-existing",
        action="store_true",
        help="keep outputs that are complete and match their source, convert the rest",
    )


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``mikasa-datasets`` console script."""
    parser = argparse.ArgumentParser(
        prog="mikasa-datasets",
        description="Convert MIKASA-Robo NPZ episodes to RLDS / LeRobotDataset v3 and validate datasets.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("to-rlds", help="NPZ -> RLDS (TFDS builder mikasa_dataset 1.0.0)")
    _add_selection(p)
    p.add_argument(
        "--workers", type=int, default=None, help="PNG-encoding threads (default: min(2, CPUs))"
    )

    p = sub.add_parser(
        "to-lerobot", help="RLDS or NPZ -> LeRobotDataset v3 (through lerobot's API)"
    )
    _add_selection(p)
    p.add_argument(
        "--from",
        dest="source",
        choices=("auto", "rlds", "npz"),
        default="auto",
        help="source format; auto: per --task the RLDS task directory if it has a version "
        "directory, else NPZ; with --all the RLDS root if it has RLDS task directories, "
        "else the NPZ root (default: %(default)s)",
    )
    p.add_argument("--lerobot-root", help="LeRobot root (default: <root>/data_lerobot)")
    p.add_argument("--version", help="RLDS version directory X.Y.Z (default: the latest)")
    p.add_argument(
        "--repo-id-template",
        default="{task}",
        help="repo id; must contain {task} (default: %(default)s)",
    )
    p.add_argument(
        "--fps", type=int, default=10, help="dataset and video fps (default: %(default)s)"
    )
    p.add_argument(
        "--robot-type",
        default="mikasa_robo",
        help="robot_type in meta/info.json (default: %(default)s)",
    )
    p.add_argument(
        "--vcodec",
        default="libsvtav1",
        help="video codec, one lerobot accepts (at lerobot's settings: crf 30, GOP 2): "
        "libsvtav1 (AV1, lerobot's default), h264 (libx264), hevc (default: %(default)s)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="writer processes (default: one per CPU, with >= 8 episodes each)",
    )
    p.add_argument(
        "--no-videos", action="store_true", help="store camera frames as PNG images instead of MP4"
    )

    p = sub.add_parser(
        "validate",
        help="check a dataset (NPZ, RLDS or LeRobot; NPZ includes the RL release's "
        "MIKASA-Robo/unbatched/<env_id> episodes) against the schema",
    )
    p.add_argument(
        "paths",
        nargs="+",
        metavar="PATH",
        help="a task/version/dataset directory, an .npz file, or a root of tasks",
    )
    p.add_argument("--format", choices=("npz", "rlds", "lerobot"), help="skip auto-detection")
    p.add_argument(
        "--quick",
        action="store_true",
        help="check structure and counts without decoding frame data",
    )
    return parser


def _is_rlds_task_dir(d: Path) -> bool:
    """A directory holding at least one ``X.Y.Z`` version directory."""
    return d.is_dir() and any(c.is_dir() and c.name.count(".") == 2 for c in d.iterdir())


def _task_dirs(args: argparse.Namespace, source_root: Path, kind: str) -> list[Path]:
    """Source task directories selected by ``--task``/``--all`` (dataset-name spelling)."""
    if args.task:
        return [find_task_dir(source_root, t) for t in args.task]
    if not source_root.is_dir():
        raise DatasetFormatError(source_root, f"{kind} root does not exist")
    dirs = []
    for d in sorted(source_root.iterdir()):
        if not d.is_dir() or d.name.startswith(("_", ".")):
            continue  # _batched staging, hidden staging outputs
        if kind == "npz" and not list_episode_files(d):
            continue
        if kind == "rlds" and not _is_rlds_task_dir(d):
            continue
        dirs.append(d)
    if not dirs:
        raise DatasetFormatError(source_root, f"no {kind} task directories")
    return dirs


def _lerobot_sources(
    args: argparse.Namespace, rlds_root: Path, npz_root: Path
) -> list[tuple[str, Path]]:
    """``(kind, task directory)`` per task to convert, ``kind`` "rlds" or "npz": as
    ``--from`` says, or for ``auto`` per ``--task`` RLDS where its task directory has a
    version directory, else NPZ; with ``--all`` the RLDS root if it has RLDS task
    directories, else the NPZ root. Resolved for every task before anything is converted."""
    if args.source != "auto":
        root = rlds_root if args.source == "rlds" else npz_root
        return [(args.source, d) for d in _task_dirs(args, root, args.source)]
    if not args.task:
        try:
            return [("rlds", d) for d in _task_dirs(args, rlds_root, "rlds")]
        except DatasetFormatError:  # no RLDS root, or no RLDS task directory in it
            return [("npz", d) for d in _task_dirs(args, npz_root, "npz")]
    sources = []
    for task in args.task:
        rlds_dir = find_task_dir(rlds_root, task)
        if _is_rlds_task_dir(rlds_dir):
            sources.append(("rlds", rlds_dir))
            continue
        npz_dir = find_task_dir(npz_root, task)
        if not npz_dir.is_dir():
            raise DatasetFormatError(
                npz_dir,
                f"NPZ task directory does not exist, nor an RLDS one (with a version "
                f"directory) at {rlds_dir}",
            )
        sources.append(("npz", npz_dir))
    return sources


def _report(command: str, task: str, result: object) -> None:
    r = result  # ConversionResult
    if r.skipped:  # type: ignore[attr-defined]
        print(f"{command} {task}: kept existing {r.path} (--resume)")  # type: ignore[attr-defined]
    else:
        print(
            f"{command} {task}: {r.episodes} episodes, {r.frames} frames in {r.seconds:.1f} s "  # type: ignore[attr-defined]
            f"({r.frames_per_second:.0f} frames/s) -> {r.path}"  # type: ignore[attr-defined]
        )


def _run_to_rlds(args: argparse.Namespace) -> int:
    from mikasa_datasets import rlds

    root = Path(args.root)
    npz_root = Path(args.npz_root) if args.npz_root else root / DATA_NPZ_DIRNAME
    rlds_root = Path(args.rlds_root) if args.rlds_root else root / RLDS_DIRNAME
    for src in _task_dirs(args, npz_root, "npz"):
        result = rlds.convert_npz_to_rlds(
            src,
            rlds_root,
            overwrite=args.overwrite,
            resume=args.resume,
            max_episodes=args.max_episodes,
            workers=args.workers,
        )
        _report("to-rlds", src.name, result)
    return 0


def _run_to_lerobot(args: argparse.Namespace) -> int:
    from mikasa_datasets import lerobot

    root = Path(args.root)
    lerobot_root = Path(args.lerobot_root) if args.lerobot_root else root / LEROBOT_DIRNAME
    npz_root = Path(args.npz_root) if args.npz_root else root / DATA_NPZ_DIRNAME
    rlds_root = Path(args.rlds_root) if args.rlds_root else root / RLDS_DIRNAME
    for kind, src in _lerobot_sources(args, rlds_root, npz_root):
        name = src.name
        if kind == "rlds" and args.version:
            if not (src / args.version).is_dir():
                raise DatasetFormatError(src / args.version, "no such RLDS version directory")
            src = src / args.version
        print(f"to-lerobot {name}: from {kind.upper()} {src}", flush=True)
        convert = (
            lerobot.convert_rlds_to_lerobot if kind == "rlds" else lerobot.convert_npz_to_lerobot
        )
        result = convert(
            src,
            lerobot_root,
            repo_id_template=args.repo_id_template,
            overwrite=args.overwrite,
            resume=args.resume,
            max_episodes=args.max_episodes,
            fps=args.fps,
            robot_type=args.robot_type,
            use_videos=not args.no_videos,
            vcodec=args.vcodec,
            workers=args.workers,
        )
        _report("to-lerobot", result.path.name, result)
    return 0


def _run_validate(args: argparse.Namespace) -> int:
    from mikasa_datasets.validate import validate_path

    status = 0
    for path in args.paths:
        try:
            print(validate_path(path, args.format, quick=args.quick).summary())
        except (DatasetFormatError, EpisodeFormatError, FileNotFoundError, ValueError) as exc:
            print(f"INVALID {exc}")
            status = 1
    return status


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mikasa-datasets`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    run = {"to-rlds": _run_to_rlds, "to-lerobot": _run_to_lerobot, "validate": _run_validate}[
        args.command
    ]
    try:
        return run(args)
    except MissingDependencyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    except (
        DatasetFormatError,
        EpisodeFormatError,
        OutputExistsError,
        FileNotFoundError,
        ValueError,
    ) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
