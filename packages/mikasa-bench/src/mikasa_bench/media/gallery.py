"""The task gallery: an animated image of the oracle solving each task, and an HTML page.

    mikasa-bench gallery OUT [--task ID ...] [--workers N]

For every task (or the ones named) one oracle episode runs in the canonical ``rgb`` env
(seed ``--seed``, default the protocol's first seed) and its top and wrist camera frames,
side by side, with the phase (cue / delay / action), the step and the success latch
written under them, become ``OUT/tasks/<env_id>.webp`` (animated); ``OUT/tasks/<env_id>.json`` holds
the task's card: id, instruction, memory type, split, horizon, what is hidden and when
(the env class's Task Description and its phase lengths), the success condition, chance
level (`mikasa_bench.results.chance`) and the episode's outcome. ``OUT/index.html`` shows them all
and ``OUT/gallery.json`` lists the cards.

A task whose card exists is not rendered again, so an interrupted gallery resumes; every
file is written under a temporary name and renamed.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import re
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from mikasa_bench.errors import BenchError
from mikasa_bench.media.gallery_html import write_index
from mikasa_bench.media.render import apply_environment
from mikasa_bench.policies.loading import build_policy, resolve_policy
from mikasa_bench.policies.oracle_extra import require_oracles
from mikasa_bench.protocol import START_SEED, SUPPORTED_SPLITS, BenchmarkConfig
from mikasa_bench.protocol.tasks import registered_env_ids, resolve_tasks
from mikasa_bench.results.chance import task_chance
from mikasa_bench.results.files import atomic_write_bytes, atomic_write_json
from mikasa_bench.runners.episode import make_benchmark_env, run_episode
from mikasa_bench.runners.worker import worker_env_vars

__all__ = [
    "PHASE_COLORS",
    "FrameRecorder",
    "task_card",
    "render_task",
    "build_gallery",
    "add_gallery_parser",
    "run_gallery",
]

PHASE_COLORS: dict[str, tuple[int, int, int]] = {
    "cue": (230, 160, 30),
    "delay": (120, 120, 200),
    "action": (40, 170, 80),
}
"""Label colour (RGB) of each phase in the animation and on the page."""

_STRIP_H = 22
GALLERY_CONFIG = BenchmarkConfig(sim_backend="cpu")
"""The canonical env (rgb, default render device) on the CPU sim, one per worker."""
_SECTION = re.compile(r"\*\*(?P<name>[A-Za-z ]+):\*\*")


class FrameRecorder:
    """Wraps the canonical env and keeps a thinned copy of every observation's camera
    frames with the phase it belongs to, at most ``max_frames`` of them (when the episode
    outgrows that, every other kept frame is dropped and the stride doubles)."""

    def __init__(self, env: Any, max_frames: int) -> None:
        if max_frames < 2:
            raise ValueError(f"max_frames must be >= 2, got {max_frames}")
        self.env, self.max_frames = env, int(max_frames)
        self.frames: list[tuple[np.ndarray, str, int, bool]] = []
        self.stride, self._seen, self._success = 1, 0, False
        self._last: tuple[np.ndarray, str, int, bool] | None = None

    def __getattr__(self, name: str) -> Any:  # action_space, max_episode_steps, unwrapped...
        return getattr(self.env, name)

    def reset(self, **kwargs: Any) -> Any:
        obs, info = self.env.reset(**kwargs)
        self.frames, self.stride, self._seen, self._success = [], 1, 0, False
        self._keep(obs)
        return obs, info

    def step(self, action: Any) -> Any:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._success |= bool(np.asarray(info.get("success", False)).reshape(-1)[0])
        self._keep(obs)
        return obs, reward, terminated, truncated, info

    def phase(self) -> str:
        """The phase of the current frame (the base env's cue/delay/action clock)."""
        base = self.env.unwrapped
        cue, _, action = base.phase_masks(base.elapsed_steps)
        return "cue" if bool(cue[0]) else "action" if bool(action[0]) else "delay"

    def _keep(self, obs: dict[str, Any]) -> None:
        rgb = obs["rgb"]
        rgb = rgb.cpu().numpy() if hasattr(rgb, "cpu") else np.asarray(rgb)
        frame = (np.ascontiguousarray(rgb[0]), self.phase(), self._seen, self._success)
        self._last = frame
        if self._seen % self.stride == 0:
            self.frames.append(frame)
            if len(self.frames) > self.max_frames:
                self.frames, self.stride = self.frames[::2], self.stride * 2
        self._seen += 1

    def kept_frames(self) -> list[tuple[np.ndarray, str, int, bool]]:
        """The kept frames, always ending with the episode's last one."""
        if self._last is not None and (not self.frames or self.frames[-1][2] != self._last[2]):
            return [*self.frames, self._last]
        return list(self.frames)


def compose_gallery_frame(
    cams: np.ndarray, phase: str, step: int, horizon: int, success: bool, scale: int
) -> np.ndarray:
    """Top camera | wrist camera (``cams``: H x W x 6), each upscaled ``scale`` times, over a
    strip naming the phase, the step and the success latch."""
    import cv2

    top, wrist = cams[..., :3], cams[..., 3:6]
    pair = np.concatenate([top, wrist], axis=1)
    if scale > 1:
        pair = np.repeat(np.repeat(pair, scale, axis=0), scale, axis=1)
    strip = np.full((_STRIP_H, pair.shape[1], 3), 24, dtype=np.uint8)
    cv2.rectangle(strip, (0, 0), (64, _STRIP_H), PHASE_COLORS[phase], thickness=-1)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(strip, phase, (6, 16), font, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    cv2.putText(
        strip, f"step {step}/{horizon}", (72, 16), font, 0.45, (230, 230, 230), 1, cv2.LINE_AA
    )
    if success:
        x = pair.shape[1] - 70
        cv2.putText(strip, "success", (x, 16), font, 0.5, (90, 230, 120), 1, cv2.LINE_AA)
    return np.concatenate([np.ascontiguousarray(pair), strip], axis=0)


def write_animation(path: Path, frames: Sequence[np.ndarray], strides: Sequence[int]) -> None:
    """An endlessly looping animated WebP, atomically: each frame shown for its simulator
    steps at 30 steps/s but at least 0.1 s, the last one held for 1.5 s. (Lossy WebP: the
    rendered table's wood grain makes a GIF 3-4 times larger.)"""
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    durations = [max(100, round(1000 * s / 30)) for s in strides]
    durations[-1] = 1500
    encoded = io.BytesIO()
    images[0].save(
        encoded,
        format="WEBP",
        save_all=True,
        append_images=images[1:],
        duration=durations,
        loop=0,
        quality=80,
        method=4,
    )
    atomic_write_bytes(path, encoded.getvalue())


def _docstring_sections(cls: type) -> dict[str, str]:
    """The ``**Name:** text`` sections of the first docstring in ``cls``'s MRO that has a
    Task Description (one per family, as ManiSkill's tasks document themselves)."""
    for klass in cls.__mro__:
        doc = klass.__dict__.get("__doc__") or ""
        if "**Task Description:**" in doc:
            parts = _SECTION.split(doc)
            return {
                parts[i].strip(): " ".join(parts[i + 1].split())
                for i in range(1, len(parts) - 1, 2)
            }
    return {}


def _phase_text(base: Any) -> str:
    """The cue and delay lengths the env draws, from its class constants."""

    def span(lo_hi: tuple[int, int]) -> str:
        lo, hi = lo_hi
        return f"{lo} step{'s' * (hi != 1)}" if lo == hi else f"{lo}-{hi} steps"

    cue, delay = tuple(base.CUE_PHASE_STEPS), tuple(base.EMPTY_PHASE_STEPS)
    if cue == delay == (0, 0):
        return (
            "no timed cue: the agent acts from the first step, and what it must remember "
            "is shown while it acts (see above)"
        )
    then = "no delay" if delay == (0, 0) else f"a delay of {span(delay)}"
    return f"cue {span(cue)}, then {then}, then the action phase until the horizon"


def task_card(env_id: str, env: Any) -> dict[str, Any]:
    """What the page says about ``env_id`` (``env``: the made env, for its class)."""
    from mikasa_envs.family import get_family
    from mikasa_envs.manifest import get_task

    spec, chance = get_task(env_id), task_chance(env_id)
    base = env.unwrapped
    sections = _docstring_sections(type(base))
    return {
        "env_id": env_id,
        "family": spec.family,
        "instruction": spec.language_instruction,
        "memory_type": spec.memory_type,
        "split": spec.split or "extra",
        "horizon": int(spec.max_episode_steps),
        "description": sections.get("Task Description", ""),
        "hidden": get_family(spec.family).hidden,
        "phases": _phase_text(base),
        "randomizations": sections.get("Randomizations", ""),
        "success_condition": sections.get("Success Conditions", ""),
        "chance": {"rate": chance.rate, "reason": chance.reason},
    }


def render_task(
    env_id: str, out_dir: str | Path, seed: int, scale: int = 1, max_frames: int = 120
) -> dict[str, Any]:
    """Run the oracle for one episode of ``env_id`` and write its animation and card; returns the card."""
    tasks_dir = Path(out_dir) / "tasks"
    tasks_dir.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    env = make_benchmark_env(env_id, GALLERY_CONFIG)
    try:
        recorder = FrameRecorder(env, max_frames)
        policy = build_policy(resolve_policy("oracle"), env, env_id)
        result, _ = run_episode(recorder, policy, seed)
        card = task_card(env_id, env)
        horizon = card["horizon"]
        kept = recorder.kept_frames()
        frames = [compose_gallery_frame(c, p, t, horizon, s, scale) for c, p, t, s in kept]
        steps = [b[2] - a[2] for a, b in zip(kept, kept[1:], strict=False)] + [1]
        write_animation(tasks_dir / f"{env_id}.webp", frames, steps)
    finally:
        env.close()
    card["episode"] = {
        "seed": int(seed),
        "success": bool(result.success_once),
        "steps": int(result.n_steps),
        "frames": len(frames),
        "seconds": round(time.perf_counter() - started, 1),
    }
    card["image"] = f"tasks/{env_id}.webp"
    atomic_write_json(tasks_dir / f"{env_id}.json", card)
    return card


def _init_worker(worker_config: BenchmarkConfig, n_workers: int) -> None:
    """Each worker renders as the bench's pool workers do (`worker_env_vars`: its device,
    its share of the cores, one GPU)."""
    apply_environment(worker_env_vars(worker_config, 0, n_workers))
    from mikasa_envs.workers import use_one_gpu  # after the Vulkan restriction: loads ManiSkill

    use_one_gpu(0)


def build_gallery(
    out_dir: str | Path,
    env_ids: Sequence[str],
    *,
    seed: int,
    workers: int = 1,
    scale: int = 1,
    max_frames: int = 120,
) -> list[dict[str, Any]]:
    """Render every task of ``env_ids`` not rendered yet (``workers`` processes), then
    write ``gallery.json`` and ``index.html`` for every task rendered in ``out_dir``;
    returns the cards of ``env_ids``, in that order."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    require_oracles("the gallery (an oracle episode per task)")  # before the workers start
    out = Path(out_dir)
    (out / "tasks").mkdir(parents=True, exist_ok=True)
    todo = [e for e in env_ids if not (out / "tasks" / f"{e}.json").exists()]
    if len(todo) < len(env_ids):
        print(
            f"gallery: {len(env_ids) - len(todo)} of {len(env_ids)} tasks already rendered in {out}"
        )
    started = time.perf_counter()
    if todo:
        n = min(workers, len(todo))
        ctx = get_context("spawn")  # SAPIEN and fork do not mix
        with ProcessPoolExecutor(
            n, mp_context=ctx, initializer=_init_worker, initargs=(GALLERY_CONFIG, n)
        ) as pool:
            futures = {pool.submit(render_task, e, out, seed, scale, max_frames): e for e in todo}
            for done, future in enumerate(as_completed(futures), 1):
                card = future.result()
                ep = card["episode"]
                elapsed = time.perf_counter() - started
                eta = elapsed / done * (len(todo) - done)
                print(
                    f"[{done}/{len(todo)}] {card['env_id']}: oracle "
                    f"{'success' if ep['success'] else 'FAILED'} in {ep['steps']} steps, "
                    f"{ep['frames']} frames, {ep['seconds']} s (eta {math.ceil(eta)} s)",
                    file=sys.stderr,
                    flush=True,
                )
    # The page shows every task rendered in OUT so far (galleries grow by --task), in the
    # manifest's order.
    from mikasa_envs.manifest import list_tasks

    order = {t.env_id: i for i, t in enumerate(list_tasks(include_extra=True))}
    paths = sorted(
        (out / "tasks").glob("*.json"), key=lambda p: (order.get(p.stem, len(order)), p.stem)
    )
    cards = {p.stem: json.loads(p.read_text()) for p in paths}
    atomic_write_json(out / "gallery.json", {"tasks": list(cards.values())})
    write_index(out / "index.html", list(cards.values()), PHASE_COLORS)
    return [cards[e] for e in env_ids]


def add_gallery_parser(sub: Any) -> argparse.ArgumentParser:
    """Add the ``gallery`` subcommand to an argparse subparsers object."""
    p = sub.add_parser(
        "gallery",
        help="animations of the oracle solving each task, and an HTML page describing them",
        description="Render one oracle episode per task (top and wrist cameras, the phase "
        "shown) as OUT/tasks/<id>.webp and write OUT/index.html and OUT/gallery.json. "
        "Tasks already rendered in OUT are kept (an interrupted gallery resumes).",
    )
    p.add_argument("out", metavar="OUT", help="output directory")
    sel = p.add_mutually_exclusive_group()
    sel.add_argument(
        "--task",
        action="append",
        default=None,
        metavar="ENV_ID",
        help="an env id (repeatable; default: the 90 canonical tasks)",
    )
    sel.add_argument(
        "--split", default=None, help=f"the tasks of one split: {', '.join(SUPPORTED_SPLITS)}"
    )
    p.add_argument(
        "--seed", type=int, default=START_SEED, help=f"episode seed (default {START_SEED})"
    )
    p.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    p.add_argument(
        "--scale",
        type=int,
        default=1,
        help="upscale the 128x128 cameras this many times (default 1)",
    )
    p.add_argument(
        "--max-frames",
        type=int,
        default=120,
        help="frames kept per animation at most (default 120)",
    )
    return p


def run_gallery(args: argparse.Namespace) -> int:
    """The ``gallery`` subcommand; returns the exit code (0, or 2 on bad input)."""
    try:
        if args.task or args.split:
            env_ids = [t.env_id for t in resolve_tasks(split=args.split, env_ids=args.task).tasks]
        else:
            from mikasa_envs.manifest import list_tasks

            registered = registered_env_ids()
            env_ids = [t.env_id for t in list_tasks() if t.env_id in registered]
        cards = build_gallery(
            args.out,
            env_ids,
            seed=args.seed,
            workers=args.workers,
            scale=args.scale,
            max_frames=args.max_frames,
        )
    except (BenchError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    failed = [c["env_id"] for c in cards if not c["episode"]["success"]]
    print(
        f"{len(cards)} task(s) in {Path(args.out) / 'index.html'}"
        + (f"; oracle failed on {', '.join(failed)}" if failed else "")
    )
    return 0
