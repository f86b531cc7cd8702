"""What runs inside a batch worker (a local pool process, a Ray worker, or the driver itself for
the inline engine): `execute(task) -> JobResult`, which reports a job's failure in its result
instead of raising, so one bad job never takes a worker down.

Avatars are loaded once per worker: each process keeps the last `cache_size` avatars it loaded
(keyed by folder and content hash, so an edited avatar is read again), and the driver submits a
batch's jobs grouped by avatar.

Ctrl-C: pool workers get `init_pool_worker` as their initializer. A SIGINT (from the terminal,
or from the driver stopping the batch) interrupts the job being run once (its writers abort:
nothing half-written stays) and is ignored while the worker is idle, so an idle worker never
dies of it. A job whose frames are all written is let finish: its outputs are being moved into
place and recorded, which takes moments and leaves no output without its record.

Workers die with their driver: on Linux the kernel sends each a SIGTERM when the driver dies
(`prctl(PR_SET_PDEATHSIG)`), and everywhere a watchdog thread sees the driver gone (the worker's
parent changes) within a second and sends the same. SIGTERM interrupts a running job as Ctrl-C
does (its writers clean up), then the worker exits; an idle worker exits at once.
"""
from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
import traceback
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

from avatarkit.batch.job import JobInputs, JobResult, run_job, worker_name
from avatarkit.batch.spec import BakeJob

_CACHE: "OrderedDict[tuple[str, str], object]" = OrderedDict()
_running = False      # a job is being run
_committing = False   # its frames are all written: the writers are moving outputs into place
_interrupted = False  # a SIGINT reached this job
_terminated = False   # a SIGTERM reached this worker: exit once the job has cleaned up
#: how often the watchdog looks for the driver, and how long a job may take to clean up after
WATCH_SECONDS = 1.0
CLEANUP_SECONDS = 30.0
_PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class Task:
    """One attempt at a job, as sent to a worker. kinds: the outputs to (re)write."""

    job: BakeJob
    outdir: str
    kinds: tuple[str, ...]
    inputs: JobInputs
    attempt: int = 1
    cache_size: int = 2


def init_pool_worker() -> None:
    signal.signal(signal.SIGINT, _on_sigint)
    signal.signal(signal.SIGTERM, _on_sigterm)
    die_with_parent()


def die_with_parent() -> None:
    """Make this process receive SIGTERM when its parent (the batch driver) dies."""
    driver = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        except (OSError, AttributeError):
            pass  # the watchdog still covers it
    threading.Thread(target=_watch_parent, args=(driver,), name="avatarkit-driver-watch",
                     daemon=True).start()
    if os.getppid() != driver:  # the driver died before prctl took effect
        os.kill(os.getpid(), signal.SIGTERM)


def _watch_parent(driver: int) -> None:
    while os.getppid() == driver:
        time.sleep(WATCH_SECONDS)
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(CLEANUP_SECONDS)  # a job stuck in native code: do not wait for ever
    os._exit(143)


def _on_sigterm(signum, frame):
    global _terminated
    _terminated = True
    if not _running:
        os._exit(143)
    if not _committing:
        raise KeyboardInterrupt  # the job's writers clean up; execute() then exits


def _on_sigint(signum, frame):
    global _interrupted
    if _running and not _interrupted:
        _interrupted = True
        if not _committing:
            raise KeyboardInterrupt
    # idle, finishing, or already stopping this job: nothing more to interrupt


def _frame_done(done: int, total: int) -> None:
    global _committing
    if done >= total:
        _committing = True


def cached_avatar(folder: Path, sha256: str, cache_size: int):
    """(Avatar, loaded): from this process's cache, or loaded now (loaded=True)."""
    from avatarkit.avatar import load_avatar

    key = (str(Path(folder).resolve()), sha256)
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key], False
    avatar = load_avatar(folder)
    if cache_size > 0:
        _CACHE[key] = avatar
        while len(_CACHE) > cache_size:
            _CACHE.popitem(last=False)
    return avatar, True


def clear_cache() -> None:
    _CACHE.clear()


def failure(task: Task, error: BaseException, seconds: float) -> JobResult:
    """The result of a job that raised `error`."""
    from avatarkit.errors import AvatarKitError

    job = task.job
    result = JobResult(job.name, "failed", str(job.avatar), str(job.clip), seconds=seconds,
                       error_type=type(error).__name__, worker=worker_name())
    if isinstance(error, AvatarKitError):
        result.error = str(error)
    else:  # not a user's mistake: keep the traceback for the report
        result.error = f"{type(error).__name__}: {error}"
        result.traceback = "".join(traceback.format_exception(error))
        # a flaky disk or network share; anything else is deterministic
        result.transient = isinstance(error, OSError)
    return result


def execute(task: Task) -> JobResult:
    """Run one attempt of a job; a failure comes back as a "failed" result. KeyboardInterrupt
    (Ctrl-C, a cancelled Ray task) propagates after the job's writers have cleaned up."""
    global _running, _committing, _interrupted
    _running, _committing, _interrupted = True, False, False
    t0 = time.perf_counter()
    try:
        avatar, loaded = cached_avatar(task.job.avatar, task.inputs.avatar_sha256, task.cache_size)
        result = run_job(task.job, task.outdir, avatar=avatar, kinds=list(task.kinds), inputs=task.inputs,
                         progress=_frame_done)
        result.avatar_loaded = loaded
    except KeyboardInterrupt:
        raise
    except Exception as e:  # noqa: BLE001 -- every job failure is reported, none ends the worker
        if _interrupted and not _committing:
            # the interrupt surfaced as another error (raised inside a C++ callback, say)
            raise KeyboardInterrupt from e
        result = failure(task, e, time.perf_counter() - t0)
    finally:
        _running = _committing = False
        if _terminated:
            os._exit(143)
    result.attempts = task.attempt
    return result


__all__ = ["Task", "cached_avatar", "clear_cache", "die_with_parent", "execute", "failure", "init_pool_worker"]
