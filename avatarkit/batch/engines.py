"""Where batch jobs run. Every engine has the same small shape, used by `runner.run_batch`:

    submit(task) -> handle         start one attempt of a job (`worker.Task`)
    wait(handles, timeout) -> done the handles that finished (at least one, or none on timeout)
    outcome(handle) -> Outcome     its JobResult, or "lost" (the worker died), "cancelled", "error"
    interrupt(handles, grace)      Ctrl-C: drop queued attempts, stop running ones cleanly
    kill()                         second Ctrl-C: stop now
    close()                        release the workers

- `InlineEngine`: in this process, one job after another (the baseline of the benchmark, and
  easy to debug).
- `LocalEngine`: `concurrent.futures.ProcessPoolExecutor` with the spawn start method, so each
  worker is a fresh interpreter that initialises Taichi for itself.
- `RayEngine`: Ray tasks (`ray.remote`, one CPU each) on a local Ray instance started for the
  run, on an address given, or on the instance this process already joined. Ray does the
  scheduling and the transport; Ray's own task retries are off because the runner retries
  every engine's failures by one policy.

`precise_loss`: whether a dead worker fails only the job it ran (Ray) or every job in flight
(a process pool breaks as a whole; the runner then re-runs those jobs one at a time to find
the one that kills its worker).
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import signal
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Callable

from avatarkit.batch.job import JobResult
from avatarkit.batch.worker import Task, execute, init_pool_worker
from avatarkit.errors import InputError

ENGINES = ("local", "ray")
#: thread pools that numpy/BLAS, torch and our Taichi kernels size at start from these variables
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "AVATARKIT_THREADS")
#: the message of a job whose worker process died under it
LOST = "its worker process died (killed, out of memory, or crashed)"


@dataclass
class Outcome:
    kind: str                       # "result" | "lost" | "cancelled" | "error"
    result: JobResult | None = None
    message: str = ""


def default_workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


class InlineEngine:
    """Runs each job in this process when it is submitted."""

    name = "inline"
    precise_loss = True

    def __init__(self, execute_fn: Callable[[Task], JobResult] = execute):
        self._execute = execute_fn
        self.workers = self.slots = 1

    def submit(self, task: Task) -> cf.Future:
        f: cf.Future = cf.Future()
        f.set_result(self._execute(task))
        return f

    def wait(self, handles, timeout: float):
        return [h for h in handles if h.done()]

    def outcome(self, handle) -> Outcome:
        return Outcome("result", handle.result())

    def interrupt(self, handles, grace: float) -> None:
        pass

    def kill(self) -> None:
        pass

    def close(self) -> None:
        pass


class LocalEngine:
    """A spawn-context process pool of `workers` processes on this machine."""

    name = "local"
    precise_loss = False

    def __init__(self, workers: int, execute_fn: Callable[[Task], JobResult] = execute):
        self.workers = self.slots = max(1, int(workers))
        self._execute = execute_fn
        self._pool: cf.ProcessPoolExecutor | None = None
        # The workers share the machine: each gets its share of BLAS/OpenMP threads (as Ray
        # gives its tasks), unless the user chose. Spawned children read them at import, and
        # the pool spawns them as work arrives: set for the engine's life, restored by close().
        share = str(max(1, default_workers() // self.workers))
        self._set_env = [k for k in THREAD_VARIABLES if k not in os.environ]
        for k in self._set_env:
            os.environ[k] = share

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                      initializer=init_pool_worker)

    def submit(self, task: Task) -> cf.Future:
        if self._pool is None:
            self._pool = self._new_pool()
        try:
            return self._pool.submit(self._execute, task)
        except BrokenProcessPool:  # a worker died earlier: this pool takes no more work
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            return self._pool.submit(self._execute, task)

    def wait(self, handles, timeout: float):
        done, _ = cf.wait(handles, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        return list(done)

    def outcome(self, handle: cf.Future) -> Outcome:
        if handle.cancelled():
            return Outcome("cancelled")
        exc = handle.exception()
        if exc is None:
            return Outcome("result", handle.result())
        if isinstance(exc, BrokenProcessPool):
            return Outcome("lost", message=LOST)
        if isinstance(exc, KeyboardInterrupt):
            return Outcome("cancelled")
        return Outcome("error", message=f"{type(exc).__name__}: {exc}")

    def _processes(self) -> list:
        # ProcessPoolExecutor keeps its workers in `_processes` (pid -> Process) since 3.2
        return list(getattr(self._pool, "_processes", None) or {}) if self._pool else []

    def interrupt(self, handles, grace: float) -> None:
        for h in handles:
            h.cancel()  # only those not started yet
        # the running ones: SIGINT makes their writers abort (see worker.init_pool_worker); a
        # worker that already got the terminal's Ctrl-C ignores this second one
        for pid in self._processes():
            try:
                os.kill(pid, signal.SIGINT)
            except (ProcessLookupError, PermissionError):
                pass
        running = [h for h in handles if not h.done()]
        if running:
            cf.wait(running, timeout=grace)

    def kill(self) -> None:
        for pid in self._processes():
            try:
                os.kill(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    def close(self) -> None:
        try:
            if self._pool is not None:
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None
        finally:
            for k in self._set_env:
                os.environ.pop(k, None)
            self._set_env = []


class RayEngine:
    """Ray tasks: one CPU each, at most `workers` in flight.

    address: a running cluster ("ray://host:10001", "host:6379" or "auto"); None joins the
    instance this process already started (`ray.init` before), or starts a local one with
    `workers` CPUs. Usage statistics are off, there is no dashboard, and worker logs stay out
    of the terminal. Inputs and the output folder must be on a file system every node sees."""

    name = "ray"
    precise_loss = True

    def __init__(self, workers: int | None = None, address: str | None = None,
                 execute_fn: Callable[[Task], JobResult] = execute):
        os.environ["RAY_USAGE_STATS_ENABLED"] = "0"  # never phone home, whatever the user's config
        try:
            import ray
        except ImportError:
            raise InputError("--engine ray needs Ray, which is not installed: pip install 'avatarkit[ray]'") \
                from None
        import logging

        self._ray = ray
        self._owns = False
        if not ray.is_initialized():
            common = dict(include_dashboard=False, log_to_driver=False)
            if address:
                try:
                    ray.init(address=address, logging_level=logging.WARNING, **common)
                except (ConnectionError, ValueError, RuntimeError, TimeoutError) as e:
                    raise InputError(f"cannot connect to the Ray cluster at {address!r}: {e}") from None
            else:
                # ERROR: a private instance's start-up notes (token auth, ...) are not the user's
                ray.init(num_cpus=workers or default_workers(), logging_level=logging.ERROR, **common)
            self._owns = True
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.workers = self.slots = min(int(workers), cpus) if workers else cpus
        self._remote = ray.remote(execute_fn).options(num_cpus=1, max_retries=0)

    def submit(self, task: Task):
        return self._remote.remote(task)

    def wait(self, handles, timeout: float):
        handles = list(handles)
        ready, rest = self._ray.wait(handles, num_returns=1, timeout=timeout)
        if ready and rest:
            more, _ = self._ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        return ready

    def outcome(self, handle) -> Outcome:
        ex = self._ray.exceptions
        try:
            return Outcome("result", self._ray.get(handle))
        except ex.TaskCancelledError:
            return Outcome("cancelled")
        except (ex.WorkerCrashedError, ex.NodeDiedError, ex.ObjectLostError, ex.OwnerDiedError,
                ex.OutOfMemoryError, ex.LocalRayletDiedError) as e:
            return Outcome("lost", message=f"{LOST} [{type(e).__name__}]")
        except ex.RayTaskError as e:
            if isinstance(e.cause, KeyboardInterrupt):
                return Outcome("cancelled")
            return Outcome("error", message=f"{type(e.cause).__name__}: {e.cause}")
        except ex.RayError as e:
            return Outcome("error", message=f"{type(e).__name__}: {e}")

    def interrupt(self, handles, grace: float) -> None:
        handles = list(handles)
        for h in handles:
            try:
                self._ray.cancel(h)  # running: KeyboardInterrupt in the task, writers abort
            except Exception:  # noqa: BLE001 -- already finished
                pass
        if handles:
            self._ray.wait(handles, num_returns=len(handles), timeout=grace)

    def kill(self) -> None:
        pass  # close() shuts our own instance down; a cluster's tasks were cancelled already

    def close(self) -> None:
        if self._owns:
            self._ray.shutdown()
            self._owns = False


def make_engine(name: str, workers: int | None = None, address: str | None = None,
                execute_fn: Callable[[Task], Any] | None = None):
    """The engine `name` ("local", "ray" or "inline")."""
    fn = execute_fn or execute
    if address and name != "ray":
        raise InputError("--address applies to --engine ray")
    if name == "local":
        return LocalEngine(workers or default_workers(), fn)
    if name == "ray":
        return RayEngine(workers, address, fn)
    if name == "inline":
        return InlineEngine(fn)
    raise InputError(f"unknown engine {name!r}; use one of {', '.join(ENGINES)}")


__all__ = ["ENGINES", "InlineEngine", "LocalEngine", "Outcome", "RayEngine", "default_workers", "make_engine"]
