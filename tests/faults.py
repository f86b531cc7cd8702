"""Fault injection shared by the safety tests: writes that fail part-way, and what a failed
writer may leave behind.

`disk_full_after(n)` makes the kernel refuse every write that would take a file past `n` bytes
(RLIMIT_FSIZE; the error is EFBIG where a full disk gives ENOSPC, the same `write()` failure to
every writer). It works in this process and under C and C++ writers alike (OpenUSD's crate and
text layers, OpenCV, Pillow, zlib), which monkeypatched Python writes would miss. The first `n`
bytes do go out, so a writer fails mid-file, not at open.

`real_enospc_available()` / `ENOSPC_SHELL`: a real full disk, a 1 MB tmpfs mounted in a user
namespace (`unshare -rm`), for the slow end-to-end runs where the machine allows it.
"""
from __future__ import annotations

import contextlib
import os
import resource
import shutil
import signal
import subprocess
from pathlib import Path


@contextlib.contextmanager
def disk_full_after(nbytes: int):
    """Writes past `nbytes` in any one file fail with OSError(EFBIG) in this process."""
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    previous = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # else the kernel kills us
    resource.setrlimit(resource.RLIMIT_FSIZE, (int(nbytes), hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, previous)


def entries(folder: Path) -> list[str]:
    """Every name under `folder` (recursively, relative, sorted): what a writer left there."""
    folder = Path(folder)
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def temp_leftovers(folder: Path) -> list[str]:
    """Names under `folder` that look like a writer's temporary entries (ours, any age)."""
    return [n for n in entries(folder) if ".partial" in n or ".build-" in n or ".old-" in n]


def real_enospc_available() -> bool:
    """Whether a user namespace with a private tmpfs can be made here (for real ENOSPC)."""
    if not shutil.which("unshare"):
        return False
    try:
        r = subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=64k none /mnt"],
                           capture_output=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return False
    return r.returncode == 0


def run_on_full_disk(command: str, folder: Path, size_kb: int, env: dict | None = None,
                     timeout: float = 300) -> subprocess.CompletedProcess:
    """Run the shell `command` with a fresh `size_kb` tmpfs mounted over `folder` (which must
    exist); files the command writes there are gone afterwards, so it should list what it left
    (`ls -A`) on stdout itself."""
    script = f'mount -t tmpfs -o size={int(size_kb)}k none "{folder}" && cd "{folder}" && {command}'
    return subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})
