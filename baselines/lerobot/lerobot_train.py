"""``lerobot-train`` (lerobot 0.4.x) with a clean stop at a deadline, offline.

    python baselines/lerobot/lerobot_train.py ARGS      # = lerobot-train ARGS

What it adds to lerobot-train, and why:

* ``mikasa_bench.lerobot_policy.import_lerobot()`` before lerobot's first import: the Hub is
  switched off (``HF_HUB_OFFLINE=1``) and ``torchvision`` imports where PyPI's CUDA build
  sits beside a CPU torch (``.venv-datasets``), where plain ``lerobot-train`` dies at
  ``import torchvision``.
* ``MIKASA_TRAIN_DEADLINE`` (a Unix time): once an optimisation step ends past it, that step
  is checkpointed (lerobot's own ``save_checkpoint``, with the configured ``save_freq``
  written to ``train_config.json``) and the process exits with `EXIT_PAUSED`; lerobot-train's
  ``--resume=true --config_path=.../checkpoints/last/pretrained_model/train_config.json``
  continues from there. So a time-limited command loses no finished step.
* ``MIKASA_TRAIN_PROGRESS`` (a path): a small JSON with the step, the last loss, this
  call's steps and wall time, the device and the parameter count, rewritten at every log
  step and at the end (the driver's record of training time comes from it).
* ``--dataset.video_backend=pyav`` decodes with PyAV directly (`decode_frames_pyav`) where
  torchvision no longer has ``io.VideoReader`` (lerobot 0.4.4's "pyav" path needs it): a
  machine without torchcodec or without system FFmpeg libraries can still train on videos.
* After every checkpoint, the older numbered checkpoints of the run are removed (each holds
  the weights and the optimizer state; only ``last`` is ever resumed or evaluated).

Everything else is lerobot-train's ``main`` unchanged (its own CLI, its own output layout).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

EXIT_PAUSED = 75
"""Exit status after a checkpointed stop at the deadline (EX_TEMPFAIL: run again to go on)."""


class _Paused(Exception):
    """Raised inside lerobot's training loop once the deadline's checkpoint is saved."""


class _State:
    """What the patched lerobot functions share."""

    def __init__(self) -> None:
        self.cfg: Any = None
        self.deadline = float(os.environ.get("MIKASA_TRAIN_DEADLINE") or "inf")
        self.progress_path = os.environ.get("MIKASA_TRAIN_PROGRESS") or None
        self.started = time.time()
        self.first_step: int | None = None
        self.loop_started: float | None = None  # start of this call's first update
        self.step = 0
        self.loss = float("nan")
        self.stop_requested = False
        self.saved_after_stop = False
        self.save_freq: int | None = None
        self.num_params: int | None = None
        self.device = ""

    def write_progress(self, status: str) -> None:
        """Rewrite the progress JSON atomically (no partial file is ever read)."""
        if not self.progress_path:
            return
        steps_this_call = self.step - (self.first_step or 0) if self.first_step is not None else 0
        wall = time.time() - self.started
        loop = time.time() - self.loop_started if self.loop_started is not None else 0.0
        data = {
            "status": status,
            "step": self.step,
            "total_steps": getattr(self.cfg, "steps", None),
            "loss": self.loss,
            "steps_this_call": steps_this_call,
            "wall_s_this_call": round(wall, 2),
            # From the first update on: start-up (imports, dataset, model) excluded.
            "train_loop_s_this_call": round(loop, 2),
            "device": self.device,
            "num_params": self.num_params,
        }
        path = Path(self.progress_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(data, indent=2))
        os.replace(tmp, path)


def _prune_checkpoints(checkpoint_dir: Path) -> None:
    """Remove the run's numbered checkpoints other than ``checkpoint_dir`` (the new ``last``)."""
    for other in checkpoint_dir.parent.iterdir():
        if other.name != checkpoint_dir.name and other.name.isdigit() and not other.is_symlink():
            shutil.rmtree(other, ignore_errors=True)


def decode_frames_pyav(
    video_path: str | Path,
    timestamps: list[float],
    tolerance_s: float,
    backend: str = "pyav",
    log_loaded_timestamps: bool = False,
) -> Any:
    """lerobot's ``decode_video_frames_torchvision`` for ``backend="pyav"``, with PyAV itself.

    lerobot 0.4.4's "pyav" backend goes through ``torchvision.io.VideoReader``, which recent
    torchvision releases no longer have; its "torchcodec" backend needs torchcodec built for
    the installed torch plus the system's FFmpeg libraries. PyAV (which lerobot imports
    anyway) bundles FFmpeg, so this works wherever lerobot's dataset code imports. Same
    contract as lerobot's function: seek to the key frame before the first timestamp,
    decode up to the last, take the closest frame of each timestamp (within
    ``tolerance_s``, else lerobot's ``FrameTimestampError``), float32 (N, C, H, W) in [0, 1].
    """
    import av
    import numpy as np
    import torch
    from lerobot.datasets.video_utils import FrameTimestampError

    first, last = min(timestamps), max(timestamps)
    frames: list[Any] = []
    loaded: list[float] = []
    with av.open(str(video_path)) as container:
        stream = container.streams.video[0]
        container.seek(int(first / stream.time_base), stream=stream, backward=True)
        for frame in container.decode(stream):
            t = float(frame.pts * stream.time_base)
            frames.append(frame)
            loaded.append(t)
            if t >= last:
                break
        query = np.asarray(timestamps, dtype=np.float64)
        have = np.asarray(loaded, dtype=np.float64)
        dist = (
            np.abs(query[:, None] - have[None, :])
            if len(have)
            else np.full((len(query), 1), np.inf)
        )
        idx = dist.argmin(1)
        err = dist[np.arange(len(query)), idx]
        if not (err < tolerance_s).all():
            raise FrameTimestampError(
                f"query timestamps {query[err >= tolerance_s].tolist()} have no frame within "
                f"{tolerance_s=} (loaded {have.tolist()}) in {video_path} (pyav)"
            )
        # Convert only the frames asked for (a key frame's GOP is decoded, not converted).
        rgb = [frames[i].to_ndarray(format="rgb24") for i in idx]
    out = torch.from_numpy(np.stack(rgb)).permute(0, 3, 1, 2).contiguous()
    return out.to(torch.float32) / 255


def _install_pyav_decoder() -> bool:
    """Route lerobot's "pyav" backend to `decode_frames_pyav` where torchvision lacks
    ``io.VideoReader``; whether it did."""
    import torchvision
    from lerobot.datasets import video_utils

    if hasattr(torchvision.io, "VideoReader"):
        return False
    video_utils.decode_video_frames_torchvision = decode_frames_pyav
    return True


def _install_hooks(state: _State) -> None:
    """Wrap lerobot_train's update_policy / save_checkpoint / make_optimizer_and_scheduler."""
    import torch
    from lerobot.scripts import lerobot_train as lt

    orig_make_opt = lt.make_optimizer_and_scheduler
    orig_update = lt.update_policy
    orig_save = lt.save_checkpoint

    def make_optimizer_and_scheduler(cfg: Any, policy: Any) -> Any:
        # The only place train() hands out its cfg and policy before the loop.
        state.cfg = cfg
        state.save_freq = cfg.save_freq
        state.num_params = sum(p.numel() for p in policy.parameters())
        dev = next(policy.parameters()).device
        state.device = torch.cuda.get_device_name(dev) if dev.type == "cuda" else str(dev.type)
        return orig_make_opt(cfg, policy)

    def update_policy(train_metrics: Any, *args: Any, **kwargs: Any) -> Any:
        if state.saved_after_stop:
            raise _Paused
        if state.loop_started is None:
            state.loop_started = time.time()
        out = orig_update(train_metrics, *args, **kwargs)
        if state.first_step is None:
            # The tracker counts finished steps (resumed runs start at the checkpoint's).
            state.first_step = int(train_metrics.steps)
        state.step = int(train_metrics.steps) + 1
        state.loss = float(train_metrics.loss.val)
        if state.cfg is not None and state.step % max(int(state.cfg.log_freq), 1) == 0:
            state.write_progress("running")
        if time.time() >= state.deadline and not state.stop_requested and state.cfg is not None:
            # Make the step that just ended a saving step; save_checkpoint puts save_freq back
            # before lerobot dumps the config, so a resumed run keeps the configured value.
            state.stop_requested = True
            state.cfg.save_freq = 1
        return out

    def save_checkpoint(checkpoint_dir: Path, *args: Any, **kwargs: Any) -> None:
        if state.cfg is not None and state.save_freq is not None:
            state.cfg.save_freq = state.save_freq
        orig_save(checkpoint_dir, *args, **kwargs)
        if state.stop_requested:
            state.saved_after_stop = True

    def update_last_checkpoint(checkpoint_dir: Path) -> Path:
        result = orig_update_last(checkpoint_dir)
        _prune_checkpoints(Path(checkpoint_dir))
        return result

    orig_update_last = lt.update_last_checkpoint
    lt.make_optimizer_and_scheduler = make_optimizer_and_scheduler
    lt.update_policy = update_policy
    lt.save_checkpoint = save_checkpoint
    lt.update_last_checkpoint = update_last_checkpoint


def main() -> int:
    """Run lerobot-train with ``sys.argv[1:]``; 0 when done, `EXIT_PAUSED` at the deadline."""
    from mikasa_bench.lerobot_policy import import_lerobot

    import_lerobot()  # offline, torchvision importable: before any lerobot module
    state = _State()
    _install_pyav_decoder()
    _install_hooks(state)
    from lerobot.scripts import lerobot_train as lt

    try:
        lt.main()
    except _Paused:
        state.write_progress("paused")
        print(
            f"lerobot_train: deadline reached; checkpoint saved at step {state.step}, "
            f"resume with --resume=true",
            flush=True,
        )
        return EXIT_PAUSED
    state.write_progress("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
