"""The summary table printed at the end of a batch (text; the CLI prints it)."""
from __future__ import annotations

from avatarkit.batch.runner import BatchReport

_ROWS = ("done", "skipped", "failed", "cancelled")


def human_bytes(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale / 10 or unit == "kB":
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"


def _seconds(s: float) -> str:
    return f"{s:.1f} s" if s < 120 else f"{s / 60:.1f} min"


def format_summary(report: BatchReport, verbose: bool = False) -> str:
    """jobs done / skipped / failed (/ cancelled): count, time, output size; then the total,
    the failed jobs with their errors, and (verbose) one line per job."""
    w = max([len("cancelled")] + ([len(j.name) for j in report.jobs] if verbose else []))
    lines = []
    if verbose:
        lines.append(f"{'job':<{w}}  {'status':<9} {'time':>8} {'output':>10}  attempts  worker")
        for j in report.jobs:
            lines.append(f"{j.name:<{w}}  {j.status:<9} {_seconds(j.seconds) if j.seconds else '-':>8} "
                         f"{human_bytes(j.bytes) if j.outputs else '-':>10}  {j.attempts or '-':>8}  "
                         f"{j.worker or '-'}")
        lines.append("")
    lines.append(f"{'':<{w}}  {'jobs':>5} {'time':>9} {'output':>10}")
    for status in _ROWS:
        jobs = [j for j in report.jobs if j.status == status]
        if not jobs and status == "cancelled":
            continue
        secs = sum(j.seconds for j in jobs)
        size = sum(j.bytes for j in jobs)
        lines.append(f"{status:<{w}}  {len(jobs):>5} {_seconds(secs) if secs else '-':>9} "
                     f"{human_bytes(size) if size else '-':>10}")
    total = sum(j.bytes for j in report.jobs)
    lines.append(f"{'total':<{w}}  {len(report.jobs):>5} {_seconds(report.seconds):>9} {human_bytes(total):>10}"
                 f"  (wall time; {report.engine} engine, {report.workers} worker"
                 f"{'s' if report.workers != 1 else ''})")
    for j in report.failed:
        lines.append(f"failed: {j.name}: {j.error}")
    seen = set()
    for j in report.jobs:
        for text in j.warnings:
            if text not in seen:
                seen.add(text)
                lines.append(f"warning: {j.name}: {text}")
    if report.path is not None:
        lines.append(f"report: {report.path}")
    return "\n".join(lines)


__all__ = ["format_summary", "human_bytes"]
