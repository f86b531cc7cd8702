"""Motion clips for `avatarkit inspect`: a predicate that recognises clip files and the inspector.

`avatarkit.inspect` routes files by `register_inspector(predicate, "module:function")`:

    from avatarkit.motion.inspector import is_motion_clip
    register_inspector(is_motion_clip, "avatarkit.motion.inspector:inspect_clip")

The predicate is cheap: it reads a .npz file's key list (not its arrays), the first 64 kB of a
.json file, or the keys of the first .npz in a folder.
"""
from __future__ import annotations

from pathlib import Path

_CLIP_KEYS = {"rotation", "expr"}
_JAW_KEYS = {"jaw_pose", "jaw"}


def _npz_is_clip(path: Path) -> bool:
    from avatarkit.errors import FormatError
    from avatarkit.fileio import open_npz

    try:
        with open_npz(path) as data:
            keys = set(data.files)
    except FormatError:
        return False
    return _CLIP_KEYS <= keys and bool(_JAW_KEYS & keys)


def is_motion_clip(path: Path) -> bool:
    """True for a motion .npz (FLAME keys), our .json clip, or a folder of per-frame clip files."""
    p = Path(path)
    try:
        if p.is_dir():
            folder = p / "flame_param" if (p / "flame_param").is_dir() else p
            first = min(folder.glob("*.npz"), default=None)
            return first is not None and _npz_is_clip(first)
        suffix = p.suffix.lower()
        if suffix == ".npz":
            return _npz_is_clip(p)
        if suffix == ".json":
            with open(p, "rb") as fh:
                return b'"avatarkit.motion"' in fh.read(65536)
    except OSError:
        return False
    return False


def inspect_clip(path: Path):
    """A `Summary` of the clip at `path` (frames, fps, duration, channel ranges)."""
    from avatarkit.inspect import Summary
    from avatarkit.motion.io import load_clip
    from avatarkit.motion.summary import summarize

    s = summarize(load_clip(path))
    out = Summary("motion clip", str(path))
    out.add("name", s["name"] or "(none)").add("frames", s["frames"]).add("fps", s["fps"])
    out.add("duration (s)", round(s["duration_s"], 4))
    out.add("expression dims", s["expr_dims"]).add("shape dims", s["shape_dims"])
    for label, c in s["channels"].items():
        ranges = ", ".join(f"{axis} {lo:.2f}..{hi:.2f}" for axis, lo, hi in zip("xyz", c["min"], c["max"]))
        out.add(f"{label} ({c['unit']})", f"{ranges}; peak {c['peak']:.2f}")
    if "expr" in s:
        e = s["expr"]
        out.add("expr", f"{e['min']:.3f}..{e['max']:.3f}, {e['active_dims']} of {s['expr_dims']} move")
    return out
