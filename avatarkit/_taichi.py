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


def _keep_interrupts(ti) -> None:
    """Taichi decides whether a kernel is defined inside a class by reading the caller's source
    (`kernel_impl._inside_class`) under a bare `except:`, so a Ctrl-C (or our SIGTERM, also a
    KeyboardInterrupt) that lands while modules decorate their kernels on import was swallowed
    and the command ran on. Put the same function back with an `except Exception`."""
    import inspect

    kernel_impl = getattr(getattr(ti, "lang", None), "kernel_impl", None)
    original = getattr(kernel_impl, "_inside_class", None)
    patterns = getattr(kernel_impl, "_KERNEL_CLASS_STACKFRAME_STMT_RES", None)
    if original is None or patterns is None or getattr(original, "_avatarkit", False):
        return

    def _inside_class(level_of_class_stackframe):
        try:
            frame = sys._getframe(level_of_class_stackframe)
            first = inspect.getframeinfo(frame)[3][0].strip()
            return any(p.match(first) for p in patterns)
        except Exception:  # noqa: BLE001 - as Taichi's, but KeyboardInterrupt/SystemExit pass
            return False

    _inside_class._avatarkit = True
    kernel_impl._inside_class = _inside_class


@contextlib.contextmanager
def _signals_held():
    """Hold SIGINT/SIGTERM while Taichi imports (its own modules decorate functions on import,
    under the bare `except` that `_keep_interrupts` then replaces) and deliver them after, to
    the handler that was there before. Only the main thread can set handlers; others run as is."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    for sig in dict.fromkeys(pending):
        handler = previous[sig]
        if callable(handler):
            handler(sig, None)
        elif handler == signal.SIG_DFL:
            if sig == signal.SIGINT:
                raise KeyboardInterrupt
            signal.raise_signal(sig)


def _frozen_sources_known() -> None:
    """Taichi decides whether a kernel is defined in a class by reading the source line of a
    caller's frame (`_inside_class`: `inspect.getframeinfo`). For kernels decorated while a
    module imports, that frame is importlib's, whose file "<frozen importlib._bootstrap>"
    `inspect.getmodule` never finds: each call then walks every module in `sys.modules` (twice),
    ~20-30 ms with torch loaded, 1.0 of the 1.4 CPU s Taichi's import and our kernels' decoration
    took in a build. Telling inspect's file->module cache which module those files are gives the
    same answer (frozen modules have no source: still no line, still "not in a class") at once."""
    import inspect

    cache = getattr(inspect, "modulesbyfile", None)
    if not isinstance(cache, dict):
        return
    for name in ("importlib._bootstrap", "importlib._bootstrap_external"):
        if name in sys.modules:
            cache.setdefault(f"<frozen {name}>", name)


def _set_environment() -> None:
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    # With stdout swapped during import Taichi thinks it runs in a GUI shell, logs that on
    # stderr and flushes a print buffer after every launch; its plain-stdout mode avoids both.
    os.environ.setdefault("TI_ENABLE_PYBUF", "0")
    # Taichi asks "is torch (paddle) installed?" by importing it under a bare `except:` the first
    # time a kernel argument's dtype is converted, i.e. while modules decorate kernels: seconds
    # of import in which a Ctrl-C was swallowed. Our kernels take numpy arrays only.
    os.environ.setdefault("TI_ENABLE_TORCH", "0")
    os.environ.setdefault("TI_ENABLE_PADDLE", "0")


def import_taichi() -> None:
    """Import Taichi (as `ensure_taichi` does) without starting it: for a thread that loads it
    while the caller's thread does other work (`recon.pipeline`). Prints nothing, so it leaves
    stdout alone (another thread may be writing to it); off the main thread no Ctrl-C can land
    in Taichi's bare `except`s."""
    _set_environment()
    with _lock:
        if _ready:
            return
        _frozen_sources_known()
        with _signals_held():
            import taichi as ti

            _keep_interrupts(ti)


def taichi_running() -> bool:
    """Has this process started Taichi? (Callers pick a kernel when its start is already paid.)"""
    return _ready


def ensure_taichi():
    """Initialise Taichi once (arch=cpu, all cores, no version check) and return the module."""
    global _ready
    if _ready:
        import taichi as ti
        return ti
    _set_environment()
    with _lock:
        _frozen_sources_known()
        with _quiet_stdout():
            with _signals_held():
                import taichi as ti

                _keep_interrupts(ti)
            if not _ready:
                # arch=gpu/opengl segfaults on our machines; the CPU backend is the product.
                ti.init(arch=ti.cpu, log_level=ti.WARN, cpu_max_num_threads=_threads(),
                        offline_cache=True)
                _restore_fp_environment()
                _ready = True
    return ti
