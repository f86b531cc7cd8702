"""Nearest triangle of a mesh for many points: exact, vectorised, with a KD-tree prefilter.

trimesh's `proximity.closest_point` needs the optional `rtree` package; this needs only scipy.
Each point is first tested against the `k` triangles with the nearest centroids. That answer is
certified exact when no other triangle can be closer: a triangle whose centroid is at distance
c from the point, and whose corners lie within r of its centroid, is at least c - r away. Points
that the first pass cannot certify look at every triangle whose centroid is within
(best + r_max) of them; of those, only the ones whose lower bound (the centroid sphere's c - r,
and the distance to the triangle's plane) does not exceed the best distance so far get the exact
test (`_pruned_near`): the others cannot be nearer, so the answer is the one testing all of them
gives (`_exhaustive_near`, the reference; ties go to the lower triangle index in both). Points far
from a coarse mesh (hair over the scalp: 2 cm away, 1 cm triangles) leave the first pass
uncertified, which is where the pruning pays.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point as _closest_point_pairs

from avatarkit.errors import InputError

#: points handled at once; bounds the (chunk, k, 3, 3) candidate arrays
CHUNK = 65536
#: candidates per uncertified point fetched as one (M, k) array before falling back to lists
WIDE = 48


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Pairwise distances: points (M, 3), triangles (M, 3, 3) -> (M,) float64 (Ericson's method)."""
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0)
    closest = _closest_point_pairs(triangles, points)
    return np.linalg.norm(closest - points, axis=1)


def nearest_faces(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                  exclude: np.ndarray | None = None, candidates: int = 8, prune: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """For each point the index of the closest triangle and the distance to it.

    points: (N, 3); vertices: (V, 3); faces: (F, 3) int; exclude: optional (F,) bool mask of
    triangles never to return (e.g. degenerate ones). Returns face ids (N,) int64 and
    distances (N,) float64. Ties (a point equally far from two triangles, e.g. over a shared
    edge) go to the triangle whose centroid is nearer among the first `candidates`, to the lower
    index beyond them. prune=False tests every candidate exactly (the reference: same answer,
    bit for bit, slower).
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
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    # a degenerate triangle has no plane: its plane bound is 0 (the sphere bound still holds)
    normal = np.where(length > 1e-30, normal / np.maximum(length, 1e-300), 0.0)   # (Fa, 3)
    tree = cKDTree(centroids)
    k = int(min(max(candidates, 1), len(allowed)))

    ids = np.empty(len(p), np.int64)
    dist = np.empty(len(p), np.float64)
    classes = None
    for start in range(0, len(p), CHUNK):
        chunk = p[start:start + CHUNK]
        cd, ci = tree.query(chunk, k=k)
        cd = cd.reshape(len(chunk), k)
        ci = ci.reshape(len(chunk), k)
        if prune:
            d = _pruned_candidates(chunk, ci, tri, centroids, radius, normal)
        else:
            d = point_triangle_distance(np.repeat(chunk, k, axis=0), tri[ci.ravel()]).reshape(len(chunk), k)
        best = np.argmin(d, axis=1)    # the first minimum: the nearer centroid wins a tie
        rows = np.arange(len(chunk))
        bid, bd = ci[rows, best], d[rows, best]
        if k < len(allowed):
            # Triangles outside the k nearest centroids are at least cd[:, -1] - r_max away.
            unsure = np.flatnonzero(bd > cd[:, -1] - r_max)
            if len(unsure) and prune:
                classes = classes or _SizeClasses(centroids, radius)
                bid[unsure], bd[unsure] = _pruned_near(chunk[unsure], bd[unsure], classes, tri,
                                                       centroids, radius, normal)
            elif len(unsure):
                bid[unsure], bd[unsure] = _exhaustive_near(chunk[unsure], bd[unsure] + r_max, tree, tri)
        ids[start:start + len(chunk)] = allowed[bid]
        dist[start:start + len(chunk)] = bd
    return ids, dist


def _lower_bound(pts: np.ndarray, cand: np.ndarray, centroids: np.ndarray, radius: np.ndarray,
                 normal: np.ndarray) -> np.ndarray:
    """A lower bound (M,) of the distance from each point (M, 3) to triangle cand (M,): the
    larger of the centroid sphere's (|p - c| - r) and the distance to the triangle's plane."""
    offset = pts - centroids[cand]
    sphere = np.linalg.norm(offset, axis=1) - radius[cand]
    return np.maximum(sphere, np.abs(np.einsum("ij,ij->i", offset, normal[cand])))


def _slack(distance: np.ndarray) -> np.ndarray:
    """What a bound may exceed a distance by through rounding alone (both are float64)."""
    return 1e-9 * (1.0 + np.abs(distance))


def _bounded_search(pts: np.ndarray, owner: np.ndarray, tri_of_pair: np.ndarray, bound: np.ndarray,
                    tri: np.ndarray, best: np.ndarray) -> np.ndarray:
    """Exact distances (K,) of the (point, triangle) pairs (owner (K,) into pts (M, 3),
    tri_of_pair (K,) into tri) that can be a point's nearest, +inf for the others.

    Each point's pairs are tested in order of their lower bound (K,), and a point stops at the
    first pair whose bound exceeds the best distance found so far (best (M,): a distance each
    point already reaches, +inf if none): that pair and the rest are farther than the nearest,
    never tied with it, so an argmin over the result is the argmin over all pairs."""
    m = len(pts)
    order = np.lexsort((bound, owner))
    start = np.searchsorted(owner[order], np.arange(m))
    count = np.diff(np.append(start, len(order)))
    best = np.array(best, np.float64)
    out = np.full(len(order), np.inf)
    active = np.flatnonzero(count > 0)
    rank = 0
    while len(active):
        pair = order[start[active] + rank]
        alive = bound[pair] <= best[active] + _slack(best[active])
        active, pair = active[alive], pair[alive]
        out[pair] = point_triangle_distance(pts[active], tri[tri_of_pair[pair]])
        best[active] = np.minimum(best[active], out[pair])
        rank += 1
        active = active[count[active] > rank]
    return out


def _pruned_candidates(pts: np.ndarray, ci: np.ndarray, tri: np.ndarray,
                       centroids: np.ndarray, radius: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(M, k) distances from each point (M, 3) to its k candidate triangles ci (M, k), exact
    where the triangle can be the nearest and +inf where it cannot (`_bounded_search`): argmin
    along the rows is the one of the exact distances."""
    m, k = ci.shape
    owner = np.repeat(np.arange(m), k)
    bound = _lower_bound(pts[owner], ci.ravel(), centroids, radius, normal)
    return _bounded_search(pts, owner, ci.ravel(), bound, tri, np.full(m, np.inf)).reshape(m, k)


class _SizeClasses:
    """The triangles split by their radius (r_max / 4, / 2, all), a centroid KD-tree each: a
    triangle within d of a point has its centroid within d + r of it, so each class is searched
    with its own largest r instead of the mesh's (a few big triangles no longer widen every
    search)."""

    def __init__(self, centroids: np.ndarray, radius: np.ndarray):
        r_max = float(radius.max())
        self.parts = []
        lower = -np.inf
        for upper in (r_max / 4, r_max / 2, np.inf):
            members = np.flatnonzero((radius > lower) & (radius <= upper))
            lower = upper
            if len(members):
                self.parts.append((cKDTree(centroids[members]), members, float(radius[members].max())))

    def within(self, pts: np.ndarray, best: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(owner, triangle) pairs: every triangle of each point (M, 3) whose centroid lies
        within best (M,) + its class's largest radius (+ rounding slack)."""
        owners, cands = [], []
        for tree, members, r in self.parts:
            reach = best + r + _slack(best + r)
            n = len(members)
            k = min(WIDE, n)
            cd, ci = tree.query(pts, k=k)
            cd, ci = cd.reshape(len(pts), k), ci.reshape(len(pts), k)
            inside = cd <= reach[:, None]
            owner, cand = np.nonzero(inside)[0], ci[inside]
            if k < n:
                # points whose ball holds more than k centroids: take their whole ball instead
                full = np.flatnonzero(inside[:, -1])
                if len(full):
                    lists = tree.query_ball_point(pts[full], reach[full])
                    counts = np.fromiter((len(x) for x in lists), np.int64, len(lists))
                    keep = ~np.isin(owner, full)
                    owner = np.concatenate([owner[keep], np.repeat(full, counts)])
                    cand = np.concatenate([cand[keep], np.fromiter((j for x in lists for j in x), np.int64,
                                                                   int(counts.sum()))])
            owners.append(owner)
            cands.append(members[cand])
        return np.concatenate(owners), np.concatenate(cands)


def _pruned_near(pts: np.ndarray, best: np.ndarray, classes: _SizeClasses, tri: np.ndarray,
                 centroids: np.ndarray, radius: np.ndarray, normal: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """`_exhaustive_near(pts, best + r_max, tree, tri)`'s answer, testing only the triangles
    that can beat `best`. pts (M, 3); best (M,): a distance each point already reaches;
    centroids, normal (Fa, 3) and radius (Fa,) of the triangles tri (Fa, 3, 3)."""
    owner, cand = classes.within(pts, best)
    # a triangle at distance d has both bounds <= d: the others cannot be nearer than best
    bound = _lower_bound(pts[owner], cand, centroids, radius, normal)
    keep = bound <= best[owner] + _slack(best[owner])
    owner, cand, bound = owner[keep], cand[keep], bound[keep]
    d = _bounded_search(pts, owner, cand, bound, tri, best)
    order = np.lexsort((cand, d, owner))     # by point, then distance, then triangle index
    first = np.searchsorted(owner[order], np.arange(len(pts)))
    pick = order[first]
    return cand[pick], d[pick]


def _exhaustive_near(pts: np.ndarray, reach: np.ndarray, tree: cKDTree, tri: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Test every triangle whose centroid lies within `reach` (M,) of each point (M, 3) (the
    reference of `_pruned_near`; ties go to the lower triangle index)."""
    lists = tree.query_ball_point(pts, reach)
    counts = np.fromiter((len(x) for x in lists), np.int64, len(lists))
    cand = np.fromiter((j for x in lists for j in x), np.int64, int(counts.sum()))
    owner = np.repeat(np.arange(len(pts)), counts)
    d = point_triangle_distance(pts[owner], tri[cand])
    order = np.lexsort((d, owner))           # by point, then by distance
    first = np.searchsorted(owner[order], np.arange(len(pts)))
    pick = order[first]
    return cand[pick], d[pick]
