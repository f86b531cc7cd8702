"""What makes a batch re-run skip work: content hashes of a job's inputs, a key per output, and
a record file beside each output (`<output>.job.json`).

An output is up to date when its record exists, its key equals the key the job would write now
(SHA-256 of: avatarkit's version, the avatar's files, the clip's bytes, the bake settings and
that output's own options), and every file the record lists is there with the recorded size.
The record is written (atomically) after its output is complete and removed before an output
is rewritten, so a record never vouches for a half-written or older output.
"""
from __future__ import annotations

import datetime
import hashlib
import json
import os
from pathlib import Path

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path, json_loads

RECORD_FORMAT = "avatarkit.batch-output"
RECORD_VERSION = 1
RECORD_SUFFIX = ".job.json"
#: avatar files that do not change what a bake produces
_AVATAR_IGNORED = {"preview.png"}
_CHUNK = 1 << 20


def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as fh:
        while block := fh.read(_CHUNK):
            h.update(block)


def _hash_files(files: list[Path], root: Path, tag: str) -> str:
    h = hashlib.sha256(tag.encode())
    for f in files:
        rel = f.relative_to(root).as_posix().encode()
        h.update(len(rel).to_bytes(4, "little") + rel + f.stat().st_size.to_bytes(8, "little"))
        _hash_file(h, f)
    return h.hexdigest()


def avatar_sha256(folder: str | os.PathLike) -> str:
    """SHA-256 of an avatar folder: every visible file in it (names and bytes) but preview.png.
    Nothing is parsed, so a corrupt avatar still hashes (and fails when its job loads it)."""
    folder = Path(folder)
    if not folder.exists():
        raise InputError("avatar folder not found", folder)
    if not folder.is_dir():
        raise InputError("not an avatar folder (a file, not a folder)", folder)
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and not p.name.startswith(".") and p.name not in _AVATAR_IGNORED)
    return _hash_files(files, folder, "avatarkit.avatar-files/1")


def clip_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a clip: its file's bytes, or a per-frame folder's .npz files (the ones
    `load_clip` reads: in flame_param/ if there is one)."""
    path = Path(path)
    if path.is_dir():
        folder = path / "flame_param" if (path / "flame_param").is_dir() else path
        files = sorted(p for p in folder.glob("*.npz") if p.is_file())
        return _hash_files(files, folder, "avatarkit.clip-folder/1")
    if not path.exists():
        raise InputError("no such file or folder", path)
    try:
        return _hash_files([path], path.parent, "avatarkit.clip-file/1")
    except PermissionError as e:
        raise InputError(f"cannot read: {e.strerror}", path) from None


def output_key(avatar_sha: str, clip_sha: str, bake_settings: dict, kind: str, options: dict) -> str:
    """The key of one output: what it depends on, canonical JSON, SHA-256."""
    from avatarkit import __version__

    doc = {"record": RECORD_VERSION, "tool": "avatarkit", "version": __version__, "avatar": avatar_sha,
           "clip": clip_sha, "bake": bake_settings, "output": {"kind": kind, **options}}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":"), default=str).encode()).hexdigest()


def record_path(target: str | os.PathLike) -> Path:
    """Where the record of the output `target` lives: beside it, `<name>.job.json`."""
    target = Path(target)
    return target.with_name(target.name + RECORD_SUFFIX)


def output_files(kind: str, target: Path) -> list[Path]:
    """The files an output consists of: a USD stage and its `<name>_clips/` layers; a PLY
    sequence's sequence.json and the frames it lists; a preview file."""
    files = [target] if kind != "ply" else []
    if kind == "usd":
        from avatarkit.export.usd_stage import CLIP_FOLDER_SUFFIX

        clips = target.with_name(target.stem + CLIP_FOLDER_SUFFIX)
        if target.suffix.lower() != ".usdz" and clips.is_dir():
            files += sorted(p for p in clips.rglob("*") if p.is_file() and not p.name.startswith("."))
    elif kind == "ply":
        from avatarkit.export.ply_sequence import SIDECAR, read_sidecar

        doc = read_sidecar(target / SIDECAR)
        names = doc["files"]
        names = [n for v in names.values() for n in v] if isinstance(names, dict) else names
        files = [target / SIDECAR] + [target / n for n in names]
    return files


def read_record(target: str | os.PathLike) -> dict | None:
    """The record of output `target`, or None if there is none or it is unreadable."""
    p = record_path(target)
    try:
        doc = json_loads(p.read_text(encoding="utf-8"), p)
    except (OSError, UnicodeDecodeError, ValueError, FormatError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != RECORD_FORMAT or doc.get("version") != RECORD_VERSION:
        return None
    return doc


def is_up_to_date(target: str | os.PathLike, key: str) -> bool:
    """True when output `target` is complete (every recorded file, recorded size) and its
    record's key is `key`."""
    target = Path(target)
    doc = read_record(target)
    if doc is None or doc.get("key") != key or not isinstance(doc.get("files"), list) or not doc["files"]:
        return False
    base = target.parent
    for entry in doc["files"]:
        try:
            rel, size = entry["path"], int(entry["bytes"])
            if Path(rel).is_absolute() or ".." in Path(rel).parts:
                return False
            if (base / rel).stat().st_size != size:
                return False
        except (KeyError, TypeError, ValueError, OSError):
            return False
    return True


def recorded_bytes(target: str | os.PathLike) -> int:
    """Total size of an output as its record lists it (0 without a record)."""
    doc = read_record(target)
    try:
        return sum(int(e["bytes"]) for e in doc["files"]) if doc else 0
    except (KeyError, TypeError, ValueError):
        return 0


def remove_record(target: str | os.PathLike) -> None:
    record_path(target).unlink(missing_ok=True)


def write_record(target: str | os.PathLike, kind: str, key: str, job_name: str, inputs: dict,
                 settings: dict, seconds: float) -> int:
    """Write the record of the finished output `target` (atomically); returns its size in bytes."""
    from avatarkit import __version__

    target = Path(target)
    files = [{"path": f.relative_to(target.parent).as_posix(), "bytes": f.stat().st_size}
             for f in output_files(kind, target)]
    doc = {"format": RECORD_FORMAT, "version": RECORD_VERSION, "key": key, "job": job_name, "kind": kind,
           "output": target.name, "tool": f"avatarkit {__version__}", "inputs": inputs, "settings": settings,
           "seconds": round(float(seconds), 3),
           "finished": datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat(),
           "files": files}
    with atomic_path(record_path(target)) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return sum(f["bytes"] for f in files)


__all__ = ["RECORD_FORMAT", "RECORD_SUFFIX", "avatar_sha256", "clip_sha256", "is_up_to_date", "output_files",
           "output_key", "read_record", "record_path", "recorded_bytes", "remove_record", "write_record"]
