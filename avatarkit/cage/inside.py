"""Is a point inside a closed mesh, and how deep? Winding numbers and clipped signed depth.

`winding_numbers` sums each triangle's signed solid angle (Van Oosterom & Strackee 1983) over
4 pi: ~1 inside a closed outward mesh, ~0 outside, for any (non-convex) shape. The Taichi kernel
is the fast path; `winding_numbers_reference` is the numpy twin tests compare it with.

`clipped_depth` answers "is every point at least r inside?" without testing all P x M pairs:
 - distance: only triangles whose bounding ball (centroid, circumradius + r) holds a point can be
   closer than r to it (a KD-tree over the points finds them); those pairs get an exact
   point-triangle distance. Every other point is at least r from the surface.
 - sign: points closer than r get their own winding number. The rest are binned into cubes of
   side 2r / sqrt(3): two such points in one cube are closer than 2r while both are at least r
   from the surface, so the segment between them cannot cross it. One winding number per cube
   decides the whole cube.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def winding_numbers(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """points (P, 3), vertices (C, 3), faces (M, 3) -> generalised winding numbers (P,) float64."""
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(pts), np.float64)
    if len(pts):
        from avatarkit.cage import _kernels  # imports Taichi: only when a kernel runs

        _kernels.winding(pts, np.ascontiguousarray(vertices, np.float64),
                         np.ascontiguousarray(faces, np.int32), out)
    return out


def winding_numbers_reference(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """numpy float64 twin of `winding_numbers` (slow: P x M arrays in chunks)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]          # (M, 3, 3)
    out = np.empty(len(pts))
    for s in range(0, len(pts), 256):
        rel = tri[None] - pts[s:s + 256, None, None, :]                 # (p, M, 3, 3)
        a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("pmi,pmi->pm", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pmi,pmi->pm", a, b) * lc
               + np.einsum("pmi,pmi->pm", a, c) * lb + np.einsum("pmi,pmi->pm", b, c) * la)
        out[s:s + 256] = 2 * np.arctan2(det, den).sum(axis=1) / (4 * np.pi)
    return out


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Exact distance between pairs: points (n, 3), triangles (n, 3, 3) -> (n,)."""
    import trimesh.triangles

    if len(points) == 0:
        return np.zeros(0)
    closest = trimesh.triangles.closest_point(np.asarray(triangles, np.float64),
                                              np.asarray(points, np.float64))
    return np.linalg.norm(closest - points, axis=1)


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                     radius: float) -> np.ndarray:
    """Unsigned distance (P,) from each point to the mesh, exact below `radius`, else `radius`."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]          # (M, 3, 3)
    out = np.full(len(pts), float(radius))
    if not len(pts):
        return out
    centroid = tri.mean(axis=1)
    circum = np.linalg.norm(tri - centroid[:, None], axis=2).max(axis=1)
    tree = cKDTree(pts)
    hits = tree.query_ball_point(centroid, circum + radius, workers=-1, return_sorted=False)
    counts = np.fromiter((len(h) for h in hits), dtype=np.int64, count=len(hits))
    if counts.sum() == 0:
        return out
    pi = np.concatenate([np.asarray(h, dtype=np.int64) for h in hits if len(h)])
    fi = np.repeat(np.arange(len(tri)), counts)
    for s in range(0, len(pi), 1 << 20):  # bounded memory for huge point sets
        p, f = pi[s:s + (1 << 20)], fi[s:s + (1 << 20)]
        np.minimum.at(out, p, point_triangle_distance(pts[p], tri[f]))
    return out


def clipped_depth(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                  radius: float) -> np.ndarray:
    """Signed depth (P,): + inside, - outside, |depth| = distance to the surface when below
    `radius`, else +-radius. The mesh must be closed and outward oriented."""
    if not radius > 0:
        raise ValueError("radius must be > 0")
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    dist = surface_distance(pts, vertices, faces, radius)
    inside = np.zeros(len(pts), bool)
    near = dist < radius
    if near.any():
        inside[near] = winding_numbers(pts[near], vertices, faces) > 0.5
    far = np.flatnonzero(~near)
    if len(far):
        cube = 2 * radius / np.sqrt(3) * (1 - 1e-9)
        ijk = np.floor(pts[far] / cube).astype(np.int64)
        ijk -= ijk.min(axis=0)
        keys = np.ravel_multi_index(ijk.T, ijk.max(axis=0) + 1)
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        inside[far] = (winding_numbers(pts[far[first]], vertices, faces) > 0.5)[inverse]
    return np.where(inside, dist, -dist)
