"""Atomic output files and folders: write to a temporary name beside the target, rename when
complete. `read_npz`/`open_npz`, the guarded readers of every .npz file we read (clips, rigs,
head models, cage weights, trackers' FLAME fits).

The rules every writer follows (docs/safety.md):
- A failed or interrupted writer never leaves a half-written file or folder under the requested
  name; a failed write (a full disk: ENOSPC, EFBIG, EIO ...) is an `OutputError` naming the target.
- Temporary entries are named `.<target name>.<tag>-<host>-<pid>-<random>` beside the target (tag
  `partial`, `build` or `old`). A process killed outright (SIGKILL, power loss) cannot remove its
  own: the next writer into that folder does (`sweep_stale`), once the process that made them is
  gone. Nothing else is ever removed by the sweep.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import shutil
import socket
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import Iterator

from avatarkit.errors import FormatError, OutputError

#: tags of our temporary entries: `partial` (being written), `build` (an avatar being built),
#: `old` (a previous output moved aside while its replacement goes in)
TEMP_TAGS = ("partial", "build", "old")
_HOST = hashlib.sha1(socket.gethostname().encode()).hexdigest()[:6]
_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.(?P<tag>%s)-(?P<host>[0-9a-f]{6})-(?P<pid>\d+)-"
                      % "|".join(TEMP_TAGS))


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def temp_prefix(name: str, tag: str = "partial") -> str:
    """The start of a temporary entry's name for the output `name` (see the module notes)."""
    if tag not in TEMP_TAGS:
        raise ValueError(f"unknown temporary tag {tag!r}")
    return f".{name}.{tag}-{_HOST}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # someone else's process (or a pid we cannot ask about): leave it alone
    return True


def is_stale_temp(path: str | os.PathLike) -> bool:
    """Whether `path` is a temporary entry of ours whose process (on this host) has gone."""
    m = _TEMP_RE.match(Path(path).name)
    return bool(m) and m["host"] == _HOST and not _alive(int(m["pid"]))


def sweep_stale(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary entries in `folder` left by writers that were killed (see the module
    notes); returns what was removed. A moved-aside `old` output whose replacement never arrived
    is put back under its name instead. Errors are ignored: a sweep never fails a command."""
    folder = Path(folder) if str(folder) else Path(".")
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        m = _TEMP_RE.match(entry.name)
        if not m or m["host"] != _HOST or _alive(int(m["pid"])):
            continue
        path = Path(entry.path)
        try:
            if m["tag"] == "old" and not os.path.lexists(folder / m["name"]):
                os.replace(path, folder / m["name"])
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(path)
            else:
                path.unlink()
            removed.append(path)
        except OSError:
            pass
    return removed


_swept: set[str] = set()


def _sweep_once(folder: Path) -> None:
    """`sweep_stale(folder)` the first time this process writes there: what a killed run left is
    there before we start, and a writer of thousands of frames should not list them every time."""
    key = os.path.abspath(folder)
    if key not in _swept:
        _swept.add(key)
        sweep_stale(folder)


def check_output_folder(folder: str | os.PathLike) -> Path:
    """Raise OutputError unless `folder` (a target's parent; "" is the current folder) exists
    and new entries can be made in it. Returns it as a Path."""
    folder = Path(folder) if str(folder) else Path(".")
    if not folder.is_dir():
        raise OutputError("output folder does not exist", folder)
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError("output folder is not writable", folder)
    return folder


def write_failed(e: OSError, target: str | os.PathLike) -> OutputError:
    """The OutputError for an OSError met while writing `target` (a full disk, a lost mount)."""
    why = e.strerror or (errno.errorcode.get(e.errno) if e.errno else None) or str(e) or type(e).__name__
    return OutputError(f"could not write ({why})", target)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it onto `path`.

    The temporary name keeps the target's extension (`suffix`), since some writers (USD, OpenCV)
    choose the format from it. On any exception (KeyboardInterrupt included) the temporary file
    is removed and the target is untouched; an OSError (a full disk) becomes an OutputError
    naming the target.
    """
    target = Path(path)
    folder = check_output_folder(target.parent)
    _sweep_once(folder)
    suffix = target.suffix if suffix is None else suffix
    try:
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(target.name), suffix=suffix, dir=folder)
    except OSError as e:
        raise write_failed(e, target) from None
    os.close(fd)
    # mkstemp creates 0600; give the result the permissions a plain open() would have.
    os.chmod(tmp, 0o666 & ~_umask())
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException as e:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        if isinstance(e, OSError):
            raise write_failed(e, target) from None
        raise


def replace_folder(staged: str | os.PathLike, target: str | os.PathLike) -> Path:
    """Rename the finished folder `staged` onto `target` (same file system).

    An existing `target` is first moved aside and only deleted once the new folder is in
    place, so a failure at any point leaves either the old or the new folder under the name
    (a kill between the two renames leaves the old one aside; `sweep_stale` puts it back).
    """
    staged, target = Path(staged), Path(target)
    old = None
    if target.exists():
        parent = target.parent if str(target.parent) else Path(".")
        old = Path(tempfile.mkdtemp(prefix=temp_prefix(target.name, "old"), dir=parent))
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


def make_temp_folder(target: str | os.PathLike, tag: str = "partial", inside: bool = False) -> Path:
    """A new empty temporary folder for building `target`: beside it, or inside it (`inside`,
    for writers that fill an existing folder). Stale ones of killed runs are swept first."""
    target = Path(target)
    parent = target if inside else (target.parent if str(target.parent) else Path("."))
    _sweep_once(parent)
    try:
        return Path(tempfile.mkdtemp(prefix=temp_prefix(target.name, tag), dir=parent))
    except OSError as e:
        raise OutputError(f"output folder is not writable ({e.strerror})", parent) from None


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, tag: str = "partial") -> Iterator[Path]:
    """Yield an empty temporary folder beside `path`; on success give it plain permissions and
    `replace_folder` it onto `path`. On any exception it is removed and `path` is untouched; an
    OSError (a full disk) becomes an OutputError naming `path`.

    The caller checks that `path` may be replaced; the parent folder must exist.
    """
    target = Path(path)
    tmp = make_temp_folder(target, tag)
    try:
        yield tmp
        _plain_permissions(tmp)
        replace_folder(tmp, target)
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(e, OSError):
            raise write_failed(e, target) from None
        raise


# --- .npz ------------------------------------------------------------------------------------
# the most bytes the arrays of one .npz may hold once decompressed: checked against the sizes the
# file declares before anything is inflated or allocated (a zip bomb is refused unread)
from avatarkit.limits import MAX_NPZ_BYTES  # noqa: E402


class GuardedNpz:
    """An open .npz whose members are read only after their declared sizes are checked:
    `files` (names), `npz[name]` -> ndarray (FormatError when unreadable), `close()`."""

    def __init__(self, path: str | os.PathLike, unreadable: str = "not a readable .npz file",
                 max_bytes: int | None = None):
        import numpy as np

        self.path, self._unreadable = path, unreadable
        self.max_bytes = int(MAX_NPZ_BYTES if max_bytes is None else max_bytes)
        self._npz = None
        try:
            with open(path, "rb") as fh:
                magic = fh.read(4)
            # np.load would read a bare .npy (or pickle) whole, whatever size its header claims
            if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
                raise ValueError("not a zip archive")
            self._npz = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise FormatError(f"{unreadable} ({e})", path) from None
        try:
            infos = self._npz.zip.infolist()
        except Exception as e:  # noqa: BLE001 - any failure here is a damaged archive
            self.close()
            raise FormatError(f"{unreadable} ({e})", path) from None
        total = sum(max(i.file_size, 0) for i in infos)
        if total > self.max_bytes:
            self.close()
            raise FormatError(f"its arrays would take {total / 2**20:,.0f} MiB once decompressed; the "
                              f"limit is {self.max_bytes / 2**20:,.0f} MiB", path)
        self._infos = {i.filename: i for i in infos}
        self.files = list(self._npz.files)

    def __getitem__(self, key: str):
        import numpy as np

        info = self._infos.get(key + ".npy") or self._infos.get(key)
        try:
            if info is None:
                raise KeyError(key)
            with self._npz.zip.open(info) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                else:
                    shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                header = fh.tell()
            count = 1
            for s in shape:
                count *= int(s)
            need = count * dtype.itemsize
            if dtype.hasobject:
                raise ValueError("object arrays are not read (they would need pickle)")
            if need > info.file_size - header:
                raise ValueError(f"its header claims shape {tuple(shape)} {dtype} ({need:,} bytes) but "
                                 f"the member holds {max(info.file_size - header, 0):,}")
            return self._npz[key]
        except KeyError:
            raise
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, MemoryError,
                OverflowError, TypeError) as e:
            raise FormatError(f"cannot read key {key!r} ({e})", self.path) from None

    def __contains__(self, key: str) -> bool:
        return key in self.files

    def close(self) -> None:
        if self._npz is not None:
            self._npz.close()
            self._npz = None

    def __enter__(self) -> "GuardedNpz":
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False


def open_npz(path: str | os.PathLike, unreadable: str = "not a readable .npz file",
             max_bytes: int | None = None) -> GuardedNpz:
    """Open an .npz for guarded reads (see `GuardedNpz`); use it as a context manager."""
    return GuardedNpz(path, unreadable, max_bytes)


def read_npz(path: str | os.PathLike, unreadable: str = "not a readable .npz file",
             max_bytes: int | None = None) -> dict:
    """Every array of an .npz file (name -> ndarray), pickles refused, sizes checked before
    allocation (`MAX_NPZ_BYTES`). A file that is not a readable npz is a FormatError
    "`unreadable` (why)" naming it; the caller checks that the file exists (its message says what
    was missing) and which keys it needs."""
    with open_npz(path, unreadable, max_bytes) as z:
        out = {}
        for k in z.files:
            try:
                out[k] = z[k]
            except FormatError as e:
                raise FormatError(f"{unreadable} ({e.message})", path) from None
        return out


# --- JSON ------------------------------------------------------------------------------------
def json_depth_ok(doc, limit: int) -> bool:
    """Whether `doc` (parsed JSON) nests at most `limit` containers deep (checked iteratively)."""
    stack = [(doc, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, (dict, list)):
            if depth > limit:
                return False
            children = node.values() if isinstance(node, dict) else node
            stack.extend((c, depth + 1) for c in children if isinstance(c, (dict, list)))
    return True


def json_loads(text: str | bytes, path: str | os.PathLike | None = None):
    """`json.loads`, plus a FormatError naming `path` for a document nested deeper than
    `limits.MAX_JSON_DEPTH` (which would otherwise end in a RecursionError here or in the schema
    check). Other parse errors propagate as `json.JSONDecodeError` for the caller to word."""
    import json

    from avatarkit.limits import MAX_JSON_DEPTH

    try:
        doc = json.loads(text)
    except RecursionError:
        doc = None
        ok = False
    else:
        ok = json_depth_ok(doc, MAX_JSON_DEPTH)
    if not ok:
        raise FormatError(f"JSON nested more than {MAX_JSON_DEPTH} levels deep", path)
    return doc


def check_not_an_input(output: str | os.PathLike, inputs: dict[str, str | os.PathLike | None]) -> None:
    """OutputError when `output` names the same file or folder as one of `inputs` (label ->
    path; None entries skipped): a command never replaces what it reads."""
    out = Path(output)
    for label, p in inputs.items():
        if p is None:
            continue
        try:
            same = out.exists() and Path(p).exists() and os.path.samefile(out, p)
        except OSError:
            same = False
        if same or out.resolve() == Path(p).resolve():
            raise OutputError(f"is also the {label} input; refusing to replace it (choose another output)",
                              output)


def check_inside(target: str | os.PathLike, root: str | os.PathLike) -> Path:
    """OutputError unless `target` stays inside the folder `root` once links are followed, and is
    not itself a link: a symbolic link placed in an output folder must not send outputs (or the
    replacement of old ones) elsewhere. Returns `target` as a Path."""
    target, root = Path(target), Path(root)
    real_root = root.resolve()
    if target.is_symlink():
        raise OutputError(f"is a symbolic link; outputs are written only inside {root}", target)
    try:
        target.parent.resolve().relative_to(real_root)
    except ValueError:
        raise OutputError(f"a symbolic link on the way leads outside the output folder {root}; "
                          f"refusing to write there", target) from None
    return target
