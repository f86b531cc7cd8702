"""Nearest triangle of a mesh for many points: exact, vectorised, with a KD-tree prefilter.

trimesh's `proximity.closest_point` needs the optional `rtree` package; this needs only scipy.
Each point is first tested against the `k` triangles with the nearest centroids. That answer is
certified exact when no other triangle can be closer: a triangle whose centroid is at distance
c from the point, and whose corners lie within r of its centroid, is at least c - r away. Points
that the first pass cannot certify get every triangle within (best + r_max) of them tested too.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point as _closest_point_pairs

from avatarkit.errors import InputError

#: points handled at once; bounds the (chunk, k, 3, 3) candidate arrays
CHUNK = 65536


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Pairwise distances: points (M, 3), triangles (M, 3, 3) -> (M,) float64 (Ericson's method)."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0)
    closest = _closest_point_pairs(triangles, points)
    return np.linalg.norm(closest - points, axis=1)


def nearest_faces(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                  exclude: np.ndarray | None = None, candidates: int = 8
                  ) -> tuple[np.ndarray, np.ndarray]:
    """For each point the index of the closest triangle and the distance to it.

    points: (N, 3); vertices: (V, 3); faces: (F, 3) int; exclude: optional (F,) bool mask of
    triangles never to return (e.g. degenerate ones). Returns face ids (N,) int64 and
    distances (N,) float64. Ties (a point equally far from two triangles, e.g. over a shared
    edge) go to the triangle whose centroid is nearer.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    allowed = np.arange(len(f)) if exclude is None else np.flatnonzero(~np.asarray(exclude, bool))
    if len(allowed) == 0:
        raise InputError("the mesh has no usable (non-degenerate) triangles to bind to")
    tri = v[f[allowed]]                                     # (Fa, 3, 3)
    centroids = tri.mean(axis=1)                            # (Fa, 3)
    radius = np.linalg.norm(tri - centroids[:, None], axis=2).max(axis=1)
    r_max = float(radius.max())
    tree = cKDTree(centroids)
    k = int(min(max(candidates, 1), len(allowed)))

    ids = np.empty(len(p), np.int64)
    dist = np.empty(len(p), np.float64)
    for start in range(0, len(p), CHUNK):
        chunk = p[start:start + CHUNK]
        cd, ci = tree.query(chunk, k=k)
        cd = cd.reshape(len(chunk), k)
        ci = ci.reshape(len(chunk), k)
        d = point_triangle_distance(np.repeat(chunk, k, axis=0), tri[ci.ravel()]).reshape(len(chunk), k)
        best = np.argmin(d, axis=1)
        rows = np.arange(len(chunk))
        bid, bd = ci[rows, best], d[rows, best]
        if k < len(allowed):
            # Triangles outside the k nearest centroids are at least cd[:, -1] - r_max away.
            unsure = np.flatnonzero(bd > cd[:, -1] - r_max)
            if len(unsure):
                bid[unsure], bd[unsure] = _exhaustive_near(chunk[unsure], bd[unsure] + r_max,
                                                           tree, tri)
        ids[start:start + len(chunk)] = allowed[bid]
        dist[start:start + len(chunk)] = bd
    return ids, dist


def _exhaustive_near(pts: np.ndarray, reach: np.ndarray, tree: cKDTree, tri: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Test every triangle whose centroid lies within `reach` (M,) of each point (M, 3)."""
    lists = tree.query_ball_point(pts, reach)
    counts = np.fromiter((len(x) for x in lists), np.int64, len(lists))
    cand = np.fromiter((j for x in lists for j in x), np.int64, int(counts.sum()))
    owner = np.repeat(np.arange(len(pts)), counts)
    d = point_triangle_distance(pts[owner], tri[cand])
    order = np.lexsort((d, owner))           # by point, then by distance
    first = np.searchsorted(owner[order], np.arange(len(pts)))
    pick = order[first]
    return cand[pick], d[pick]
