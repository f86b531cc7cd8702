"""Reading a binary USD file once in a child process before this process opens it, so that a
damaged file that crashes OpenUSD's C++ reader is a `FormatError` naming the file, not a dead
process.

Why: the crate (`.usdc`) reader trusts the file's counts and offsets. The fuzz tests
(tests/test_fuzz_readers.py) found one changed byte (offset 89 of a small splat file, 1 -> 63)
that makes `Usd.Stage.Open` segfault: no Python exception to catch, the user sees "Segmentation
fault" and a core instead of our one-line error. The child opens the stage as `open_usd_stage`
does and reads every attribute's default value and time samples; when it dies by a signal the
file is refused. What the child survived, this process survives too (the same library reading
the same bytes).

Probed: crate files (`PXR-USDC`), `.usdz` packages, and text layers that name other files
(`@...@` asset paths: a sublayer or reference may be a damaged crate). A plain `.usda` is not
probed: its text parser reports errors as exceptions. Cost: a Python start and `pxr` import
(~0.3 s) plus one more read of the file's values; each file's content (a BLAKE2 hash) is
probed once per process. `AVATARKIT_USD_PROBE=0` turns the probe off (a trusted pipeline reading
files it wrote itself).
"""
from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
from pathlib import Path

from avatarkit.errors import FormatError

PROBE_ENV = "AVATARKIT_USD_PROBE"
#: seconds the child may take: a floor for the interpreter start, plus a generous read rate
TIMEOUT_FLOOR_S = 120.0
TIMEOUT_S_PER_MB = 2.0

_CHILD = r"""
import sys
from pxr import Usd
stage = Usd.Stage.Open(sys.argv[1], Usd.Stage.LoadAll)
for prim in (stage.TraverseAll() if stage is not None else ()):
    for attr in prim.GetAttributes():
        try:
            attr.Get()
            for t in attr.GetTimeSamples():
                attr.Get(t)
        except Exception:
            pass
"""

_probed: set[tuple[str, str]] = set()


def needs_probe(path: Path) -> bool:
    """Whether opening `path` may run OpenUSD's binary readers: a crate file, a usdz package,
    or a text layer that names other files."""
    with open(path, "rb") as f:
        head = f.read(8)
        if head == b"PXR-USDC" or head[:4] == b"PK\x03\x04":
            return True
        if not head.startswith(b"#usda"):
            return True  # neither: USD decides what it is; let the child find out first
        return b"@" in f.read()


def probe_usd_file(path: str | os.PathLike) -> None:
    """Read `path` with OpenUSD in a child process; FormatError naming the file when the reader
    crashed there (killed by a signal) or did not finish in time. Nothing when the child read it
    or failed with an ordinary error (this process reports that one itself, with its message)."""
    path = Path(path)
    if os.environ.get(PROBE_ENV, "1") == "0" or not needs_probe(path):
        return
    key = (str(path.resolve()), _content_hash(path))
    if key in _probed:
        return
    timeout = TIMEOUT_FLOOR_S + TIMEOUT_S_PER_MB * path.stat().st_size / 2**20
    try:
        done = subprocess.run([sys.executable, "-c", _CHILD, str(path)], stdin=subprocess.DEVNULL,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise FormatError(f"not a readable USD file (USD's reader did not finish it in {timeout:.0f} s)",
                          path) from None
    if done.returncode < 0:
        raise FormatError(f"not a readable USD file (USD's reader crashed on it: "
                          f"{_signal_name(-done.returncode)}); the file is damaged", path)
    _probed.add(key)


def _content_hash(path: Path) -> str:
    # by content, not modification time: a file rewritten within the clock's tick at the same
    # size (the fuzz tests do it) must be probed again
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"signal {number}"


__all__ = ["PROBE_ENV", "needs_probe", "probe_usd_file"]
