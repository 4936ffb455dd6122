"""Render-only overlay wrappers (debug text and markers drawn on ``env.render()`` frames).

Every overlay passes ``reset``/``step`` through unchanged, remembering the latest ``info``,
reward and ``elapsed_steps``, and draws on the frames returned by ``render()`` (one per
env), which it first converts to contiguous uint8 numpy arrays. Values are read from
``info`` first and from ``env.unwrapped`` attributes second; a value that is missing (for
example on a family that does not define it) is simply not drawn.
"""

from __future__ import annotations

import os
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import torch
from mikasa_envs.building_blocks.shapes import SHAPE_NAMES

from ._drawing import (
    BLACK,
    WHITE,
    draw_swatch,
    draw_text,
    frames_to_uint8,
    restore_batching,
    text_size,
    to_rgb255,
)

__all__ = [
    "RenderStepInfoWrapper",
    "RenderRewardInfoWrapper",
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
    "DebugRewardWrapper",
    "DISABLE_REWARD_OVERLAY_ENV_VAR",
    "reward_overlay_disabled",
    "COLOR_MEMORY",
    "SHAPE_MEMORY",
    "SHAPE_COLOR_MEMORY",
    "SHELL_GAME",
    "INTERCEPT",
    "ROTATE",
    "MEMORY_CAPACITY",
    "BATTERIES_CHECKER",
    "BLINK_COUNT",
    "TRACE_SHAPE",
    "TIMED_TRANSFER",
    "STEP_REWARD",
    "OVERLAY_CHAINS",
]

DISABLE_REWARD_OVERLAY_ENV_VAR = "MIKASA_DISABLE_REWARD_OVERLAY"
_TRUTHY = {"1", "true", "yes", "y", "on"}

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


def reward_overlay_disabled() -> bool:
    """Whether ``MIKASA_DISABLE_REWARD_OVERLAY`` is set to 1/true/yes/y/on (any case)."""
    return os.environ.get(DISABLE_REWARD_OVERLAY_ENV_VAR, "").strip().lower() in _TRUTHY


# ----------------------------------------------------------------------------------------
# value access helpers
# ----------------------------------------------------------------------------------------


def _to_numpy(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    return value


def _per_env(value: Any, i: int) -> Any:
    """Env i's entry of a batched value; unbatched scalars are returned as they are."""
    value = _to_numpy(value)
    if value is None:
        return None
    if isinstance(value, (list, tuple)):
        if not value:
            return None
        return value[i] if i < len(value) else None
    if isinstance(value, np.ndarray):
        if value.ndim == 0:
            return value.item()
        return value[i] if i < value.shape[0] else None
    return value


def _scalar(value: Any) -> float | None:
    """A single finite number from a value (first element of an array), or None."""
    if value is None:
        return None
    try:
        arr = np.asarray(_to_numpy(value), dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        return None
    if not arr.size or not np.isfinite(arr[0]):
        return None
    return float(arr[0])


def _lookup(table: Any, key: int) -> Any:
    """``table[key]`` for dicts (int or str keys) and sequences; None if absent."""
    if table is None:
        return None
    if isinstance(table, dict):
        for k in (key, str(key)):
            if k in table:
                return table[k]
        return None
    try:
        return table[key]
    except (IndexError, KeyError, TypeError):
        return None


# ----------------------------------------------------------------------------------------
# base class
# ----------------------------------------------------------------------------------------


class _RenderOverlayWrapper(gym.Wrapper):
    """Base class: remember info/reward/steps and draw on every rendered frame."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.last_info: dict = {}
        self.last_reward: Any = None
        self.elapsed_steps: Any = None

    def _remember(self, info: Any, reward: Any) -> None:
        self.last_info = info if isinstance(info, dict) else {}
        self.last_reward = reward
        self.elapsed_steps = self.last_info.get("elapsed_steps")

    def reset(self, **kwargs: Any):
        """Reset and remember the info (the reward is unset until the first step)."""
        obs, info = self.env.reset(**kwargs)
        self._remember(info, None)
        return obs, info

    def step(self, action: Any):
        """Step and remember info, reward and ``elapsed_steps``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._remember(info, reward)
        return obs, reward, terminated, truncated, info

    def _value(self, name: str, i: int) -> Any:
        """Env i's value of ``name`` from the latest info, else from the base env."""
        value = self.last_info.get(name)
        if value is None:
            value = getattr(self.env.unwrapped, name, None)
        return _per_env(value, i)

    def render(self):
        """Render through the inner env and draw this overlay on each env's frame."""
        frames = self.env.render()
        if not isinstance(frames, (torch.Tensor, np.ndarray)):
            return frames  # None, or a viewer in render_mode="human": nothing to draw on
        arr, batched = frames_to_uint8(frames)
        for i in range(arr.shape[0]):
            self.draw(arr[i], i)
        return restore_batching(arr, batched)

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw on env i's (H, W, 3) uint8 frame in place."""
        raise NotImplementedError


# ----------------------------------------------------------------------------------------
# generic overlays
# ----------------------------------------------------------------------------------------


class RenderStepInfoWrapper(_RenderOverlayWrapper):
    """Draw ``Step: <elapsed_steps>`` at (10, 30)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw the step counter of env i."""
        steps = _scalar(_per_env(self.elapsed_steps, i))
        if steps is not None:
            draw_text(frame, f"Step: {int(steps)}", (10, 30), 1.0, WHITE, 2)


class RenderRewardInfoWrapper(_RenderOverlayWrapper):
    """Draw ``Reward: <r>`` (latest step reward, 3 decimals) at (10, 90).

    Draws nothing while ``MIKASA_DISABLE_REWARD_OVERLAY`` is 1/true/yes/y/on.
    """

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw the latest reward of env i (0.000 before the first step)."""
        if reward_overlay_disabled():
            return
        reward = 0.0 if self.last_reward is None else _scalar(_per_env(self.last_reward, i))
        if reward is not None:
            draw_text(frame, f"Reward: {reward:.3f}", (10, 90), 1.0, WHITE, 2)


class DebugRewardWrapper(_RenderOverlayWrapper):
    """List every ``info["reward_dict"]`` entry (scale 0.5) from y = 170 down, 20 px apart."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's reward terms."""
        reward_dict = self.last_info.get("reward_dict")
        if not isinstance(reward_dict, dict):
            return
        for row, (key, value) in enumerate(reward_dict.items()):
            v = _scalar(_per_env(value, i))
            text = f"{key}: {v:.3f}" if v is not None else f"{key}: {value}"
            draw_text(frame, text, (10, 170 + 20 * row), 0.5, WHITE, 1)


# ----------------------------------------------------------------------------------------
# selection families
# ----------------------------------------------------------------------------------------


class RememberColorInfoWrapper(_RenderOverlayWrapper):
    """Draw ``Target:`` and a 22 px swatch of ``color_dict[oracle_info]`` (white if unknown).

    Used for RememberColor and FindImposterColor (where it shows the imposter's colour).
    """

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target colour."""
        key = _scalar(self._value("oracle_info", i))
        if key is None:
            return
        color_dict = getattr(self.env.unwrapped, "color_dict", None)
        fill = to_rgb255(_lookup(color_dict, int(key))) or WHITE
        draw_text(frame, "Target:", (10, 60), 1.0, WHITE, 2)
        width, _ = text_size("Target:", 1.0, 2)
        draw_swatch(frame, 10 + width + 10, 38, 22, fill, WHITE, 2)


class RememberShapeInfoWrapper(_RenderOverlayWrapper):
    """Draw ``Target: <shape name>`` (names by index, see ``SHAPE_NAMES``) at (10, 60)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target shape name."""
        key = _scalar(self._value("oracle_info", i))
        if key is None:
            return
        k = int(key)
        name = SHAPE_NAMES[k] if 0 <= k < len(SHAPE_NAMES) else str(k)
        draw_text(frame, f"Target: {name}", (10, 60), 1.0, WHITE, 2)


class RememberShapeAndColorInfoWrapper(_RenderOverlayWrapper):
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
        fill = to_rgb255(_lookup(getattr(base, "COLOR_PALETTE", None), color_id))
        fill = fill or _RGB_FALLBACK.get(color_id, WHITE)
        name = _lookup(getattr(base, "BASE_SHAPES", None), shape_id)
        name = str(name) if name is not None else "Unknown"
        draw_text(frame, "Target:", (10, 60), 1.0, WHITE, 2)
        width, _ = text_size("Target:", 1.0, 2)
        x = 10 + width + 10
        draw_swatch(frame, x, 38, 22, fill, WHITE, 2)
        draw_text(frame, name, (x + 22 + 12, 60), 1.0, WHITE, 2)


# ----------------------------------------------------------------------------------------
# shell games, rotate
# ----------------------------------------------------------------------------------------


class ShellGameRenderCupInfoWrapper(_RenderOverlayWrapper):
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


class RotateRenderAngleInfoWrapper(_RenderOverlayWrapper):
    """Draw the target angle (``task_cue``) at (10, 60) and the current one
    (``relative_angle``) at (10, 120), in degrees with 2 decimals."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's target and current peg angles."""
        target = _scalar(self._value("task_cue", i))
        if target is not None:
            draw_text(frame, f"Target : {np.degrees(target):.2f} deg", (10, 60), 1.0, WHITE, 2)
        current = _scalar(self._value("relative_angle", i))
        if current is not None:
            draw_text(frame, f"Current: {np.degrees(current):.2f} deg", (10, 120), 1.0, WHITE, 2)


# ----------------------------------------------------------------------------------------
# long-horizon families
# ----------------------------------------------------------------------------------------


class MemoryCapacityInfoWrapper(_RenderOverlayWrapper):
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
                return bool(_scalar(_per_env(_lookup(touched, color_id), i)))
            row = _per_env(touched, i)
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
            fill = to_rgb255(_lookup(color_dict, cid)) or _CAPACITY_PALETTE.get(cid, WHITE)
            outline = WHITE if self._touched(cid, i) else BLACK
            draw_swatch(frame, x + j * (15 + 10), 45, 15, fill, outline, 2)


class RenderWorkingBatteriesInfoWrapper(_RenderOverlayWrapper):
    """Draw ``Working found: <found>/<target>`` at (10, 150), scale 0.8
    (``found_working_count`` / ``target_working_count``)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's battery progress."""
        found = _scalar(self._value("found_working_count", i))
        target = _scalar(self._value("target_working_count", i))
        if found is None or target is None:
            return
        draw_text(frame, f"Working found: {int(found)}/{int(target)}", (10, 150), 0.8, WHITE, 2)


class RenderPressProgressInfoWrapper(_RenderOverlayWrapper):
    """Draw ``Press raw/conf: <raw>/<confirmed>/<target>`` at (10, 120), scale 0.8
    (``raw_press_count`` / ``press_count`` / ``target_blinks``)."""

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's button-press progress."""
        values = [
            _scalar(self._value(name, i))
            for name in ("raw_press_count", "press_count", "target_blinks")
        ]
        if any(v is None for v in values):
            return
        raw, conf, target = (int(v) for v in values)
        draw_text(frame, f"Press raw/conf: {raw}/{conf}/{target}", (10, 120), 0.8, WHITE, 2)


class RenderTraceShapeDebugWrapper(_RenderOverlayWrapper):
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
            xy = _to_numpy(cube.pose.p)[:, :2]
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
        active = _scalar(self._value("active_shape_idx", i))
        return int(active) if active is not None else None

    def _element(self, value: Any, i: int, per_element_ndim: int) -> np.ndarray | None:
        """Env i's array for the drawn element (the active one for sequences)."""
        row = _per_env(value, i)
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
            v = _scalar(_per_env(self.last_info.get(key), i))
            if v:
                return label
        return None

    def _shape_name(self, i: int) -> str | None:
        sid = _scalar(self._value("shape_type", i))
        if sid is None:
            seq = _per_env(getattr(self.env.unwrapped, "shape_sequence", None), i)
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
        closed = _scalar(_per_env(closed, i))
        if closed is not None:
            lines.append(f"Closed: {'YES' if closed else 'NO'}")
        for row, text in enumerate(lines):
            draw_text(frame, text, (x0, y0 + size + 18 + 20 * row), 0.5, WHITE, 1)


class RenderTimedTransferInfoWrapper(_RenderOverlayWrapper):
    """Draw the TimedTransfer timer near the right edge (x = width - 260).

    Lines: ``T-<steps left>`` to the target step (signal + delay), the phase
    (WAIT/COUNTING/WINDOW/LATE), ``[start,end] d=<delay>`` and ``ON RED`` / ``not on red``.
    """

    def _delay(self, i: int) -> float | None:
        delay = getattr(self.env.unwrapped, "DELAY_STEPS", None)
        if delay is None:
            return _scalar(self._value("oracle_info", i))
        return _scalar(_per_env(delay, i))

    def draw(self, frame: np.ndarray, i: int) -> None:
        """Draw env i's timing state."""
        x = frame.shape[1] - 260
        e = _scalar(_per_env(self.elapsed_steps, i))
        signal = _scalar(self._value("signal_step", i))
        start = _scalar(self._value("window_start", i))
        end = _scalar(self._value("window_end", i))
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
        on_red = _scalar(_per_env(self.last_info.get("cube_on_red"), i))
        if on_red is not None:
            lines.append(("ON RED", (255, 80, 80)) if on_red else ("not on red", WHITE))
        for row, (text, color) in enumerate(lines):
            draw_text(frame, text, (x, 30 + 30 * row), 0.8, color, 2)


# ----------------------------------------------------------------------------------------
# named chains (inner -> outer)
# ----------------------------------------------------------------------------------------

COLOR_MEMORY = (RememberColorInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
SHAPE_MEMORY = (RememberShapeInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
SHAPE_COLOR_MEMORY = (
    RememberShapeAndColorInfoWrapper,
    RenderStepInfoWrapper,
    RenderRewardInfoWrapper,
)
SHELL_GAME = (RenderStepInfoWrapper, ShellGameRenderCupInfoWrapper, RenderRewardInfoWrapper)
INTERCEPT = (RenderStepInfoWrapper, RenderRewardInfoWrapper)
ROTATE = (RenderStepInfoWrapper, RenderRewardInfoWrapper, RotateRenderAngleInfoWrapper)
MEMORY_CAPACITY = (MemoryCapacityInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
BATTERIES_CHECKER = (
    RenderWorkingBatteriesInfoWrapper,
    RenderStepInfoWrapper,
    RenderRewardInfoWrapper,
)
BLINK_COUNT = (RenderPressProgressInfoWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
TRACE_SHAPE = (RenderTraceShapeDebugWrapper, RenderStepInfoWrapper, RenderRewardInfoWrapper)
TIMED_TRANSFER = (
    RenderTimedTransferInfoWrapper,
    RenderStepInfoWrapper,
    RenderRewardInfoWrapper,
)
STEP_REWARD = (RenderStepInfoWrapper, RenderRewardInfoWrapper)

OVERLAY_CHAINS: dict[str, tuple[type[gym.Wrapper], ...]] = {
    "COLOR_MEMORY": COLOR_MEMORY,
    "SHAPE_MEMORY": SHAPE_MEMORY,
    "SHAPE_COLOR_MEMORY": SHAPE_COLOR_MEMORY,
    "SHELL_GAME": SHELL_GAME,
    "INTERCEPT": INTERCEPT,
    "ROTATE": ROTATE,
    "MEMORY_CAPACITY": MEMORY_CAPACITY,
    "BATTERIES_CHECKER": BATTERIES_CHECKER,
    "BLINK_COUNT": BLINK_COUNT,
    "TRACE_SHAPE": TRACE_SHAPE,
    "TIMED_TRANSFER": TIMED_TRANSFER,
    "STEP_REWARD": STEP_REWARD,
}
"""The named overlay chains of the per-task table, by name."""
