"""Mesh sanity checks that trimesh does not offer without optional dependencies.

`self_intersections` finds pairs of non-adjacent triangles that cross each other: candidate
pairs come from a KD-tree over triangle centroids (bounding-sphere overlap), then every edge of
one triangle is tested against the other with Moller-Trumbore, both ways, vectorised in chunks.
Triangles sharing a vertex are skipped (they touch by construction); coplanar overlaps are not
reported.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def _segments_hit_triangles(p0, p1, a, b, c, eps=1e-12) -> np.ndarray:
    """Does segment p0-p1 cross triangle abc (strictly inside both)? All (n, 3) -> (n,) bool."""
    d = p1 - p0
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p0 - a
    u = inv * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", d, q)
    t = inv * np.einsum("ij,ij->i", e2, q)
    tol = 1e-9
    return ok & (u > tol) & (v > tol) & (u + v < 1 - tol) & (t > tol) & (t < 1 - tol)


def self_intersections(vertices: np.ndarray, faces: np.ndarray, chunk: int = 200_000) -> np.ndarray:
    """Pairs (K, 2) of face indices whose triangles intersect and share no vertex."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    centre = tri.mean(axis=1)
    radius = np.linalg.norm(tri - centre[:, None], axis=2).max(axis=1)
    pairs = cKDTree(centre).query_pairs(2 * radius.max(), output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = pairs[:, 0], pairs[:, 1]
    close = np.linalg.norm(centre[i] - centre[j], axis=1) <= radius[i] + radius[j]
    i, j = i[close], j[close]
    share = (f[i][:, :, None] == f[j][:, None, :]).any(axis=(1, 2))
    i, j = i[~share], j[~share]
    hits = []
    for s in range(0, len(i), chunk):
        ii, jj = i[s:s + chunk], j[s:s + chunk]
        A, B = tri[ii], tri[jj]
        hit = np.zeros(len(ii), dtype=bool)
        for k in range(3):
            hit |= _segments_hit_triangles(A[:, k], A[:, (k + 1) % 3], B[:, 0], B[:, 1], B[:, 2])
            hit |= _segments_hit_triangles(B[:, k], B[:, (k + 1) % 3], A[:, 0], A[:, 1], A[:, 2])
        hits.append(np.stack([ii[hit], jj[hit]], axis=1))
    return np.concatenate(hits) if hits else np.zeros((0, 2), dtype=np.int64)


def triangle_quality(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Smallest interior angle of each triangle, degrees (F,)."""
    t = np.asarray(vertices, dtype=np.float64)[faces]
    angles = []
    for k in range(3):
        u = t[:, (k + 1) % 3] - t[:, k]
        w = t[:, (k + 2) % 3] - t[:, k]
        cos = np.einsum("ij,ij->i", u, w) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-30)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(angles, axis=0)
