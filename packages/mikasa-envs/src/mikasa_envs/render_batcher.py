"""Several envs of one process, stepped by their own threads, rendered in one GPU pass.

On a machine with a GPU, CPU-simulated envs each render a handful of 128x128 pictures per step:
the GPU does almost no work per pass, and what limits a pool of worker processes is the
number of passes the processes queue on the one GPU (measured on an H200: 16 processes
together finished ~29 episodes/s however small each pass). A `RenderBatcher` lets one
process run K envs in K threads and render all their cameras with one
`CameraGroupRenderer` pass: K times fewer passes for the same number of env steps.

How the threads meet: a thread that runs an episode holds `participating()`; an env that
needs its pictures calls `render`, which waits. When every participating thread is waiting,
the batcher's own thread renders all their scenes at once and wakes them. A thread that
does something else between episodes (waits for a job, builds an env) does not hold
`participating()`, so it never holds the others up; a render requested outside it joins
the next pass on its own. The pictures of a scene do not depend on which other scenes
share its pass, so results do not depend on the number of threads.

Process-wide random state: ManiSkill's reset reseeds torch's global RNG and the tasks draw
their layouts from it, so two threads resetting at once would mix their draws. Code that
uses the global RNGs runs inside `global_rng_section()`, one thread at a time (the envs'
``reset`` does); a render requested inside it is made at once, without waiting for the
other threads, which may be queued on the section.

The group is rebuilt when the set of scenes changes (an env is built, rebuilt or closed):
SAPIEN fixes a group's scenes when it is created. Env code only calls `render` and
`forget`; `install_batcher` (done by a worker that runs several env threads) turns it on.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import torch

from mikasa_envs.camera_group import CameraGroupRenderer, SceneCameras

__all__ = [
    "RenderBatcher",
    "active_batcher",
    "global_rng_section",
    "install_batcher",
    "participating",
    "uninstall_batcher",
]

_GLOBAL_RNG_LOCK = threading.RLock()
_section = threading.local()


@contextlib.contextmanager
def global_rng_section() -> Iterator[None]:
    """Run a block that uses the process's global RNGs with no other thread inside one."""
    with _GLOBAL_RNG_LOCK:
        _section.depth = getattr(_section, "depth", 0) + 1
        try:
            yield
        finally:
            _section.depth -= 1


def _in_global_rng_section() -> bool:
    return getattr(_section, "depth", 0) > 0


@dataclass(eq=False)
class _Request:
    owner: Any
    view: SceneCameras
    device: torch.device
    urgent: bool = False  # made inside a global RNG section: rendered without waiting
    images: dict[str, torch.Tensor] | None = None
    error: BaseException | None = None
    done: bool = False


class RenderBatcher:
    """Renders the cameras of envs stepped by several threads in shared GPU passes."""

    def __init__(self, group_factory: Callable[..., Any] = CameraGroupRenderer) -> None:
        self._group_factory = group_factory  # (views, device, first_group) -> .render_all(refresh)
        self._cond = threading.Condition()
        self._active = 0
        self._pending: list[_Request] = []
        self._views: dict[int, _Request] = {}  # id(owner) -> its latest request (scene, device)
        self._group: Any = None
        self._order: list[int] = []  # id(owner) of the group's scenes, in group order
        self._grouped: set[int] = set()  # id(owner) whose current scene was in a group
        self._rendering = False
        self._closed = False
        self._local = threading.local()
        self.passes = 0
        """Render passes made (each serves every scene that was waiting)."""
        self.pictures = 0
        """Scene renders delivered to waiting envs."""
        self._thread = threading.Thread(target=self._loop, name="mikasa-render-batcher", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------ thread side
    @contextlib.contextmanager
    def participating(self) -> Iterator[None]:
        """Held by a thread while it steps an env: passes wait for it to request a render."""
        with self._cond:
            self._active += 1
        self._local.depth = getattr(self._local, "depth", 0) + 1
        try:
            yield
        finally:
            self._local.depth -= 1
            with self._cond:
                self._active -= 1
                self._cond.notify_all()

    def render(self, owner: Any, view: SceneCameras, device: torch.device) -> dict[str, torch.Tensor]:
        """Pictures of ``view``'s cameras at its scene's current poses (name -> uint8
        [1, H, W, 3] on the CPU), rendered in the next shared pass. ``owner`` (the env)
        identifies the scene across calls."""
        if not getattr(self._local, "depth", 0):
            with self.participating():
                return self.render(owner, view, device)
        request = _Request(owner, view, device, urgent=_in_global_rng_section())
        with self._cond:
            if self._closed:
                raise RuntimeError("the render batcher is closed")
            self._pending.append(request)
            self._cond.notify_all()
            self._cond.wait_for(lambda: request.done)
        if request.error is not None:
            raise RuntimeError(f"batched render failed: {request.error}") from request.error
        assert request.images is not None
        return request.images

    def forget(self, owner: Any) -> None:
        """Drop ``owner``'s scene (its env is closing or rebuilding its scene); waits for a
        pass in flight, which may still read that scene."""
        with self._cond:
            self._cond.wait_for(lambda: not self._rendering)
            if self._views.pop(id(owner), None) is not None:
                self._group = None
            self._grouped.discard(id(owner))

    def close(self) -> None:
        """Stop the batcher's thread; later renders raise."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout=10)

    # ----------------------------------------------------------- render side
    def _ready(self) -> bool:
        if self._closed or any(r.urgent for r in self._pending):
            return True
        return bool(self._pending) and len(self._pending) >= self._active

    def _loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(self._ready)
                batch, self._pending = self._pending, []
                if self._closed:
                    for request in batch:
                        request.error, request.done = RuntimeError("the render batcher is closed"), True
                    self._cond.notify_all()
                    return
                self._rendering = True
            try:
                images = self._render(batch)
                error = None
            except BaseException as exc:  # handed to every waiting thread
                images, error = {}, exc
                self._group = None
            with self._cond:
                for request in batch:
                    request.images = images.get(id(request.owner))
                    request.error = error
                    request.done = True
                self._rendering = False
                self.passes += 1
                self.pictures += len(batch)
                self._cond.notify_all()

    def _render(self, batch: list[_Request]) -> dict[int, dict[str, torch.Tensor]]:
        for request in batch:
            key = id(request.owner)
            known = self._views.get(key)
            if known is None or known.view[0] is not request.view[0]:
                self._group = None
                self._grouped.discard(key)
            self._views[key] = request
        if self._group is None:
            self._order = list(self._views)
            known = [self._views[key] for key in self._order]
            first = [key not in self._grouped for key in self._order]
            self._group = self._group_factory([r.view for r in known], known[0].device, first)
            self._grouped.update(self._order)
        # Only the waiting threads' scenes are read: another thread may be stepping its
        # scene right now, and its pictures are not wanted in this pass anyway.
        waiting = {id(r.owner) for r in batch}
        refresh = [i for i, key in enumerate(self._order) if key in waiting]
        pictures = self._group.render_all(refresh)
        return dict(zip(self._order, pictures, strict=True))


_installed: RenderBatcher | None = None


def install_batcher() -> RenderBatcher:
    """Turn batching on for this process (envs that render through camera groups use it)."""
    global _installed
    if _installed is None:
        _installed = RenderBatcher()
    return _installed


def uninstall_batcher() -> None:
    """Turn batching off again and stop the batcher's thread."""
    global _installed
    batcher, _installed = _installed, None
    if batcher is not None:
        batcher.close()


def active_batcher() -> RenderBatcher | None:
    """The process's batcher, if `install_batcher` was called."""
    return _installed


def participating() -> contextlib.AbstractContextManager[None]:
    """`RenderBatcher.participating` of the installed batcher, or a no-op without one."""
    return _installed.participating() if _installed is not None else contextlib.nullcontext()
