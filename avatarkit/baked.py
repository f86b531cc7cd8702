"""The data a bake streams from `bake` to the writers (USD stage, PLY sequence, preview).

`BakeStatic` is what never changes over a clip (topology, colours, opacities); `BakeFrame` is one
frame's moving data. Writers consume `BakeStatic` once and then an iterator of `BakeFrame`s, so a
300-frame bake never holds more than one frame in memory.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.limits import MAX_FPS, MIN_FPS
from avatarkit.gaussians import GaussianSet


@dataclass(frozen=True)
class SplatFrame:
    """Moving attributes of one splat part at one frame (same order as the part's static data)."""

    means: np.ndarray   # (N, 3) float32, world space
    quats: np.ndarray   # (N, 4) float32, w x y z, unit
    scales: np.ndarray  # (N, 3) float32, linear


@dataclass(frozen=True)
class BakeStatic:
    """What a whole bake shares: topology and the non-moving splat attributes.

    `face` / `hair` are the rest-pose GaussianSets: their opacities, SH and extras are the
    static attributes; their means/quats/scales are the rest pose (frames override them).
    """

    fps: float
    n_frames: int
    head_faces: np.ndarray            # (F, 3) int32
    face: GaussianSet                 # bald head splats, rest pose
    hair: GaussianSet                 # hair splats, rest pose
    cage_faces: np.ndarray            # (M, 3) int32
    provenance: dict = field(default_factory=dict)  # JSON-able: tool version, avatar, clip, settings


@dataclass(frozen=True)
class BakeFrame:
    """One baked frame. `index` is the USD time code; `time` = index / fps seconds."""

    index: int
    time: float
    head_vertices: np.ndarray         # (V, 3) float32, posed head mesh
    face: SplatFrame
    hair: SplatFrame
    cage_vertices: np.ndarray         # (C, 3) float32, simulated cage

    def gaussians(self, static: BakeStatic, part: str) -> GaussianSet:
        """The part ('face' or 'hair') at this frame as a full GaussianSet."""
        rest: GaussianSet = getattr(static, part)
        moving: SplatFrame = getattr(self, part)
        return rest.replace(means=moving.means, quats=moving.quats, scales=moving.scales)

    def person(self, static: BakeStatic, hair: bool = True) -> GaussianSet:
        """The whole avatar at this frame as one GaussianSet to render: the face part, then the
        hair part (when `hair`), without per-Gaussian extras."""
        parts = [self.gaussians(static, "face").replace(extras={})]
        if hair:
            parts.append(self.gaussians(static, "hair").replace(extras={}))
        return GaussianSet.concat(parts)


def check_fps(fps) -> None:
    """InputError unless `fps` (a `BakeStatic`'s frame rate) is a finite positive number."""
    if not (isinstance(fps, (int, float, np.number)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    if not MIN_FPS <= fps <= MAX_FPS:
        raise InputError(f"fps must be between {MIN_FPS:g} and {MAX_FPS:g}, got {fps:g}")


class StreamingWriter:
    """What the file writers of a bake share: `begin(static)`, `write(frame)` per frame, then
    `close()` or `abort()`; subclasses move `_state` from "new" to "open" to "closed". As a
    context manager: close on success, abort on any exception (Ctrl-C included)."""

    _state = "new"

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            self.abort()
        elif self._state == "open":
            self.close()
        return False
