"""Per-family overlays: target colour / shape, shell-game cup, rotate angles, memory
capacity, batteries, button presses, the trace-shape minimap and the timed-transfer timer.
"""

from __future__ import annotations

from typing import Any

import cv2
import gymnasium as gym
import numpy as np
from mikasa_envs.building_blocks.shapes import SHAPE_NAMES

from ._drawing import BLACK, WHITE, draw_swatch, draw_text, text_size, to_rgb255
from .generic_overlays import RenderOverlayWrapper, lookup, per_env, scalar, to_numpy

__all__ = [
    "RememberColorInfoWrapper",
    "RememberShapeInfoWrapper",
    "RememberShapeAndColorInfoWrapper",
    "ShellGameRenderCupInfoWrapper",
    "RotateRenderAngleInfoWrapper",
    "MemoryCapacityInfoWrapper",
    "RenderWorkingBatteriesInfoWrapper",
    "RenderPressProgressInfoWrapper",
    "RenderTraceShapeDebugWrapper",
    "RenderTimedTransferInfoWrapper",
]

CUP_NAMES = {0: "Left", 1: "Center", 2: "Right"}
# Fallback palettes, used only when the env exposes no colour table.
_RGB_FALLBACK = {0: (255, 0, 0), 1: (0, 255, 0), 2: (0, 0, 255)}
_CAPACITY_PALETTE = {
    0: (255, 0, 0),
    1: (0, 255, 0),
    2: (0, 0, 255),
    3: (255, 255, 0),
    4: (255, 0, 255),
    5: (0, 255, 255),
    6: (128, 0, 0),
    7: (255, 128, 0),
    8: (0, 128, 128),
}
_TRACE_SHAPE_NAMES = {0: "circle", 1: "square", 2: "triangle"}


# ----------------------------------------------------------------------------------------
# selection families
# ----------------------------------------------------------------------------------------


class RememberColorInfoWrapper(RenderOverlayWrapper):
    """Draw ``Target:`` and a 22 px swatch of ``color_dict[oracle_info]`` (white if unknown).

    Used for RememberColor and FindImposterColor (where it shows the imposter's colour).
    """

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target colour."""
        key = scalar(self._value("oracle_info", i))
        if key is None:
            return
        color_dict = getattr(self.env.unwrapped, "color_dict", None)
        fill = to_rgb255(lookup(color_dict, int(key))) or WHITE
        draw_text(frame, "Target:", (10, 60), 1.0, WHITE, 2)
        width, _ = text_size("Target:", 1.0, 2)
        draw_swatch(frame, 10 + width + 10, 38, 22, fill, WHITE, 2)


class RememberShapeInfoWrapper(RenderOverlayWrapper):
    """Draw ``Target: <shape name>`` (names by index, see ``SHAPE_NAMES``) at (10, 60)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target shape name."""
        key = scalar(self._value("oracle_info", i))
        if key is None:
            return
        k = int(key)
        name = SHAPE_NAMES[k] if 0 <= k < len(SHAPE_NAMES) else str(k)
        draw_text(frame, f"Target: {name}", (10, 60), 1.0, WHITE, 2)


class RememberShapeAndColorInfoWrapper(RenderOverlayWrapper):
    """Draw ``Target:``, a swatch of ``COLOR_PALETTE[color_id]`` and ``BASE_SHAPES[shape_id]``.

    Reads ``oracle_info[i] = [shape_id, color_id]``.
    """

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target colour swatch and shape name."""
        oracle = self._value("oracle_info", i)
        if oracle is None:
            return
        ids = np.asarray(oracle).reshape(-1)
        if ids.size < 2:
            return
        shape_id, color_id = int(ids[0]), int(ids[1])
        base = self.env.unwrapped
        fill = to_rgb255(lookup(getattr(base, "COLOR_PALETTE", None), color_id))
        fill = fill or _RGB_FALLBACK.get(color_id, WHITE)
        name = lookup(getattr(base, "BASE_SHAPES", None), shape_id)
        name = str(name) if name is not None else "Unknown"
        draw_text(frame, "Target:", (10, 60), 1.0, WHITE, 2)
        width, _ = text_size("Target:", 1.0, 2)
        x = 10 + width + 10
        draw_swatch(frame, x, 38, 22, fill, WHITE, 2)
        draw_text(frame, name, (x + 22 + 12, 60), 1.0, WHITE, 2)


# ----------------------------------------------------------------------------------------
# shell games, rotate
# ----------------------------------------------------------------------------------------


class ShellGameRenderCupInfoWrapper(RenderOverlayWrapper):
    """Draw ``Target: Left/Center/Right`` at (10, 60) from ``oracle_info``.

    Other scalar answers show ``Target: <n>``, vector answers ``Oracle: [...]``, and a
    missing answer ``Target: N/A``.
    """

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's answer cup."""
        oracle = self._value("oracle_info", i)
        if oracle is None:
            text = "Target: N/A"
        else:
            arr = np.asarray(oracle).reshape(-1)
            if arr.size == 1:
                k = int(arr[0])
                text = f"Target: {CUP_NAMES.get(k, k)}"
            else:
                text = f"Oracle: {arr.tolist()}"
        draw_text(frame, text, (10, 60), 1.0, WHITE, 2)


class RotateRenderAngleInfoWrapper(RenderOverlayWrapper):
    """Draw the target angle (``task_cue``) at (10, 60) and the current one
    (``relative_angle``) at (10, 120), in degrees with 2 decimals."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target and current peg angles."""
        target = scalar(self._value("task_cue", i))
        if target is not None:
            draw_text(frame, f"Target : {np.degrees(target):.2f} deg", (10, 60), 1.0, WHITE, 2)
        current = scalar(self._value("relative_angle", i))
        if current is not None:
            draw_text(frame, f"Current: {np.degrees(current):.2f} deg", (10, 120), 1.0, WHITE, 2)


# ----------------------------------------------------------------------------------------
# long-horizon families
# ----------------------------------------------------------------------------------------


class MemoryCapacityInfoWrapper(RenderOverlayWrapper):
    """Draw ``Target: `` and one 15 px swatch per target colour id in ``oracle_info``.

    Swatches sit 10 px apart at y 45-60; the outline is white once that colour's cube is
    touched (``env.touched_cubes``), black otherwise.
    """

    def _touched(self, color_id: int, i: int) -> bool:
        touched = getattr(self.env.unwrapped, "touched_cubes", None)
        if touched is None:
            return False
        try:
            if isinstance(touched, dict):
                return bool(scalar(per_env(lookup(touched, color_id), i)))
            row = per_env(touched, i)
            return bool(np.asarray(row).reshape(-1)[color_id])
        except (IndexError, TypeError, ValueError):
            return False

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target colours and touched state."""
        oracle = self._value("oracle_info", i)
        if oracle is None:
            return
        ids = [int(v) for v in np.asarray(oracle).reshape(-1)]
        color_dict = getattr(self.env.unwrapped, "color_dict", None)
        draw_text(frame, "Target: ", (10, 60), 1.0, WHITE, 2)
        x = 10 + text_size("Target: ", 1.0, 2)[0]
        for j, cid in enumerate(ids):
            fill = to_rgb255(lookup(color_dict, cid)) or _CAPACITY_PALETTE.get(cid, WHITE)
            outline = WHITE if self._touched(cid, i) else BLACK
            draw_swatch(frame, x + j * (15 + 10), 45, 15, fill, outline, 2)


class RenderWorkingBatteriesInfoWrapper(RenderOverlayWrapper):
    """Draw ``Working found: <found>/<target>`` at (10, 150), scale 0.8
    (``found_working_count`` / ``target_working_count``)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's battery progress."""
        found = scalar(self._value("found_working_count", i))
        target = scalar(self._value("target_working_count", i))
        if found is None or target is None:
            return
        draw_text(frame, f"Working found: {int(found)}/{int(target)}", (10, 150), 0.8, WHITE, 2)


class RenderPressProgressInfoWrapper(RenderOverlayWrapper):
    """Draw ``Press raw/conf: <raw>/<confirmed>/<target>`` at (10, 120), scale 0.8
    (``raw_press_count`` / ``press_count`` / ``target_blinks``)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's button-press progress."""
        values = [
            scalar(self._value(name, i))
            for name in ("raw_press_count", "press_count", "target_blinks")
        ]
        if any(v is None for v in values):
            return
        raw, conf, target = (int(v) for v in values)
        draw_text(frame, f"Press raw/conf: {raw}/{conf}/{target}", (10, 120), 0.8, WHITE, 2)


class RenderTraceShapeDebugWrapper(RenderOverlayWrapper):
    """Draw a 160 px translucent minimap of the trace task (top-left, from y = 130).

    Shows the reference waypoints, the green cube's trail, the checkpoints (green visited,
    blue not), the shape name with the visited count, the phase (PRE-DEMO/DEMO/ACTION) and
    ``Closed: YES/NO``. For TraceShapeSeq the active element is drawn.
    """

    MAP_X, MAP_Y, MAP_SIZE = 10, 130, 160
    MAX_TRAIL = 4000

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._trails: dict[int, list[tuple[float, float]]] = {}

    def _record_trail(self) -> None:
        cube = getattr(self.env.unwrapped, "green_cube", None)
        try:
            xy = to_numpy(cube.pose.p)[:, :2]
        except AttributeError:
            return
        for i, (x, y) in enumerate(np.asarray(xy, dtype=np.float64)):
            trail = self._trails.setdefault(i, [])
            if len(trail) < self.MAX_TRAIL:
                trail.append((float(x), float(y)))

    def reset(self, **kwargs: Any):
        """Reset and start new trails."""
        obs, info = super().reset(**kwargs)
        self._trails = {}
        self._record_trail()
        return obs, info

    def step(self, action: Any):
        """Step and extend the green cube's trail."""
        out = super().step(action)
        self._record_trail()
        return out

    def _active(self, i: int) -> int | None:
        active = scalar(self._value("active_shape_idx", i))
        return int(active) if active is not None else None

    def _element(self, value: Any, i: int, per_element_ndim: int) -> np.ndarray | None:
        """Env i's array for the drawn element (the active one for sequences)."""
        row = per_env(value, i)
        if row is None:
            return None
        arr = np.asarray(row)
        if arr.ndim == per_element_ndim + 1:  # TraceShapeSeq: one entry per element
            arr = arr[self._active(i) or 0]
        return arr if arr.ndim == per_element_ndim else None

    def _phase(self, i: int) -> str | None:
        for key, label in (
            ("action_mask", "ACTION"),
            ("demo_mask", "DEMO"),
            ("pre_demo_mask", "PRE-DEMO"),
        ):
            v = scalar(per_env(self.last_info.get(key), i))
            if v:
                return label
        return None

    def _shape_name(self, i: int) -> str | None:
        sid = scalar(self._value("shape_type", i))
        if sid is None:
            seq = per_env(getattr(self.env.unwrapped, "shape_sequence", None), i)
            if seq is not None:
                seq = np.asarray(seq).reshape(-1)
                idx = self._active(i) or 0
                sid = float(seq[idx]) if idx < seq.size else None
        if sid is None:
            return None
        return _TRACE_SHAPE_NAMES.get(int(sid), str(int(sid)))

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's minimap and trace status."""
        base = self.env.unwrapped
        waypoints = self._element(getattr(base, "waypoints", None), i, 2)
        checkpoints = self._element(getattr(base, "checkpoints", None), i, 2)
        visited = self._element(getattr(base, "checkpoint_visited", None), i, 1)
        if waypoints is None and checkpoints is None:
            return
        h, w = frame.shape[:2]
        x0, y0, size = self.MAP_X, self.MAP_Y, self.MAP_SIZE
        x1, y1 = min(x0 + size, w), min(y0 + size, h)
        if x1 <= x0 or y1 <= y0:
            return
        roi = frame[y0:y1, x0:x1]
        roi[:] = (roi.astype(np.float32) * 0.4 + 30 * 0.6).astype(np.uint8)

        pts = np.concatenate([a for a in (waypoints, checkpoints) if a is not None]).astype(
            np.float64
        )
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        span = float(max(hi[0] - lo[0], hi[1] - lo[1], 1e-6)) * 1.25
        mid = (lo + hi) / 2

        def to_px(p: np.ndarray) -> np.ndarray:
            # World +x points up the map and world +y to the left, as seen from the robot.
            u = x0 + size / 2 - (p[..., 1] - mid[1]) / span * size
            v = y0 + size / 2 - (p[..., 0] - mid[0]) / span * size
            return np.stack([u, v], axis=-1).round().astype(np.int32)

        if waypoints is not None:
            cv2.polylines(frame, [to_px(waypoints)], True, (200, 200, 200), 1, cv2.LINE_AA)
        trail = self._trails.get(i)
        if trail and len(trail) > 1:
            cv2.polylines(frame, [to_px(np.asarray(trail))], False, (50, 220, 50), 1, cv2.LINE_AA)
        n_visited = None
        if checkpoints is not None:
            flags = np.zeros(len(checkpoints), bool)
            if visited is not None and visited.size == len(checkpoints):
                flags = visited.astype(bool)
            n_visited = int(flags.sum())
            for (u, v), hit in zip(to_px(checkpoints), flags, strict=True):
                color = (0, 200, 0) if hit else (60, 120, 255)
                cv2.circle(frame, (int(u), int(v)), 3, color, -1, cv2.LINE_AA)

        lines = []
        name = self._shape_name(i)
        if name is not None:
            total = len(checkpoints) if checkpoints is not None else 0
            lines.append(f"{name} {n_visited}/{total}" if n_visited is not None else name)
        phase = self._phase(i)
        if phase is not None:
            lines.append(phase)
        closed = self.last_info.get(
            "is_contour_closed", self.last_info.get("is_active_contour_closed")
        )
        closed = scalar(per_env(closed, i))
        if closed is not None:
            lines.append(f"Closed: {'YES' if closed else 'NO'}")
        for row, text in enumerate(lines):
            draw_text(frame, text, (x0, y0 + size + 18 + 20 * row), 0.5, WHITE, 1)


class RenderTimedTransferInfoWrapper(RenderOverlayWrapper):
    """Draw the TimedTransfer timer near the right edge (x = width - 260).

    Lines: ``T-<steps left>`` to the target step (signal + delay), the phase
    (WAIT/COUNTING/WINDOW/LATE), ``[start,end] d=<delay>`` and ``ON RED`` / ``not on red``.
    """

    def _delay(self, i: int) -> float | None:
        delay = getattr(self.env.unwrapped, "DELAY_STEPS", None)
        if delay is None:
            return scalar(self._value("oracle_info", i))
        return scalar(per_env(delay, i))

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's timing state."""
        x = frame.shape[1] - 260
        e = scalar(per_env(self.elapsed_steps, i))
        signal = scalar(self._value("signal_step", i))
        start = scalar(self._value("window_start", i))
        end = scalar(self._value("window_end", i))
        delay = self._delay(i)
        lines: list[tuple[str, tuple[int, int, int]]] = []
        if e is not None and signal is not None and delay is not None:
            lines.append((f"T-{int(signal + delay - e)}", WHITE))
        if e is not None and None not in (signal, start, end):
            if e < signal:
                phase = "WAIT"
            elif e < start:
                phase = "COUNTING"
            elif e <= end:
                phase = "WINDOW"
            else:
                phase = "LATE"
            lines.append((phase, WHITE))
        if start is not None and end is not None:
            d = f" d={int(delay)}" if delay is not None else ""
            lines.append((f"[{int(start)},{int(end)}]{d}", WHITE))
        on_red = scalar(per_env(self.last_info.get("cube_on_red"), i))
        if on_red is not None:
            lines.append(("ON RED", (255, 80, 80)) if on_red else ("not on red", WHITE))
        for row, (text, color) in enumerate(lines):
            draw_text(frame, text, (x, 30 + 30 * row), 0.8, color, 2)
