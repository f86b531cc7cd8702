"""Distances to a triangle mesh (the head): closest points, angle-weighted pseudo-normals and the
signed distance they give (exact on a closed, consistently oriented mesh). Used by assembly, the
import lifter's alignment and the build's checks.
"""
from __future__ import annotations

import numpy as np


def face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Unit normals (F, 3) of the triangles f (F, 3) of vertices v (V, 3)."""
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)


#: closest_points splits at least this many points between two threads
PARALLEL_POINTS = 4096


def closest_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, threads: int = 2):
    """Nearest head triangle of each point (N, 3): (face ids (N,), barycentric (N, 3),
    closest points (N, 3), distances (N,)).

    Each point's answer depends on that point alone, so `threads` (>= 2, from PARALLEL_POINTS
    points) splits them in halves, one searched on a second thread: numpy's and the kd-tree's
    work is mostly off the GIL, and the answer is bit for bit the one-thread one
    (`threads=1`)."""
    from avatarkit.recon.background import Background

    p = np.asarray(points, np.float64).reshape(-1, 3)
    if threads < 2 or len(p) < PARALLEL_POINTS:
        return _closest_points(p, vertices, faces)
    half = len(p) // 2
    other = Background(_closest_points, p[half:], vertices, faces, name="avatarkit-closest-points")
    first = _closest_points(p[:half], vertices, faces)
    second = other.result()
    return tuple(np.concatenate([a, b]) for a, b in zip(first, second))


def _closest_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray):
    """`closest_points` on one thread."""
    import trimesh

    from avatarkit.rig.frames import degenerate_faces
    from avatarkit.rig.nearest import nearest_faces

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces)
    p = np.asarray(points, np.float64).reshape(-1, 3)
    ids, dist = nearest_faces(p, v, f, exclude=degenerate_faces(v, f), candidates=32)
    tri = v[f[ids]]
    closest = trimesh.triangles.closest_point(tri, p) if len(p) else np.zeros((0, 3))
    bary = trimesh.triangles.points_to_barycentric(tri, closest) if len(p) else np.zeros((0, 3))
    return ids, bary, closest, dist


def pseudo_normals(vertices: np.ndarray, faces: np.ndarray):
    """Angle-weighted pseudo-normals (Baerentzen & Aanaes 2005) of a triangle mesh: unit face
    normals (F, 3), vertex normals (V, 3) (face normals weighted by the corner angle), edge
    normals (E, 3) (sum of the two faces' normals) and, per face, the edge index of its edges
    v0v1, v1v2, v2v0 (F, 3). The side of the closest feature's pseudo-normal is the exact
    inside/outside test on a closed, consistently oriented mesh."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]
    fn = face_normals(v, f)
    vn = np.zeros_like(v)
    for k in range(3):
        a = tri[:, (k + 1) % 3] - tri[:, k]
        b = tri[:, (k + 2) % 3] - tri[:, k]
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30)
        np.add.at(vn, f[:, k], fn * np.arccos(np.clip(cos, -1, 1))[:, None])
    pairs = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, edge_of = np.unique(pairs[:, 0] * len(v) + pairs[:, 1], return_inverse=True)
    edge_of = edge_of.reshape(-1, 3)
    en = np.zeros((int(edge_of.max()) + 1, 3))
    np.add.at(en, edge_of.ravel(), np.repeat(fn, 3, axis=0))
    return fn, vn, en, edge_of


def signed_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                    screen=None, reach: float = 0.008) -> np.ndarray:
    """Signed distance (N,) of points (N, 3) to a head mesh: negative inside.

    Near the surface: the exact point-triangle distance, signed by the closest feature's
    angle-weighted pseudo-normal (exact on a closed mesh such as the template; on FLAME's open
    eye and neck rims the nearest side). screen: optional `HeadSDF` of (about) the same head;
    points it puts farther than `reach` outside keep its (approximate, positive) value and skip
    the exact test."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.zeros(len(p))
    if len(p) == 0:
        return out
    near = np.ones(len(p), bool)
    if screen is not None:
        approx, _ = screen.query(p)
        near = approx < reach
        out[~near] = approx[~near]
    idx = np.flatnonzero(near)
    if len(idx):
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces)
        ids, bary, closest, dist = closest_points(p[idx], v, f)
        inside = inside_by_feature(p[idx], closest, ids, bary, v, f)
        out[idx] = np.where(inside, -dist, dist)
    return out


def feature_normals(ids, bary, vertices, faces) -> np.ndarray:
    """Unit pseudo-normals (N, 3) of the closest features: the face's normal when the closest
    point is inside its triangle, the edge's or the vertex's when it is on one."""
    fn, vn, en, edge_of = pseudo_normals(vertices, faces)
    eps = 1e-7
    bary = np.asarray(bary)
    zero = bary < eps
    nz = zero.sum(axis=1)
    n = fn[ids].copy()
    one = np.flatnonzero(nz == 1)
    if len(one):
        j = np.argmax(zero[one], axis=1)                   # the corner off the edge
        slot = np.array([1, 2, 0])[j]                      # its opposite edge: v1v2, v2v0, v0v1
        n[one] = en[edge_of[ids[one], slot]]
    two = np.flatnonzero(nz >= 2)
    if len(two):
        corner = np.argmax(bary[two], axis=1)
        n[two] = vn[np.asarray(faces)[ids[two], corner]]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)


def inside_by_feature(points, closest, ids, bary, v, f) -> np.ndarray:
    """(N,) bool: points lie behind the pseudo-normal of their closest feature (inside the mesh)."""
    n = feature_normals(ids, bary, v, f)
    return np.einsum("ij,ij->i", points - closest, n) < 0


__all__ = ["closest_points", "face_normals", "feature_normals", "inside_by_feature", "pseudo_normals",
           "signed_distance"]
