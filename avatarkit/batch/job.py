"""One complete bake job: avatar folder + clip + outputs + settings -> files written, a result.

`run_job` is what every batch engine runs in its workers, and usable on its own:

    job = load_batch("batch.json").jobs[0]
    result = run_job(job, "out/")

It is `avatarkit bake` as a library call: the same `bake.run_bake` feeding the same writers
(`UsdStageWriter`, `PlySequenceWriter`, `PreviewWriter`) in one pass; each output is atomic,
and a record (`records.write_record`) is written beside each finished output.
"""
from __future__ import annotations

import os
import socket
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from avatarkit.batch import records
from avatarkit.batch.spec import BakeJob
from avatarkit.fileio import check_inside

JOB_STATUSES = ("done", "skipped", "failed", "cancelled")


@dataclass
class OutputResult:
    """One output of a job: kind, path relative to the output folder, bytes on disk (all its
    files), and whether this run wrote it ("written") or found it up to date ("skipped")."""

    kind: str
    path: str
    bytes: int
    status: str


@dataclass
class JobResult:
    """What became of one job.

    status: "done" (this run wrote its missing outputs), "skipped" (all up to date), "failed",
    "cancelled" (interrupted or never started). seconds: wall time of the successful (or last)
    attempt; attempts: how many times it was started. error / error_type / transient: the last
    failure (transient failures are retried). worker: "host:pid" that ran it; avatar_loaded:
    whether that worker read the avatar from disk for it (False: its cache had it).
    """

    name: str
    status: str
    avatar: str = ""
    clip: str = ""
    outputs: list[OutputResult] = field(default_factory=list)
    frames: int = 0
    seconds: float = 0.0
    attempts: int = 0
    error: str | None = None
    error_type: str | None = None
    transient: bool = False
    traceback: str | None = None
    worker: str | None = None
    avatar_loaded: bool | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def bytes(self) -> int:
        return sum(o.bytes for o in self.outputs)

    def to_json(self) -> dict:
        d = asdict(self)
        d["seconds"] = round(self.seconds, 3)
        d["bytes"] = self.bytes
        return {k: v for k, v in d.items() if v is not None and v != []}


@dataclass(frozen=True)
class JobInputs:
    """The content hashes of a job's inputs (computed once per avatar and clip by the driver)."""

    avatar_sha256: str
    clip_sha256: str

    @classmethod
    def of(cls, job: BakeJob) -> "JobInputs":
        return cls(records.avatar_sha256(job.avatar), records.clip_sha256(job.clip))


def output_keys(job: BakeJob, inputs: JobInputs) -> dict[str, str]:
    """kind -> key of each of the job's outputs (see `records.output_key`)."""
    settings = job.config.to_json()
    return {o.kind: records.output_key(inputs.avatar_sha256, inputs.clip_sha256, settings, o.kind, o.options)
            for o in job.outputs}


def outputs_to_write(job: BakeJob, outdir: str | os.PathLike, inputs: JobInputs) -> list[str]:
    """The kinds of the job's outputs that are missing, incomplete or out of date."""
    keys = output_keys(job, inputs)
    return [o.kind for o in job.outputs if not records.is_up_to_date(o.target(outdir), keys[o.kind])]


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def run_job(job: BakeJob, outdir: str | os.PathLike, *, avatar: Any = None, kinds: list[str] | None = None,
            inputs: JobInputs | None = None,
            progress: Callable[[int, int], None] | None = None) -> JobResult:
    """Bake `job` into `outdir`: the outputs of `kinds` (default: those not up to date).

    avatar: the job's `Avatar` if the caller has it loaded (a worker's cache), else it is
    loaded here. inputs: the inputs' hashes if already known. Returns the result ("done", or
    "skipped" if nothing needed writing); raises on failure (AvatarKitError for bad input;
    nothing is left half-written under an output's name)."""
    from avatarkit.bake import run_bake
    from avatarkit.bake_writers import make_writer
    from avatarkit.errors import InputError, OutputError

    t0 = time.perf_counter()
    outdir = Path(outdir)
    inputs = inputs or JobInputs.of(job)
    keys = output_keys(job, inputs)
    todo = outputs_to_write(job, outdir, inputs) if kinds is None else list(kinds)
    result = JobResult(job.name, "done", str(job.avatar), str(job.clip), worker=worker_name())
    if not todo:
        result.status = "skipped"
        result.outputs = [OutputResult(o.kind, o.path, records.recorded_bytes(o.target(outdir)), "skipped")
                          for o in job.outputs]
        return result

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        if avatar is None:
            from avatarkit.avatar import load_avatar

            avatar = load_avatar(job.avatar)
            result.avatar_loaded = True
        from avatarkit.motion import load_clip

        clip = load_clip(job.clip)
        writers, written = [], []
        for o in job.outputs:
            if o.kind not in todo:
                continue
            target = check_inside(o.target(outdir), outdir)
            # the old record goes first: from here on nothing vouches for this output
            records.remove_record(target)
            if o.kind != "ply":
                try:
                    target.parent.mkdir(parents=True, exist_ok=True)
                except (FileExistsError, NotADirectoryError):
                    raise OutputError("cannot create the output's folder: a file is in the way",
                                      target.parent) from None
            writers.append(make_writer(o.kind, target, o.options))
            written.append(o)
        try:
            summary = run_bake(avatar, clip, job.config, writers, progress=progress)
        except InputError as e:  # the clip's problems (range, units) name the clip file
            raise e.with_path(job.clip) from None
    seconds = time.perf_counter() - t0
    settings = job.config.to_json()
    record_inputs = {"avatar": {"path": str(job.avatar), "sha256": inputs.avatar_sha256},
                     "clip": {"path": str(job.clip), "sha256": inputs.clip_sha256}}
    for o in job.outputs:
        target = o.target(outdir)
        if o in written:
            size = records.write_record(target, o.kind, keys[o.kind], job.name, record_inputs,
                                        {"bake": settings, o.kind: o.options}, seconds)
            result.outputs.append(OutputResult(o.kind, o.path, size, "written"))
        else:
            result.outputs.append(OutputResult(o.kind, o.path, records.recorded_bytes(target), "skipped"))
    result.frames = summary.frames
    result.seconds = seconds
    seen = set()
    for w in caught:
        text = str(w.message)
        if issubclass(w.category, UserWarning) and text not in seen:
            seen.add(text)
            result.warnings.append(text)
    return result


__all__ = ["JOB_STATUSES", "JobInputs", "JobResult", "OutputResult", "output_keys", "outputs_to_write",
           "run_job", "worker_name"]
