"""`Background`: one function run on a daemon thread while the caller goes on; `result()` waits.

Why: the build is mostly one thread of Python and numpy on a 2-core machine, while a head SDF
spends its time in `cKDTree.query`, which releases the GIL. Started before work it does not depend
on, the SDF takes the idle core. Results are the same as a plain call: the function runs once,
whole, and its exception (if any) is raised again by `result()` in the caller's thread. Daemon, so
a Ctrl-C in the caller is not held up at exit by a grid still being computed.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class Background:
    """Start `fn(*args, **kwargs)` on a daemon thread now; `result()` joins it and returns its
    value or raises its exception."""

    def __init__(self, fn: Callable[..., Any], *args: Any, name: str = "avatarkit-background", **kwargs: Any):
        self._value: Any = None
        self._error: BaseException | None = None

        def run():
            try:
                self._value = fn(*args, **kwargs)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread as is
                self._error = exc

        self._thread = threading.Thread(target=run, name=name, daemon=True)
        self._thread.start()

    def result(self) -> Any:
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value


__all__ = ["Background"]
