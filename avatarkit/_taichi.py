"""The one place Taichi is initialised: lazily, on the CPU, quietly.

Every module with kernels calls `ensure_taichi()` before its first launch. Taichi prints a bare
"[Taichi] Starting on arch=..." line from C++ on init; we silence the process's stdout file
descriptor for that call only, so CLI output and piped data stay clean.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import sys
import threading

_lock = threading.Lock()
_ready = False


@contextlib.contextmanager
def _quiet_stdout():
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # stdout replaced (pytest capture, notebooks)
        with contextlib.redirect_stdout(open(os.devnull, "w")):
            yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            with contextlib.redirect_stdout(open(os.devnull, "w")):
                yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, fd)
        os.close(saved)


def _threads() -> int:
    """Kernel threads: all cores, or AVATARKIT_THREADS (batch workers share the cores)."""
    value = os.environ.get("AVATARKIT_THREADS", "")
    if value.strip():
        try:
            return max(1, int(value))
        except ValueError:
            pass  # a malformed override is ignored rather than breaking every command
    return os.cpu_count() or 2


def _restore_fp_environment() -> None:
    """`ti.init` leaves flush-to-zero / denormals-are-zero on in the calling thread. Left on,
    numpy in this process (and the host application's own numpy code) would flush subnormals
    too, and our numpy references would give different bits depending on whether Taichi had
    started. Put back the C default environment (glibc and musl spell FE_DFL_ENV as
    (fenv_t *) -1). Taichi's worker threads, which run the parallel loops, keep flushing; serial
    kernel code runs on this thread with IEEE subnormals (no slower on our kernels: the XPBD
    step measured 1.61 vs 1.58 ms)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libm = ctypes.CDLL(ctypes.util.find_library("m") or "libm.so.6")
        libm.fesetenv(ctypes.c_void_p(-1))
    except (OSError, AttributeError):  # no libm to call: numpy keeps Taichi's setting
        pass


def taichi_running() -> bool:
    """Has this process started Taichi? (Callers pick a kernel when its start is already paid.)"""
    return _ready


def ensure_taichi():
    """Initialise Taichi once (arch=cpu, all cores, no version check) and return the module."""
    global _ready
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    # With stdout swapped during import Taichi thinks it runs in a GUI shell, logs that on
    # stderr and flushes a print buffer after every launch; its plain-stdout mode avoids both.
    os.environ.setdefault("TI_ENABLE_PYBUF", "0")
    with _lock:
        with _quiet_stdout():
            import taichi as ti

            if not _ready:
                # arch=gpu/opengl segfaults on our machines; the CPU backend is the product.
                ti.init(arch=ti.cpu, log_level=ti.WARN, cpu_max_num_threads=_threads(),
                        offline_cache=True)
                _restore_fp_environment()
                _ready = True
    return ti
