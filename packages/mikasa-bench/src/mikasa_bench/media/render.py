"""Choosing where a worker renders: ManiSkill's render backend and Vulkan driver selection.

How ManiSkill 3.0.1 and SAPIEN 3 pick the render device (read from their sources):

* ``gym.make(..., render_backend=...)`` (default ``"gpu"``) goes through
  ``parse_sim_and_render_backend``: ``"gpu"``/``"cuda"``/``"sapien_cuda"`` ->
  ``sapien.Device("cuda")``, which falls back to ``sapien.Device("cpu")`` with a warning
  when no CUDA device is found; ``"cpu"``/``"sapien_cpu"`` -> ``sapien.Device("cpu")``;
  ``"none"`` disables rendering.
* SAPIEN then creates one Vulkan context per process on that device. For the ``cpu``
  device the Vulkan physical device is chosen *without a hint*, and that rule still
  prefers a device with a CUDA id: on a machine with an NVIDIA GPU, ``render_backend="cpu"``
  alone renders on the GPU. Only one render device per process is possible. (Read from
  the sources of SAPIEN and sapien-vulkan-2; on this project's CPU-only machines only
  lavapipe exists, so the GPU side is not yet observed. `check_render_device` verifies
  the outcome in every worker either way.)

So rendering on the CPU (Mesa's lavapipe) on a machine with a GPU needs the Vulkan loader to see
lavapipe only: a CPU-rendering worker sets ``VK_ICD_FILENAMES``/``VK_DRIVER_FILES`` to the
lavapipe driver manifest before its first env is made. That must happen before Vulkan is
initialised in the process, which is why the executors apply `worker_environment` when a
worker starts. Every worker checks, after building its first env, which device it really
renders on (`check_render_device`) and the runner journals it with each episode.

Lavapipe rasterises with ``LP_NUM_THREADS`` threads (default: every core). Several
CPU-rendering workers with the default oversubscribe the machine badly (measured on 2
cores: two workers with default threads made 5.8 steps/s together, one process alone 10);
the executors give each worker its share of the cores, and ``LP_NUM_THREADS=0`` (rasterise
in the calling thread) when that share is one core. Thread count does not change pixels.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from mikasa_bench.errors import BenchError

__all__ = [
    "LAVAPIPE_ICD_ENV",
    "find_lavapipe_icd",
    "worker_environment",
    "apply_environment",
    "gym_render_kwargs",
    "vulkan_devices",
    "check_render_device",
]

LAVAPIPE_ICD_ENV = "MIKASA_BENCH_LAVAPIPE_ICD"
"""Path of lavapipe's Vulkan driver manifest (``lvp_icd*.json``), if not in a standard place."""

_ICD_DIRS = (
    "/usr/share/vulkan/icd.d",
    "/usr/local/share/vulkan/icd.d",
    "/etc/vulkan/icd.d",
    "/usr/lib/x86_64-linux-gnu/vulkan/icd.d",
)
_CPU_DEVICE_NAMES = ("llvmpipe", "lavapipe", "softpipe", "swiftshader")

_GYM_RENDER_BACKEND = {"cpu": "sapien_cpu", "gpu": "sapien_cuda"}


def find_lavapipe_icd() -> str | None:
    """Path of lavapipe's Vulkan driver manifest, or None if Mesa's Vulkan drivers are not
    installed (Debian/Ubuntu: ``apt-get install mesa-vulkan-drivers``)."""
    given = os.environ.get(LAVAPIPE_ICD_ENV)
    if given:
        return given if os.path.isfile(given) else None
    for d in _ICD_DIRS:
        hits = sorted(glob.glob(os.path.join(d, "lvp_icd*.json")))
        if hits:
            return hits[0]
    return None


def worker_environment(device: str, *, lp_threads: int | None = None) -> dict[str, str]:
    """Environment variables a worker that renders on ``device`` sets before Vulkan starts.

    ``cpu``: only lavapipe is visible to the Vulkan loader (else SAPIEN would pick the
    GPU, see the module doc). ``lp_threads``: lavapipe's rasteriser threads.
    """
    env: dict[str, str] = {}
    if lp_threads is not None:
        env["LP_NUM_THREADS"] = str(int(lp_threads))
    if device == "cpu":
        icd = find_lavapipe_icd()
        if icd is not None:
            env["VK_ICD_FILENAMES"] = icd  # Vulkan loader < 1.3.207
            env["VK_DRIVER_FILES"] = icd  # newer loaders
    return env


def apply_environment(env: Mapping[str, str]) -> None:
    """Set ``env`` in this process; an ``LP_NUM_THREADS`` the user exported wins."""
    for key, value in env.items():
        if key == "LP_NUM_THREADS" and key in os.environ:
            continue
        os.environ[key] = value


def gym_render_kwargs(device: str) -> dict[str, Any]:
    """``gym.make`` keyword arguments for ``device`` (``auto``: ManiSkill's default)."""
    backend = _GYM_RENDER_BACKEND.get(device)
    return {} if backend is None else {"render_backend": backend}


@dataclass(frozen=True)
class VulkanDevice:
    """One entry of SAPIEN's device summary."""

    name: str
    supported: bool
    cuda_id: int

    @property
    def is_cpu(self) -> bool:
        """A software rasteriser (lavapipe/llvmpipe and the like)."""
        return any(k in self.name.lower() for k in _CPU_DEVICE_NAMES)


def vulkan_devices() -> list[VulkanDevice]:
    """The Vulkan devices SAPIEN sees in this process (parsed from its device summary)."""
    import sapien

    out: list[VulkanDevice] = []
    name: str | None = None
    fields: dict[str, str] = {}
    for line in sapien.render.get_device_summary().splitlines() + ["GPU: "]:
        line = line.strip()
        if line.startswith("GPU:"):
            if name is not None:
                out.append(
                    VulkanDevice(
                        name,
                        fields.get("Supported", "0") == "1",
                        int(fields.get("cudaId", "-1") or -1),
                    )
                )
            name, fields = line[4:].strip(), {}
        elif ":" in line:
            k, v = line.split(":", 1)
            fields[k.strip()] = v.strip()
    return [d for d in out if d.name]


def _render_backend(env: Any) -> str:
    """ManiSkill's render backend of ``env`` (``sapien_cpu``, ``sapien_cuda``; "" if the env
    is not a ManiSkill env)."""
    backend = getattr(getattr(env, "unwrapped", env), "backend", None)
    return str(getattr(backend, "render_backend", "") or "")


def _picked_device(backend: str) -> VulkanDevice | None:
    """The Vulkan device SAPIEN renders on in this process, for ManiSkill's ``backend``.

    SAPIEN's rule: with a CUDA hint the device with a CUDA id; without one (the ``cpu``
    device) the supported device with the highest priority, where a CUDA id counts most.
    """
    devices = [d for d in vulkan_devices() if d.supported]
    cuda = [d for d in devices if d.cuda_id >= 0]
    if backend == "sapien_cuda":
        return cuda[0] if cuda else None
    return cuda[0] if cuda else (devices[0] if devices else None)


def check_render_device(env: Any, requested: str) -> str:
    """Verify that ``env`` renders where ``requested`` says; return a description such as
    ``"cpu: llvmpipe (LLVM 15.0.6, 256 bits)"`` (journalled with every episode).

    Raises `BenchError` when ``gpu`` fell back to the CPU (no CUDA device) or ``cpu`` would
    render on a GPU (lavapipe missing, or Vulkan was initialised before the restriction).
    """
    backend = _render_backend(env)
    if backend in ("", "none", "None"):
        return "none"  # not a ManiSkill env (tests) or rendering disabled
    device = _picked_device(backend)
    kind = "cpu" if device is None or device.is_cpu else "gpu"
    name = device.name if device is not None else "unknown"
    if requested == "gpu" and kind != "gpu":
        raise BenchError(
            f"render device 'gpu' requested, but this worker has no CUDA-capable Vulkan "
            f"device (ManiSkill render backend {backend}, device {name}); use "
            f"--render-device auto or cpu"
        )
    if requested == "cpu" and kind != "cpu":
        icd = find_lavapipe_icd()
        why = (
            "Mesa's lavapipe Vulkan driver was not found (install mesa-vulkan-drivers or "
            f"set {LAVAPIPE_ICD_ENV} to its lvp_icd*.json)"
            if icd is None
            else "Vulkan was initialised in this process before the worker could restrict "
            "it to lavapipe (run with worker processes, not --workers 0)"
        )
        raise BenchError(f"render device 'cpu' requested, but rendering runs on {name}: {why}")
    return f"{kind}: {name}"
