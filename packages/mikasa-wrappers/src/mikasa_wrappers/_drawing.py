"""Drawing helpers shared by the render overlays and `CameraShutdownWrapper`.

Everything here works on numpy uint8 RGB frames, because OpenCV draws on numpy arrays.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import torch

FONT = cv2.FONT_HERSHEY_SIMPLEX
WHITE = (255, 255, 255)
BLACK = (0, 0, 0)
OUTLINE = (20, 20, 20)


def frames_to_uint8(frames: Any) -> tuple[np.ndarray, bool]:
    """Convert rendered frames to a contiguous uint8 numpy array of shape (B, H, W, C).

    Returns the array and whether the input was batched; a single (H, W, C) frame gets a
    leading batch axis of 1 so that callers can always loop over envs. Float frames in
    [0, 1] are scaled to [0, 255].
    """
    if isinstance(frames, torch.Tensor):
        frames = frames.detach().cpu().numpy()
    src = np.asarray(frames)
    batched = src.ndim == 4
    arr = src if batched else src[None]
    if arr.dtype != np.uint8:
        arr = arr.astype(np.float32)
        if arr.size and float(arr.max()) <= 1.0:
            arr = arr * 255.0
        arr = np.clip(np.rint(arr), 0, 255).astype(np.uint8)
    # OpenCV needs writable C-contiguous memory; copying also keeps us from drawing into a
    # buffer the simulator (or the caller) still owns.
    arr = np.ascontiguousarray(arr)
    if np.may_share_memory(arr, src):
        arr = arr.copy()
    return arr, batched


def restore_batching(arr: np.ndarray, batched: bool) -> np.ndarray:
    """Undo the batch axis that `frames_to_uint8` added to an unbatched frame."""
    return arr if batched else arr[0]


def text_size(text: str, scale: float = 1.0, thickness: int = 2) -> tuple[int, int]:
    """(width, height) in pixels of `text` drawn with `draw_text` at this scale/thickness."""
    (w, h), _ = cv2.getTextSize(text, FONT, scale, thickness)
    return w, h


def draw_text(
    img: np.ndarray,
    text: str,
    org: tuple[int, int],
    scale: float = 1.0,
    color: tuple[int, int, int] = WHITE,
    thickness: int = 2,
) -> None:
    """Draw anti-aliased Hershey-Simplex text with a dark outline, in place.

    `org` is the (x, y) pixel of the baseline-left corner. The outline is drawn first with
    a thicker stroke so the text stays readable on any background.
    """
    org = (int(org[0]), int(org[1]))
    cv2.putText(img, text, org, FONT, scale, OUTLINE, max(2, thickness + 2), cv2.LINE_AA)
    cv2.putText(img, text, org, FONT, scale, color, thickness, cv2.LINE_AA)


def draw_swatch(
    img: np.ndarray,
    x: int,
    y: int,
    size: int,
    fill: tuple[int, int, int],
    border: tuple[int, int, int] = WHITE,
    border_thickness: int = 2,
) -> None:
    """Draw a filled `size` x `size` square with top-left (x, y) and a border, in place."""
    p0, p1 = (int(x), int(y)), (int(x + size - 1), int(y + size - 1))
    cv2.rectangle(img, p0, p1, tuple(int(c) for c in fill), -1)
    cv2.rectangle(img, p0, p1, tuple(int(c) for c in border), border_thickness)


def to_rgb255(color: Any) -> tuple[int, int, int] | None:
    """An RGB(A) colour given as floats in [0, 1] or ints in [0, 255] -> (r, g, b) ints.

    Returns None if `color` cannot be read as at least three numbers.
    """
    try:
        if isinstance(color, torch.Tensor):
            color = color.detach().cpu().numpy()
        arr = np.asarray(color, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        return None
    if arr.size < 3 or not np.all(np.isfinite(arr[:3])):
        return None
    rgb = arr[:3]
    if rgb.max() <= 1.0:
        rgb = rgb * 255.0
    r, g, b = (int(v) for v in np.clip(np.rint(rgb), 0, 255))
    return r, g, b
