"""One floating-point environment for the simulation, whatever thread steps it.

x86 keeps the rounding mode and the flush-to-zero / denormals-are-zero switches per thread
(MXCSR). Libraries may set them in the thread that loads or initialises them (a GPU driver,
code built with fast-math), so the same episode stepped from another thread can come out
different in the last bits; with several envs per process (threads) that made returns of
one episode differ by ~1e-7 between runs. Envs put the thread back to the C default at every
reset and step: the simulation then gives the same numbers in every thread and process.
"""

from __future__ import annotations

import ctypes
import sys
from collections.abc import Callable

__all__ = ["use_default_fp_environment"]


def _fesetenv() -> Callable[[], int] | None:
    if not sys.platform.startswith("linux"):
        return None
    try:
        libm = ctypes.CDLL("libm.so.6")
    except OSError:
        return None
    fesetenv = libm.fesetenv
    fesetenv.argtypes = [ctypes.c_void_p]
    fesetenv.restype = ctypes.c_int
    default_env = ctypes.c_void_p(-1)  # glibc's FE_DFL_ENV: ((const fenv_t *) -1)
    return lambda: fesetenv(default_env)


_set_default = _fesetenv()


def use_default_fp_environment() -> None:
    """Set the calling thread's floating-point environment to the C default (round to
    nearest, no flush-to-zero, no denormals-are-zero); a no-op off glibc."""
    if _set_default is not None:
        _set_default()
