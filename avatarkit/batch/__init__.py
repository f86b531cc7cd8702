"""Batch bakes: many avatars x many clips, on a local process pool or on Ray.

    from avatarkit.batch import load_batch, run_batch
    report = run_batch(load_batch("batch.json"), "out/", engine="local", workers=2)
    report.counts  # {"done": 5, "skipped": 1, "failed": 0, "cancelled": 0}

Modules: `spec` (the batch file -> `BakeJob`s), `job` (`run_job`: one complete bake job),
`records` (input hashes and `<output>.job.json` records: what makes a re-run skip work),
`worker` (what a worker process runs; its avatar cache), `engines` (inline / local / Ray),
`runner` (`run_batch`: plan, run, retry, report), `summary` (the closing table).
"""
from avatarkit.batch.job import JobInputs, JobResult, OutputResult, run_job
from avatarkit.batch.runner import REPORT_NAME, BatchEvent, BatchInterrupted, BatchReport, run_batch
from avatarkit.batch.spec import Batch, BakeJob, OutputSpec, load_batch, parse_batch
from avatarkit.batch.summary import format_summary

__all__ = ["Batch", "BakeJob", "BatchEvent", "BatchInterrupted", "BatchReport", "JobInputs", "JobResult",
           "OutputResult", "OutputSpec", "REPORT_NAME", "format_summary", "load_batch", "parse_batch", "run_batch",
           "run_job"]
