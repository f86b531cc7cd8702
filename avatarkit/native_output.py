"""Messages native libraries print straight to the process's stderr (OpenUSD's `Warning: in
_ReportErrors ...` lines when a stage's references are missing) become Python warnings, so the
CLI can hold them like its own: printed when a command succeeds, dropped when it fails, never
before the one error line."""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import warnings

_USD_WARNING = re.compile(r"^Warning: in \S+ at line \d+ of \S+ -- (?P<text>.*)$")


class NativeWarning(UserWarning):
    """A message a native library printed on stderr while we read a file."""


@contextlib.contextmanager
def native_stderr_as_warnings(label: str):
    """Capture file descriptor 2 for the block; each line printed there becomes a
    `NativeWarning` "`label`: line" (OpenUSD's source locations trimmed, repeats merged)."""
    fd = 2  # native code writes to file descriptor 2, whatever sys.stderr is (a capture, a notebook)
    try:
        sys.stderr.flush()
    except (AttributeError, OSError, ValueError):
        pass
    with tempfile.TemporaryFile() as sink:
        saved = os.dup(fd)
        os.dup2(sink.fileno(), fd)
        try:
            yield
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", "replace")
    for line in dict.fromkeys(text.splitlines()):
        line = line.strip()
        if not line:
            continue
        m = _USD_WARNING.match(line)
        line = re.sub(r"\s*\((instantiating|recomposing) stage on stage @[^)]*\)$", "",
                      m["text"] if m else line)
        warnings.warn(f"{label}: {line}", NativeWarning, stacklevel=3)
