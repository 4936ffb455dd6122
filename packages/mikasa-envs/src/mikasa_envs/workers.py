"""Worker processes that own envs: the loop and the shutdown shared by the process pools
of mikasa-bench (evaluation) and mikasa-oracles (demonstration collection).

A pool starts its workers with the ``spawn`` method (a fresh interpreter: SAPIEN and
Vulkan do not survive ``fork``). Each worker builds its state once, then runs jobs from its
inbox and puts ``("done", worker_id, result)`` on the shared outbox until it gets ``None``.

A process may serve several workers ("slots"), one thread each with its own inbox and
state (`serve_job_slots`): their envs then share GPU render passes (`render_batcher`).
"""

from __future__ import annotations

import glob
import logging
import multiprocessing as mp
import os
import queue
import signal
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any, Protocol

__all__ = [
    "JobRunner",
    "quiet_worker",
    "serve_job_slots",
    "serve_jobs",
    "stop_processes",
    "use_one_gpu",
    "visible_gpus",
]


class JobRunner(Protocol):
    """What a worker's state offers: ``run(job) -> result`` and ``close()``."""

    def run(self, job: Any) -> Any: ...

    def close(self) -> None: ...


def quiet_worker(*, one_raster_thread: bool = True) -> None:
    """Prepare a pool's worker process: one thread for torch (and, with
    ``one_raster_thread``, for Mesa's CPU Vulkan rasteriser, whose frames do not depend on
    it), since the pool already uses every core; register the envs; hush ManiSkill's
    per-process 'no CUDA render device' warning (every worker of a CPU machine would print
    it; a worker told to render on the GPU checks for itself). Call it first in the worker."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if one_raster_thread:
        os.environ.setdefault("LP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    import mikasa_envs  # noqa: F401  (registers the envs once per process)

    # ManiSkill's logger is named "mani_skill " (trailing space) and sets its level when
    # imported, so this has to come after the import.
    for name in ("mani_skill ", "mani_skill"):
        logging.getLogger(name).setLevel(logging.ERROR)


def visible_gpus() -> list[str]:
    """The CUDA devices this process may use, as ``CUDA_VISIBLE_DEVICES`` entries, found
    without initialising CUDA: that variable's entries when it is set (as CUDA reads it, up
    to the first empty or ``-1`` entry), else one index per NVIDIA device node
    (``/dev/nvidia0``, ``/dev/nvidia1``, ...; a container shows only the GPUs it was given)."""
    given = os.environ.get("CUDA_VISIBLE_DEVICES")
    if given is not None:
        gpus: list[str] = []
        for entry in given.split(","):
            if entry.strip() in ("", "-1"):
                break
            gpus.append(entry.strip())
        return gpus
    return [str(i) for i in range(len(glob.glob("/dev/nvidia[0-9]*")))]


def use_one_gpu(process_index: int) -> None:
    """Show this worker process one GPU, the ``process_index``-th (round robin) of those it
    can see, before anything initialises CUDA (importing torch or ManiSkill does not).

    ManiSkill's reset forks torch's RNG on every visible CUDA device
    (``torch.random.fork_rng``), so a worker that saw all GPUs opened a CUDA context on each
    (on a 4-GPU machine, 128 env workers took ~3 minutes to start). Round robin spreads the
    workers' GPU rendering over the machine's GPUs. No GPU visible: nothing changes."""
    gpus = visible_gpus()
    if gpus:
        os.environ["CUDA_VISIBLE_DEVICES"] = gpus[process_index % len(gpus)]


def serve_jobs(worker_id: int, inbox: Any, outbox: Any, start: Callable[[], JobRunner]) -> None:
    """The body of a worker process.

    Ignores Ctrl-C (it reaches the whole process group; the parent decides and stops the
    pool). ``start()`` builds the worker's state; if it raises, the traceback goes to the
    parent as ``("fatal", worker_id, text)``; else ``("ready", worker_id, None)`` is sent.
    A worker whose parent died (kill -9) exits instead of idling forever.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _serve(worker_id, inbox, outbox, start)


def serve_job_slots(
    worker_ids: Sequence[int],
    inboxes: Sequence[Any],
    outbox: Any,
    start: Callable[[int], JobRunner],
) -> None:
    """The body of a worker process that serves several workers, one thread each.

    Worker ``worker_ids[i]`` reads ``inboxes[i]`` and runs its jobs on ``start(worker_ids[i])``;
    each behaves as a `serve_jobs` worker towards the parent. With more than one slot the
    process's `render_batcher` is installed, so the slots' envs render together.
    """
    if len(worker_ids) != len(inboxes):
        raise ValueError("serve_job_slots needs one inbox per worker id")
    if len(worker_ids) == 1:
        serve_jobs(worker_ids[0], inboxes[0], outbox, lambda: start(worker_ids[0]))
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from mikasa_envs import render_batcher

    render_batcher.install_batcher()
    threads = [
        threading.Thread(
            target=_serve,
            args=(wid, inbox, outbox, lambda wid=wid: start(wid)),
            name=f"worker-slot-{wid}",
            daemon=True,
        )
        for wid, inbox in zip(worker_ids, inboxes, strict=True)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    render_batcher.uninstall_batcher()


def _serve(worker_id: int, inbox: Any, outbox: Any, start: Callable[[], JobRunner]) -> None:
    try:
        runner = start()
    except BaseException:
        outbox.put(("fatal", worker_id, traceback.format_exc()))
        return
    outbox.put(("ready", worker_id, None))
    parent = mp.parent_process()
    try:
        while True:
            try:
                job = inbox.get(timeout=1.0)
            except queue.Empty:
                if parent is not None and not parent.is_alive():
                    break
                continue
            if job is None:
                break
            outbox.put(("done", worker_id, runner.run(job)))
    finally:
        runner.close()


def stop_processes(processes: Sequence[Any], *, wait_s: float = 0.0) -> None:
    """Wait up to ``wait_s`` in all for ``processes`` to exit (after the caller sent them
    ``None``), then terminate, and finally kill, any still running."""
    deadline = time.monotonic() + wait_s
    if wait_s > 0:
        for p in processes:
            p.join(timeout=max(0.1, deadline - time.monotonic()))
    for p in processes:
        if p.is_alive():
            p.terminate()
    for p in processes:
        p.join(timeout=5)
        if p.is_alive():
            p.kill()
            p.join(timeout=5)
