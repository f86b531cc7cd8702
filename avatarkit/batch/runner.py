"""`run_batch(batch, outdir, engine=...)`: plan, run, retry, report.

1. Plan (in this process): hash each avatar and clip once; a job whose outputs are all up to
   date (`records.is_up_to_date`) is skipped, the rest are queued with the outputs they miss.
   A job whose inputs cannot even be read fails here, without a worker.
2. Run on the engine, jobs grouped by avatar and each handed preferably to a worker that
   already holds its avatar (`_Affinity`; workers keep the avatars they loaded), at most
   `engine.slots` in flight.
3. Failures: a deterministic one (AvatarKitError: a corrupt avatar, a bad clip; or a bug) is
   final at once; a transient one (an OSError, a worker that died) is retried up to `retries`
   times, after a short back-off. A process pool that loses a worker fails every job in it, so
   those jobs ("suspects") are re-run one at a time, uncharged, until the one that kills its
   worker is found and charged alone.
4. Ctrl-C: jobs not started are cancelled, running ones are interrupted (their writers abort:
   no partial outputs) and waited for up to `GRACE` seconds; a second Ctrl-C stops at once.
   The report is still written, and `BatchInterrupted` (a KeyboardInterrupt) carries it.
5. The report (`BatchReport`) lists every job in batch order; it is saved as
   `OUTDIR/batch_report.json`.
"""
from __future__ import annotations

import datetime
import json
import os
import time
from collections import OrderedDict, deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from avatarkit.batch import records
from avatarkit.batch.engines import ENGINES, default_workers, make_engine
from avatarkit.batch.job import JOB_STATUSES, JobInputs, JobResult, OutputResult, outputs_to_write
from avatarkit.batch.spec import Batch, BakeJob
from avatarkit.batch.worker import Task
from avatarkit.errors import AvatarKitError, InputError, OutputError
from avatarkit.fileio import atomic_path, sweep_stale

REPORT_NAME = "batch_report.json"
REPORT_FORMAT = "avatarkit.batch-report"
REPORT_VERSION = 1
#: seconds Ctrl-C waits for running jobs to clean up
GRACE = 30.0
#: back-off before retry k of a transient failure: BACKOFF * 2**(k-1) seconds, at most 10
BACKOFF = 0.5


@dataclass
class BatchEvent:
    """Progress of a batch, for a progress bar: kind is "start" (an attempt began), "retry"
    (an attempt failed transiently and will be retried; message says why) or a final job
    status ("done", "skipped", "failed", "cancelled") with the job's result."""

    kind: str
    job: str
    result: JobResult | None = None
    message: str = ""


@dataclass
class BatchReport:
    """What a batch run did; jobs in batch order."""

    jobs: list[JobResult]
    outdir: str
    engine: str
    workers: int
    retries: int
    seconds: float
    started: str
    batch: str | None = None
    interrupted: bool = False
    path: Path | None = None          # where it was saved

    def count(self, status: str) -> int:
        return sum(1 for j in self.jobs if j.status == status)

    @property
    def counts(self) -> dict[str, int]:
        return {s: self.count(s) for s in JOB_STATUSES}

    @property
    def failed(self) -> list[JobResult]:
        return [j for j in self.jobs if j.status == "failed"]

    @property
    def ok(self) -> bool:
        return not self.interrupted and all(j.status in ("done", "skipped") for j in self.jobs)

    def to_json(self) -> dict:
        from avatarkit import __version__

        written = sum(o.bytes for j in self.jobs for o in j.outputs if o.status == "written")
        return {"format": REPORT_FORMAT, "version": REPORT_VERSION, "tool": f"avatarkit {__version__}",
                "batch": self.batch, "outdir": self.outdir, "engine": self.engine, "workers": self.workers,
                "retries": self.retries, "started": self.started, "seconds": round(self.seconds, 3),
                "interrupted": self.interrupted, "counts": self.counts,
                "bytes": {"written": written, "total": sum(j.bytes for j in self.jobs)},
                "jobs": [j.to_json() for j in self.jobs]}

    def save(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_json(), indent=1) + "\n", encoding="utf-8")
        self.path = path
        return path


class BatchInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped the batch; `report` says what was finished (and is saved)."""

    def __init__(self, report: BatchReport):
        super().__init__("batch interrupted")
        self.report = report


@dataclass
class _Item:
    index: int
    job: BakeJob
    kinds: tuple[str, ...]
    inputs: JobInputs
    attempts: int = 0
    not_before: float = 0.0
    suspect: bool = False   # in flight when a pool broke: runs alone until cleared
    alone: bool = False     # this attempt runs with nothing beside it


class _Affinity:
    """Which avatars each worker holds (as its cache does) and which workers just became free.

    With at most `slots` attempts in flight, the next attempt submitted after one finishes goes
    to the worker that finished it (the others are busy), so the driver hands it a job whose
    avatar that worker already has; a job for a worker with nothing useful takes an avatar no
    other worker is busy with, which spreads the avatars over the workers."""

    def __init__(self, cache_size: int):
        self.cache_size = max(0, int(cache_size))
        self.held: dict[str, OrderedDict] = {}
        self.free: deque[str] = deque()

    def finished(self, worker: str | None, avatar: Path) -> None:
        if not worker:
            return
        held = self.held.setdefault(worker, OrderedDict())
        held[avatar] = True
        held.move_to_end(avatar)
        while len(held) > self.cache_size:
            held.popitem(last=False)
        self.free.append(worker)

    def pick(self, ready: list, running) -> "_Item":
        worker = self.free.popleft() if self.free else None
        if worker is not None:
            held = self.held.get(worker, {})
            for it in ready:
                if it.job.avatar in held:
                    return it
        busy = {it.job.avatar for it in running}
        return next((it for it in ready if it.job.avatar not in busy), ready[0])


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()


def _digests(jobs) -> tuple[dict, dict]:
    """Hash every distinct avatar and clip once: path -> sha256 or the error reading it."""
    avatars: dict[Path, object] = {}
    clips: dict[Path, object] = {}
    for job in jobs:
        for table, path, fn in ((avatars, job.avatar, records.avatar_sha256),
                                (clips, job.clip, records.clip_sha256)):
            if path not in table:
                try:
                    table[path] = fn(path)
                except (AvatarKitError, OSError) as e:
                    table[path] = e
    return avatars, clips


def _input_error(e: BaseException) -> str:
    return str(e) if isinstance(e, AvatarKitError) else f"{type(e).__name__}: {e}"


def run_batch(batch: Batch, outdir: str | os.PathLike, *, engine: str = "local", workers: int | None = None,
              retries: int = 2, address: str | None = None, force: bool = False, cache_size: int = 2,
              on_event: Callable[[BatchEvent], None] | None = None,
              execute_fn: Callable[[Task], JobResult] | None = None, save_report: bool = True) -> BatchReport:
    """Run every job of `batch` into `outdir` (see the module notes) and return the report.

    engine: "local" (process pool), "ray" or "inline" (this process, one after another);
    workers: parallel jobs (default: this machine's CPUs; with Ray, the cluster's); retries:
    extra attempts after a transient failure; force: redo jobs whose outputs are up to date;
    cache_size: avatars each worker keeps loaded; on_event: called in this process as jobs
    progress. execute_fn: what a worker runs per attempt (default `worker.execute`; tests wrap
    it to inject failures). Raises BatchInterrupted on Ctrl-C, after saving the report."""
    if int(retries) != retries or retries < 0:
        raise InputError(f"retries must be an integer >= 0, got {retries!r}")
    if workers is not None and (int(workers) != workers or workers < 1):
        raise InputError(f"workers must be an integer >= 1, got {workers!r}")
    if engine not in ENGINES + ("inline",):
        raise InputError(f"unknown engine {engine!r}; use one of {', '.join(ENGINES)}")
    if address and engine != "ray":
        raise InputError("--address applies to --engine ray")
    t0 = time.perf_counter()
    started = _now()
    outdir = Path(outdir)
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create the output folder ({e.strerror})", outdir) from None
    if not os.access(outdir, os.W_OK | os.X_OK):
        raise OutputError("output folder is not writable", outdir)

    emit = on_event or (lambda event: None)
    results: dict[int, JobResult] = {}
    queue: deque[_Item] = deque()
    inflight: dict[object, _Item] = {}
    interrupted = False
    eng = None
    affinity = _Affinity(cache_size)
    n_workers = workers or (default_workers() if engine != "inline" else 1)

    def finish(item_or_index, result: JobResult) -> None:
        index = item_or_index if isinstance(item_or_index, int) else item_or_index.index
        results[index] = result
        emit(BatchEvent(result.status, result.name, result))

    try:
        # -- plan ------------------------------------------------------------------------------
        avatars, clips = _digests(batch.jobs)
        todo: list[_Item] = []
        for i, job in enumerate(batch.jobs):
            a, c = avatars[job.avatar], clips[job.clip]
            bad = a if isinstance(a, BaseException) else c if isinstance(c, BaseException) else None
            if bad is not None:
                finish(i, JobResult(job.name, "failed", str(job.avatar), str(job.clip), error=_input_error(bad),
                                    error_type=type(bad).__name__))
                continue
            inputs = JobInputs(a, c)
            kinds = [o.kind for o in job.outputs] if force else outputs_to_write(job, outdir, inputs)
            if not kinds:
                outs = [OutputResult(o.kind, o.path, records.recorded_bytes(o.target(outdir)), "skipped")
                        for o in job.outputs]
                finish(i, JobResult(job.name, "skipped", str(job.avatar), str(job.clip), outs))
                continue
            todo.append(_Item(i, job, tuple(kinds), inputs))
        # grouped by avatar: with `_Affinity` each worker loads few of them
        todo.sort(key=lambda it: str(it.job.avatar))
        queue.extend(todo)

        # -- run -------------------------------------------------------------------------------
        if queue:
            # a Ray cluster without --workers: as many as it has CPUs
            want = None if engine == "ray" and workers is None else min(n_workers, len(queue))
            eng = make_engine(engine, want, address, execute_fn)
            n_workers = eng.workers
            while queue or inflight:
                _submit(eng, queue, inflight, outdir, cache_size, emit, affinity)
                if not inflight:  # everything queued is backing off
                    time.sleep(max(0.0, min(it.not_before for it in queue) - time.monotonic()))
                    continue
                for handle in eng.wait(list(inflight), timeout=0.5):
                    item = inflight.pop(handle)
                    out = eng.outcome(handle)
                    if out.kind == "result":
                        affinity.finished(out.result.worker, item.job.avatar)
                    _settle(eng, item, out, queue, retries, emit, finish)
    except KeyboardInterrupt:
        interrupted = True
        if eng is not None:
            try:
                eng.interrupt(list(inflight), GRACE)
            except KeyboardInterrupt:  # a second Ctrl-C: stop now
                eng.kill()
            for handle, item in list(inflight.items()):
                if eng.wait([handle], 0):
                    out = eng.outcome(handle)
                    if out.kind == "result":  # it finished before the interrupt reached it
                        results[item.index] = out.result  # (no event: the caller is stopping)
    finally:
        if eng is not None:
            try:
                eng.close()
            except KeyboardInterrupt:
                interrupted = True
                eng.kill()
    if interrupted:
        # a worker that ended while its job was starting leaves that job's writers' temporaries
        # behind (seen about once in four Ctrl-Cs); the workers are gone now, so what they left
        # is stale and goes (`fileio.sweep_stale` takes only this host's entries of dead pids)
        for job in batch.jobs:
            for o in job.outputs:
                sweep_stale(o.target(outdir).parent)

    jobs = []
    for i, job in enumerate(batch.jobs):
        r = results.get(i)
        if r is None:  # never started, or stopped by Ctrl-C
            r = JobResult(job.name, "cancelled", str(job.avatar), str(job.clip), error="interrupted")
        jobs.append(r)
    report = BatchReport(jobs, str(outdir), engine, n_workers, int(retries), time.perf_counter() - t0, started,
                         str(batch.path) if batch.path else None, interrupted)
    if save_report:
        report.save(outdir / REPORT_NAME)
    if interrupted:
        raise BatchInterrupted(report)
    return report


def _submit(eng, queue: deque, inflight: dict, outdir: Path, cache_size: int, emit, affinity: _Affinity) -> None:
    """Start attempts while the engine has room, each a job whose avatar the next free worker
    holds if there is one (`_Affinity`). While a suspect (see the module notes) is queued or
    running, suspects run alone, one at a time."""
    while queue and len(inflight) < eng.slots:
        isolate = any(it.suspect for it in queue) or any(it.suspect for it in inflight.values())
        now = time.monotonic()
        if isolate:
            if inflight:
                return
            item = next(it for it in queue if it.suspect)
        else:
            ready = [it for it in queue if it.not_before <= now]
            if not ready:
                return
            item = affinity.pick(ready, inflight.values())
        queue.remove(item)
        item.attempts += 1
        item.alone = isolate
        task = Task(item.job, str(outdir), item.kinds, item.inputs, item.attempts, cache_size)
        inflight[eng.submit(task)] = item
        emit(BatchEvent("start", item.job.name, message=f"attempt {item.attempts}"))


def _settle(eng, item: _Item, out, queue: deque, retries: int, emit, finish) -> None:
    """Decide what a finished attempt means: a final result, or another attempt."""
    job = item.job
    if out.kind == "result":
        r = out.result
        if r.status == "failed" and r.transient and item.attempts <= retries:
            item.not_before = time.monotonic() + min(BACKOFF * 2 ** (item.attempts - 1), 10.0)
            queue.append(item)
            emit(BatchEvent("retry", job.name, r, r.error or ""))
            return
        finish(item, r)
        return
    if out.kind == "lost":
        if not eng.precise_loss and not item.alone:
            # the pool broke with several jobs in it: not necessarily this one's fault
            item.attempts -= 1
            item.suspect = True
            queue.appendleft(item)
            emit(BatchEvent("retry", job.name, message=f"{out.message}; re-running it on its own"))
            return
        if item.attempts <= retries:
            queue.appendleft(item)
            emit(BatchEvent("retry", job.name, message=out.message))
            return
        finish(item, JobResult(job.name, "failed", str(job.avatar), str(job.clip), attempts=item.attempts,
                               error=f"{out.message} ({item.attempts} attempts)", error_type="WorkerLost",
                               transient=True))
        return
    if out.kind == "cancelled":
        finish(item, JobResult(job.name, "cancelled", str(job.avatar), str(job.clip), attempts=item.attempts,
                               error="interrupted"))
        return
    finish(item, JobResult(job.name, "failed", str(job.avatar), str(job.clip), attempts=item.attempts,
                           error=out.message or "the engine could not run it", error_type="EngineError"))


__all__ = ["BACKOFF", "GRACE", "REPORT_NAME", "BatchEvent", "BatchInterrupted", "BatchReport", "run_batch"]
