"""Atomic output files and folders: write to a temporary name beside the target, rename when
complete. And `read_npz`, the one guarded reader of the .npz files we keep (rigs, head models,
cage weights, trackers' FLAME fits), and `file_sha256`, the digest that provenance records of input
files.

A failed or interrupted writer never leaves a half-written file or folder under the requested name.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import Iterator

from avatarkit.errors import FormatError, OutputError


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_output_folder(folder: str | os.PathLike) -> Path:
    """Raise OutputError unless `folder` (a target's parent; "" is the current folder) exists
    and new entries can be made in it. Returns it as a Path."""
    folder = Path(folder) if str(folder) else Path(".")
    if not folder.is_dir():
        raise OutputError("output folder does not exist", folder)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError("output folder is not writable", folder)
    return folder


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it onto `path`.

    The temporary name keeps the target's extension (`suffix`), since some writers (USD, OpenCV)
    choose the format from it. On any exception (KeyboardInterrupt included) the temporary file
    is removed and the target is untouched.
    """
    target = Path(path)
    folder = check_output_folder(target.parent)
    suffix = target.suffix if suffix is None else suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".partial{suffix}", dir=folder)
    os.close(fd)
    # mkstemp creates 0600; give the result the permissions a plain open() would have.
    os.chmod(tmp, 0o666 & ~_umask())
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def replace_folder(staged: str | os.PathLike, target: str | os.PathLike) -> Path:
    """Rename the finished folder `staged` onto `target` (same file system).

    An existing `target` is first moved aside and only deleted once the new folder is in
    place, so a failure at any point leaves either the old or the new folder under the name.
    """
    staged, target = Path(staged), Path(target)
    old = None
    if target.exists():
        parent = target.parent if str(target.parent) else Path(".")
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=parent))
        os.rmdir(old)
        os.replace(target, old)
    try:
        os.replace(staged, target)
    except BaseException:
        if old is not None:
            os.replace(old, target)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return target


def _plain_permissions(folder: Path) -> None:
    """mkdtemp/mkstemp make private entries (0700/0600); give the finished folder the
    permissions a plain mkdir/open would have."""
    mask = _umask()
    os.chmod(folder, 0o777 & ~mask)
    for p in folder.rglob("*"):
        os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~mask)


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, tag: str = "partial") -> Iterator[Path]:
    """Yield an empty temporary folder beside `path`; on success give it plain permissions and
    `replace_folder` it onto `path`. On any exception it is removed and `path` is untouched.

    The caller checks that `path` may be replaced; the parent folder must exist.
    """
    target = Path(path)
    parent = target.parent if str(target.parent) else Path(".")
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.{tag}-", dir=parent))
    try:
        yield tmp
        _plain_permissions(tmp)
        replace_folder(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def read_npz(path: str | os.PathLike, unreadable: str = "not a readable .npz file") -> dict:
    """Every array of an .npz file (name -> ndarray), pickles refused. A file that is not a
    readable npz is a FormatError "`unreadable` (why)" naming it; the caller checks that the
    file exists (its message says what was missing) and which keys it needs."""
    import numpy as np

    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise FormatError(f"{unreadable} ({e})", path) from None


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 hex digest of a file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
