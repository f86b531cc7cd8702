"""Cameras for previews: frame a set of splats, orbit around it (turntables)."""
from __future__ import annotations

import math

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.render.camera import Camera, focal_from_fov

#: splat sets larger than this are framed on the 0.5..99.5 percentiles of their centres, so a
#: few stray floaters (common in lifted splats) do not shrink the subject to a dot
ROBUST_MIN_COUNT = 200
ROBUST_QUANTILE = 0.005


def scene_bounds(source) -> tuple[np.ndarray, np.ndarray]:
    """(lo (3,), hi (3,)) of a GaussianSet (robust, see ROBUST_MIN_COUNT), an (N, 3) point
    array, or a (lo, hi) pair given directly."""
    if isinstance(source, GaussianSet):
        if len(source) == 0:
            raise InputError("cannot frame an empty set of splats")
        pts = source.means.astype(np.float64)
        if len(pts) >= ROBUST_MIN_COUNT:
            lo, hi = np.quantile(pts, [ROBUST_QUANTILE, 1 - ROBUST_QUANTILE], axis=0)
            return lo, hi
        return pts.min(axis=0), pts.max(axis=0)
    if isinstance(source, (tuple, list)) and len(source) == 2:
        lo, hi = (np.asarray(v, dtype=np.float64) for v in source)
        if lo.shape != (3,) or hi.shape != (3,):
            raise InputError("bounds must be a pair of 3-vectors (lo, hi)")
    else:
        try:
            pts = np.asarray(source, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"cannot frame {type(source).__name__}: give a GaussianSet, "
                             "points (N, 3) or bounds (lo, hi)") from None
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise InputError(f"points to frame must have shape (N, 3), got {pts.shape}")
        lo, hi = pts.min(axis=0), pts.max(axis=0)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()) or (hi < lo).any():
        raise InputError("bounds must be finite with lo <= hi")
    return lo, hi


def framing(source, fov_deg: float = 30.0, width: int = 512, height: int = 512,
            margin: float = 1.15) -> tuple[np.ndarray, float]:
    """(target (3,), distance) such that the bounding sphere of `source`'s bounds, enlarged by
    `margin`, fits the narrower field of view of a `width` x `height` camera from any direction."""
    lo, hi = scene_bounds(source)
    if not (math.isfinite(margin) and margin > 0):
        raise InputError(f"framing margin must be > 0, got {margin}")
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    focal = focal_from_fov(fov_deg, height)
    half = math.atan(0.5 * min(width, height) / focal)
    return center, radius * margin / math.sin(half)


def frame_camera(source, azimuth_deg: float = 0.0, elevation_deg: float = 0.0,
                 fov_deg: float = 30.0, width: int = 512, height: int = 512,
                 margin: float = 1.15) -> Camera:
    """An orbit camera (see `Camera.orbit`) that frames `source` (GaussianSet, points (N, 3)
    or (lo, hi) bounds); azimuth 0, elevation 0 looks at the face from the front."""
    target, distance = framing(source, fov_deg, width, height, margin)
    return Camera.orbit(target, azimuth_deg, elevation_deg, distance, fov_deg, width, height)


def turntable_cameras(n: int, source=None, *, target=None, distance: float | None = None,
                      elevation_deg: float = 10.0, fov_deg: float = 30.0, width: int = 512,
                      height: int = 512, start_azimuth_deg: float = 0.0,
                      margin: float = 1.15) -> list[Camera]:
    """`n` orbit cameras evenly spaced over 360 degrees of azimuth (a seamless loop), starting
    at `start_azimuth_deg`. Target and distance come from framing `source` unless given."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InputError(f"a turntable needs a positive number of views, got {n!r}")
    if target is None or distance is None:
        if source is None:
            raise InputError("turntable_cameras needs `source` to frame, or target and distance")
        auto_target, auto_distance = framing(source, fov_deg, width, height, margin)
        target = auto_target if target is None else target
        distance = auto_distance if distance is None else distance
    return [Camera.orbit(target, start_azimuth_deg + 360.0 * i / n, elevation_deg, distance,
                         fov_deg, width, height) for i in range(int(n))]
