"""The one family of user-facing errors.

Every failure a user can cause (a bad file, a bad argument) is an `AvatarKitError`; the CLI
prints its message on one line and exits with code 2. Anything else is a bug (exit code 1).
"""
from __future__ import annotations

import os
import re


class AvatarKitError(Exception):
    """Base class. `path` (optional) names the file the problem is in; it leads the message."""

    def __init__(self, message: str, path: str | os.PathLike | None = None):
        self.message = message
        self.path = os.fspath(path) if path is not None else None
        super().__init__(f"{self.path}: {message}" if self.path else message)

    def with_path(self, path: str | os.PathLike) -> "AvatarKitError":
        """The same error, now naming `path` (used when a lower layer did not know the file)."""
        if self.path is not None:
            return self
        err = type(self)(self.message, path)
        err.__cause__ = self.__cause__
        return err


class InputError(AvatarKitError):
    """A value handed to the library is wrong: shapes, ranges, options, missing inputs."""


class FormatError(InputError):
    """A file's bytes are not what its format promises (truncated, corrupt, wrong types)."""


class OutputError(AvatarKitError):
    """An output cannot be written (unwritable folder, unknown extension)."""


def last_line(exc: BaseException, default: str = "unreadable") -> str:
    """The last non-empty line of a foreign exception's text (OpenUSD's Tf errors put the useful
    part last), safe when the text itself cannot be decoded (a damaged file's bytes quoted in a
    USD parse error are not always UTF-8)."""
    try:
        text = str(exc)
    except Exception:  # noqa: BLE001 - e.g. UnicodeDecodeError inside Tf.ErrorException.__str__
        return f"{default} (the error text is not valid UTF-8)"
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        return default
    # OpenUSD: "Error in 'pxrInternal_...::UsdStage::Open' at line 1287 in file ...cpp : 'the text'"
    m = re.match(r"^Error in '.*' at line \d+ in file .* : '(?P<text>.*)'$", lines[-1])
    return m["text"] if m else lines[-1]
