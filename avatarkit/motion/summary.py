"""A readable summary of a motion clip (for `avatarkit motion inspect` and `avatarkit inspect`)."""
from __future__ import annotations

import numpy as np

from avatarkit.motion.clip import MotionClip

_ROTATIONS = {"rotation": "rotation", "neck": "neck", "jaw": "jaw", "eyes[left]": "eyes",
              "eyes[right]": "eyes"}


def summarize(clip: MotionClip) -> dict:
    """Facts about a clip as plain data: frames, fps, duration, and per channel the range of
    each axis (axis-angle channels in degrees, translation in millimetres) and the largest
    rotation angle (degrees) or displacement (mm)."""
    out = {"name": clip.name, "frames": clip.n_frames, "fps": clip.fps, "duration_s": clip.duration,
           "expr_dims": clip.expr_dims, "shape_dims": int(len(clip.shape)), "channels": {}}
    for label, key in _ROTATIONS.items():
        a = getattr(clip, key).astype(np.float64)
        if key == "eyes":
            a = a[:, :3] if label.endswith("[left]") else a[:, 3:]
        deg = np.rad2deg(a)
        out["channels"][label] = {"unit": "deg", "min": deg.min(0).tolist(), "max": deg.max(0).tolist(),
                                  "peak": float(np.linalg.norm(deg, axis=1).max())}
    mm = clip.translation.astype(np.float64) * 1000.0
    out["channels"]["translation"] = {"unit": "mm", "min": mm.min(0).tolist(), "max": mm.max(0).tolist(),
                                      "peak": float(np.linalg.norm(mm - mm[:1], axis=1).max())}
    if clip.expr_dims:
        e = clip.expr.astype(np.float64)
        out["expr"] = {"min": float(e.min()), "max": float(e.max()),
                       "active_dims": int((np.abs(e) > 1e-6).any(0).sum())}
    if len(clip.shape):
        out["shape_norm"] = float(np.linalg.norm(clip.shape))
    return out


def format_summary(clip: MotionClip, title: str | None = None) -> str:
    """`summarize` as aligned text lines."""
    s = summarize(clip)
    lines = [f"motion clip {title or s['name'] or ''}".rstrip(),
             f"  frames     {s['frames']} at {s['fps']:g} fps ({s['duration_s']:.3f} s)",
             f"  expr dims  {s['expr_dims']}    shape dims {s['shape_dims']}",
             "  " + "channel".ljust(15) + "".join(f"{a + ' range':^19}" for a in "xyz") + "     peak"]
    for label, c in s["channels"].items():
        unit = c["unit"]
        ranges = "".join(f"{lo:>8.2f}..{hi:<8.2f} " for lo, hi in zip(c["min"], c["max"]))
        lines.append(f"  {label:<14} {ranges} {c['peak']:8.2f} {unit}")
    if "expr" in s:
        e = s["expr"]
        lines.append(f"  expr           {e['min']:.3f}..{e['max']:.3f}, {e['active_dims']} of "
                     f"{s['expr_dims']} coefficients move")
    if "shape_norm" in s:
        lines.append(f"  shape          |shape| = {s['shape_norm']:.3f}")
    return "\n".join(lines)
