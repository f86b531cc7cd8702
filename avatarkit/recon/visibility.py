"""What the input camera sees: the renderer's depth map of a set of Gaussians, and which points
lie on that visible surface (within `DEPTH_TOL` of the depth, facing the camera)."""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.image_sampling import lookup

#: a disc counts as seen when it is this close (metres) behind the rendered depth
DEPTH_TOL = 0.004
#: and faces the camera at least this much (cosine)
MIN_FACING = 0.15


def depth_map(gaussians: GaussianSet, camera, max_side: int = 512):
    """The renderer's depth (H, W) of `gaussians` seen by `camera`, rendered at most `max_side`
    pixels wide and returned with the camera it was rendered with."""
    from avatarkit.render import render

    k = min(1.0, max_side / max(camera.width, camera.height))
    cam = camera if k >= 1 else camera.with_size(max(1, round(camera.width * k)),
                                                 max(1, round(camera.height * k)))
    r = render(gaussians, cam)
    return r.depth, r.alpha, cam


def seen_from(points: np.ndarray, normals: np.ndarray | None, camera, depth: np.ndarray,
              depth_camera, tol: float | None = None, min_facing: float | None = None):
    """(seen (N,) bool, pixels (N, 2) in `camera`, facing (N,)): points within `tol` of the
    rendered depth (from `depth_camera`) and, with normals (N, 3), facing the camera."""
    tol = DEPTH_TOL if tol is None else tol
    min_facing = MIN_FACING if min_facing is None else min_facing
    px, z = camera.project(points)
    dpx, dz = depth_camera.project(points)
    d = lookup(depth, dpx)
    inside = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] < camera.width) \
        & (px[:, 1] >= 0) & (px[:, 1] < camera.height)
    seen = inside & (d > 0) & (dz <= d + tol)
    facing = np.ones(len(points))
    if normals is not None:
        view = camera.camera_center[None] - points
        view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
        facing = np.einsum("ij,ij->i", view, normals)
        seen &= facing >= min_facing
    return seen, px, facing


__all__ = ["DEPTH_TOL", "MIN_FACING", "depth_map", "seen_from"]
