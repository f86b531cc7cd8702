"""`inspect_file(path) -> Summary`: a readable summary of any file avatarkit knows.

Which summariser runs is decided by a small registry, so later formats plug in with one call:

    register_inspector(".usd", "avatarkit.export.usd:inspect_usd")      # by extension
    register_inspector(lambda p: (p / "avatar.json").is_file(), inspect_avatar)  # by predicate

An inspector takes a `pathlib.Path` and returns a `Summary`; it may be given as a
"module:function" string, imported on first use (so `inspect` of a PLY never imports pxr).
Inspectors are tried in registration order; the first whose extension or predicate matches wins.
"""
from __future__ import annotations

import importlib
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Union

import numpy as np

from avatarkit.errors import InputError

Inspector = Callable[[Path], "Summary"]


class ByteCount(int):
    """An int that prints as a file size (`12.3 MB (12,345,678 bytes)`); JSON sees the int."""


@dataclass
class Summary:
    """What `avatarkit inspect` shows: a kind, the path and ordered (label, value) rows.

    Values are JSON-friendly: str, int, float, lists of them, dicts of stats, or lists of
    dicts (one per extra, track, ...)."""

    kind: str
    path: str
    rows: list[tuple[str, Any]] = field(default_factory=list)

    def add(self, label: str, value: Any) -> "Summary":
        self.rows.append((label, value))
        return self

    def get(self, label: str) -> Any:
        return next(v for k, v in self.rows if k == label)

    def to_dict(self) -> dict[str, Any]:
        """{"kind", "path", then one snake_case key per row label} with plain JSON values."""
        out: dict[str, Any] = {"kind": self.kind, "path": self.path}
        for label, value in self.rows:
            out[_key(label)] = _plain(value)
        return out

    def to_text(self) -> str:
        """Aligned, human-readable lines (what the CLI prints)."""
        width = max((len(k) for k, _ in self.rows), default=0) + 2
        lines = [f"{self.kind}: {self.path}"]
        for label, value in self.rows:
            text = _text(value).split("\n")
            lines.append(f"  {label:<{width}}{text[0]}")
            lines += [f"  {'':<{width}}{t}" for t in text[1:]]
        return "\n".join(lines)


def _key(label: str) -> str:
    return re.sub(r"[^0-9a-z]+", "_", label.lower()).strip("_")


def _plain(v: Any) -> Any:
    if isinstance(v, ByteCount):
        return int(v)
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return _plain(v.tolist())
    if isinstance(v, np.generic):
        return _plain(v.item())
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)  # JSON has no NaN/inf
    return v


def _num(x: Any) -> str:
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, (int, np.integer)):
        return f"{int(x):,}"
    if isinstance(x, (float, np.floating)):
        return f"{float(x):.4g}"
    return str(x)


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.1f} {unit} ({n:,} bytes)"
    return f"{n:,} bytes"


def _text(v: Any) -> str:
    if isinstance(v, ByteCount):
        return _size(int(v))
    if isinstance(v, dict):
        head = f"{v['name']}: " if "name" in v else ""
        return head + "  ".join(f"{k} {'x'.join(map(str, x)) if k == 'shape' else _num(x)}"
                                for k, x in v.items() if k != "name")
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, dict) for x in v):
        return "\n".join(_text(x) for x in v)
    if isinstance(v, (list, tuple, np.ndarray)):
        return " ".join(_num(x) for x in v) if len(v) else "none"
    return _num(v)


# --- registry ---------------------------------------------------------------------------
#: (accepts(path), inspector or "module:function", the extension it was registered for or None)
_inspectors: list[tuple[Callable[[Path], bool], Union[Inspector, str], Union[str, None]]] = []


def register_inspector(predicate_or_ext: Union[str, Callable[[Path], bool]],
                       fn: Union[Inspector, str]) -> None:
    """Route files to `fn`: by extension (".usd", case-insensitive) or by predicate(path)."""
    if isinstance(predicate_or_ext, str):
        ext = predicate_or_ext.lower()
        ext = ext if ext.startswith(".") else "." + ext
        _inspectors.append((lambda p: p.suffix.lower() == ext and not p.is_dir(), fn, ext))
    elif callable(predicate_or_ext):
        _inspectors.append((predicate_or_ext, fn, None))
    else:
        raise TypeError("register_inspector needs an extension string or a predicate")


def inspect_file(path: str | os.PathLike) -> Summary:
    """Summarise `path` with the first registered inspector that accepts it."""
    p = Path(path)
    if not p.exists():
        raise InputError("no such file or folder", path)
    for accepts, fn, _ in _inspectors:
        if accepts(p):
            if isinstance(fn, str):
                module, attr = fn.split(":")
                fn = getattr(importlib.import_module(module), attr)
            return fn(p)
    known = sorted({ext for _, _, ext in _inspectors if ext})
    raise InputError(f"do not know how to inspect this; known kinds: {', '.join(known)} "
                     "files and avatarkit folders", path)


# --- PLY --------------------------------------------------------------------------------
def _stats(a: np.ndarray, keys=("min", "median", "mean", "max")) -> dict[str, float]:
    fns = {"min": np.min, "median": np.median, "mean": np.mean, "max": np.max}
    return {k: float(fns[k](a)) for k in keys}


def inspect_ply(path: Path) -> Summary:
    """3DGS PLY: count, SH degree, bounds, opacity and scale statistics, extras, format.

    A valid PLY that is not a splat file (a mesh or plain point cloud: no rot/scale/opacity)
    gets a plain element listing instead of an error."""
    from avatarkit.gaussians.ply import read_ply
    from avatarkit.gaussians.ply_header import check_element_sizes, read_ply_header

    header = read_ply_header(path)
    size = ByteCount(path.stat().st_size)
    vertex = header.element("vertex")
    splat_props = {"opacity", "scale_0", "rot_0", "f_dc_0"}
    if vertex is None or not splat_props.intersection(vertex.property_names()):
        check_element_sizes(header, int(size), path)
        s = Summary("PLY (not 3DGS splats)", str(path))
        s.add("format", header.describe_format()).add("file size", size)
        for e in header.elements:
            props = [f"{'list ' if p.is_list else ''}{p.name}" for p in e.properties]
            s.add(f"element {e.name}", f"{e.count:,} x ({', '.join(props) or 'no properties'})")
        return s

    gs = read_ply(path)
    s = Summary("3DGS PLY", str(path))
    s.add("format", header.describe_format()).add("file size", size)
    _splat_rows(s, gs)
    if header.comments:
        s.add("comments", header.comments)
    return s


def _splat_rows(s: Summary, gs) -> None:
    """The rows every splat file shows: count, SH degree, bounds, opacity/scale stats, extras."""
    s.add("Gaussians", len(gs)).add("SH degree", gs.sh_degree)
    if len(gs):
        lo, hi = gs.bounds()
        s.add("bounds min", lo.tolist()).add("bounds max", hi.tolist())
        s.add("centre", ((lo + hi) / 2).tolist()).add("size", (hi - lo).tolist())
        s.add("opacity", _stats(gs.opacities))
        s.add("scale (largest axis)", _stats(gs.scales.max(axis=1), ("min", "median", "max")))
    extras = []
    for name, a in gs.extras.items():
        e = {"name": name, "shape": list(a.shape), "dtype": str(a.dtype)}
        if a.size and a.dtype.kind in "iufb":
            e.update(min=a.min().item(), max=a.max().item())
        extras.append(e)
    s.add("extras", extras if extras else "none")


def _spz_version(path: Path) -> int:
    """The version field of an SPZ header (inside the gzip stream for versions 2 and 3)."""
    import struct
    import zlib

    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head[:2] == b"\x1f\x8b":
        head = zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, 8)
    return struct.unpack_from("<I", head, 4)[0]


def inspect_spz(path: Path) -> Summary:
    """SPZ (Niantic's compressed splats): version, then the rows of a 3DGS PLY."""
    from avatarkit.gaussians.spz import read_spz

    gs = read_spz(path)  # a bad file fails here, so the header read below is a valid one
    s = Summary("SPZ splats", str(path))
    s.add("format", f"SPZ version {_spz_version(path)}").add("file size", ByteCount(path.stat().st_size))
    _splat_rows(s, gs)
    return s


register_inspector(".ply", inspect_ply)
register_inspector(".spz", inspect_spz)
for _ext in (".usd", ".usda", ".usdc", ".usdz"):
    register_inspector(_ext, "avatarkit.export.usd_stage:inspect_usd")
register_inspector(lambda p: (p.is_dir() and (p / "sequence.json").is_file())
                   or (p.name == "sequence.json" and p.is_file()),
                   "avatarkit.export.ply_sequence:inspect_ply_sequence")
register_inspector(lambda p: p.is_dir() and (p / "avatar.json").is_file(), "avatarkit.avatar:inspect_avatar")
register_inspector(lambda p: _motion_clip(p), "avatarkit.motion.inspector:inspect_clip")
for _ext in (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi", ".gif"):  # video.VIDEO_FILE_EXTENSIONS
    register_inspector(_ext, "avatarkit.video:inspect_video")


def _motion_clip(path: Path) -> bool:
    from avatarkit.motion.inspector import is_motion_clip

    return is_motion_clip(path)

__all__ = ["Summary", "ByteCount", "inspect_file", "register_inspector", "inspect_ply", "inspect_spz"]
