"""Episode videos (benchmark.md §8): the scene view beside the two policy cameras, as mp4.

One composed frame per simulator step, captured before the step (what the policy saw),
plus one final frame after the last step. Layout: left, ``env.render()`` (the 512x512
``render_camera`` with the task's overlays) at full size; right, a column of width W/2
holding the top camera (``rgb`` channels 0-2) above the wrist camera (channels 3-5), each
upscaled from 128x128 and labelled. Result: 768x512 for the canonical envs.

Frames are streamed to ffmpeg (the binary shipped by ``imageio-ffmpeg``, a ManiSkill
dependency) as they come, so a 2160-step episode never holds ~2.5 GB of frames in memory.
Encoding: H.264 (libx264, yuv420p, CRF 20, preset medium, +faststart) at 30 fps, as the
reference transcodes to; if ffmpeg is missing, encoding fails with a clear error.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["FPS", "compose_frame", "EpisodeVideo", "video_relpath"]

FPS = 30
_LABEL_ORIGIN = (8, 22)


def video_relpath(env_id: str, episode: int) -> str:
    """Path of episode ``episode``'s video relative to the run directory (spec §8)."""
    return f"videos/{env_id}/episode_{int(episode):04d}.mp4"


def _as_uint8_hwc(img: Any) -> np.ndarray:
    """An (H, W, C) uint8 array from a tensor/array with optional batch dims; floats in
    [0, 1] are scaled by 255; a single channel becomes grey RGB."""
    if hasattr(img, "detach"):
        img = img.detach().cpu().numpy()
    arr = np.asarray(img)
    while arr.ndim > 3:
        arr = arr[0]
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.dtype != np.uint8:
        scale = 255.0 if arr.max(initial=0) <= 1.0 else 1.0
        arr = np.clip(arr.astype(np.float32) * scale, 0, 255).astype(np.uint8)
    if arr.shape[-1] == 1:
        arr = np.repeat(arr, 3, axis=-1)
    return arr


def _label(img: np.ndarray, text: str) -> None:
    """White text with a black outline at (8, 22), in place."""
    import cv2

    cv2.putText(img, text, _LABEL_ORIGIN, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(
        img, text, _LABEL_ORIGIN, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA
    )


def compose_frame(render: Any, obs: Any) -> np.ndarray:
    """One video frame: ``render`` (H, W) on the left, a column of width W//2 on the right
    with the top camera in the upper H//2 rows and the wrist camera below.

    Without an ``rgb`` observation (state mode) the render is reused for both panels.
    """
    import cv2

    scene = np.ascontiguousarray(_as_uint8_hwc(render)[..., :3])
    h, w = scene.shape[:2]
    col_w, top_h = w // 2, h // 2
    rgb = obs.get("rgb") if isinstance(obs, dict) else None
    if rgb is not None:
        cams = _as_uint8_hwc(rgb)
        top = cams[..., :3]
        wrist = cams[..., 3:6] if cams.shape[-1] >= 6 else top
    else:
        top = wrist = scene
    panels = []
    for img, rows, text in ((top, top_h, "top"), (wrist, h - top_h, "wrist")):
        # INTER_AREA as the reference; for an integer upscale it replicates pixels, so the
        # policy's 128x128 view stays sharp.
        p = cv2.resize(np.ascontiguousarray(img), (col_w, rows), interpolation=cv2.INTER_AREA)
        _label(p, text)
        panels.append(p)
    return np.ascontiguousarray(np.concatenate([scene, np.concatenate(panels, axis=0)], axis=1))


class EpisodeVideo:
    """Streams composed frames of one episode into an H.264 mp4.

    Frames go to a temp file (in ``tmp_dir``, default the system temp dir); `finish`
    returns the encoded bytes (the runner writes them atomically into the run directory,
    before it journals the episode) and `abort` discards everything. Use as a context
    manager: leaving it with an exception aborts.
    """

    def __init__(self, fps: int = FPS, tmp_dir: str | Path | None = None) -> None:
        self.fps = int(fps)
        self.n_frames = 0
        fd, self._path = tempfile.mkstemp(prefix="mikasa-episode-", suffix=".mp4", dir=tmp_dir)
        os.close(fd)
        self._writer: Any = None
        self._size: tuple[int, int] | None = None

    def add(self, frame: np.ndarray) -> None:
        """Append one (H, W, 3) uint8 frame (all frames must have the first one's size)."""
        frame = np.ascontiguousarray(frame, dtype=np.uint8)
        h, w = frame.shape[:2]
        if self._writer is None:
            import imageio_ffmpeg

            self._size = (w, h)
            self._writer = imageio_ffmpeg.write_frames(
                self._path,
                (w, h),
                fps=self.fps,
                codec="libx264",
                pix_fmt_in="rgb24",
                pix_fmt_out="yuv420p",
                quality=None,  # let -crf decide
                macro_block_size=2,  # yuv420p needs even sizes; 768x512 needs no padding
                ffmpeg_log_level="error",
                output_params=["-crf", "20", "-preset", "medium", "-movflags", "+faststart"],
            )
            self._writer.send(None)  # start ffmpeg
        elif (w, h) != self._size:
            raise ValueError(f"video frame size changed from {self._size} to {(w, h)}")
        self._writer.send(frame)
        self.n_frames += 1

    def finish(self) -> bytes:
        """Close the encoder and return the mp4 bytes (the temp file is removed)."""
        try:
            if self._writer is None:
                raise ValueError("no frames were recorded")
            self._writer.close()
            self._writer = None
            return Path(self._path).read_bytes()
        finally:
            self.abort()

    def abort(self) -> None:
        """Stop the encoder (if running) and delete the temp file."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:
                pass
            self._writer = None
        try:
            os.unlink(self._path)
        except OSError:
            pass

    def __enter__(self) -> EpisodeVideo:
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        self.abort()
