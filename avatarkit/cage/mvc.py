"""Mean value coordinates for closed triangle meshes (Ju, Schaefer & Warren, SIGGRAPH 2005).

For a point x and a closed cage with vertices c_j, the weights w_j(x) sum to 1 and reproduce x
(linear precision): sum_j w_j c_j = x. Moving the cage vertices to c'_j moves x to sum_j w_j c'_j.

Robust cases (the paper's pseudo-code): x on a vertex -> weight 1 there; x on a triangle (or on
an edge) -> the triangle's 2D barycentric coordinates (linear along an edge); x in the plane of a
triangle but outside it -> that triangle contributes nothing. Non-convex cages are fine: weights
may then be negative somewhere but still sum to 1 with linear precision.

Outside points: the formula is defined there too (Ju et al. sec. 3) and keeps linear precision
and the sum to 1, so an outside point still moves with the cage, but its weights are not positive
and it is not guaranteed to stay outside/inside; build cages that contain every point you deform.

`mvc_weights` is the fast path (Taichi on the CPU, parallel over points, float64 inside, float32
out); `mvc_weights_reference` is the slow literal numpy/float64 version tests compare against.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from avatarkit.cage.mesh import mesh_edges
from avatarkit.errors import InputError

#: relative tolerances (see the kernel's docstring): on a vertex, on a triangle, in its plane
EPS_VERTEX = 1e-9
EPS_PLANAR = 1e-12
EPS_PLANE = 1e-10

_LANES = 64       # scratch rows: enough independent work items for any CPU we run on
_CHUNK = 16384    # points per kernel launch (progress is reported between launches)


def _check_inputs(points, cage_vertices, cage_faces):
    try:
        pts = np.ascontiguousarray(points, dtype=np.float64)
        v = np.ascontiguousarray(cage_vertices, dtype=np.float64)
        f = np.asarray(cage_faces)
    except (TypeError, ValueError) as e:
        raise InputError(f"mean value coordinates need numeric arrays: {e}") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must have shape (P, 3), got {pts.shape}")
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise InputError(f"cage vertices must have shape (C, 3) with C >= 4, got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"cage faces must be integer (M, 3) with M >= 4, got {f.dtype} {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(f"cage faces index vertices outside 0..{len(v) - 1}")
    if not (np.isfinite(pts).all() and np.isfinite(v).all()):
        raise InputError("points and cage vertices must be finite")
    return pts, v, np.ascontiguousarray(f, dtype=np.int32)


def mvc_weights(points: np.ndarray, cage_vertices: np.ndarray, cage_faces: np.ndarray, *,
                transposed: bool = False,
                progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Mean value coordinates of points (P, 3) w.r.t. a closed cage -> W (P, C) float32.

    transposed: return W.T as a C-contiguous (C, P) array instead (the layout the per-frame
    product prefers), without a transposed copy. progress(done, total) is called between chunks.
    """
    pts, v, f = _check_inputs(points, cage_vertices, cage_faces)
    from avatarkit.cage import _kernels  # imports Taichi

    edges, face_edges = mesh_edges(f)
    n_p, n_v = len(pts), len(v)
    out = np.empty((n_v, n_p) if transposed else (n_p, n_v), np.float32)
    if n_p == 0:
        return out
    scale = float(np.linalg.norm(v.max(0) - v.min(0)))
    lanes = min(_LANES, n_p)
    u = np.empty((lanes, n_v, 4))
    theta = np.empty((lanes, len(edges), 5))
    acc = np.empty((lanes, n_v))
    for start in range(0, n_p, _CHUNK):
        count = min(_CHUNK, n_p - start)
        _kernels.mvc(pts, v, f, face_edges, edges, u, theta, acc, out, start, count,
                     int(transposed), EPS_VERTEX * scale, EPS_PLANAR, EPS_PLANE)
        if progress is not None:
            progress(start + count, n_p)
    return out


def mvc_weights_reference(points: np.ndarray, cage_vertices: np.ndarray,
                          cage_faces: np.ndarray, eps: float = 1e-8) -> np.ndarray:
    """The paper's pseudo-code, one point at a time (numpy float64) -> W (P, C).

    Literal except for the edge angle (see below); s_i = sign(det) sqrt(1 - c_i^2) and the
    |s_i| <= eps test are kept as written, which is what makes it an independent check of the
    fast kernel's rearranged formulas.
    """
    pts, v, f = _check_inputs(points, cage_vertices, cage_faces)
    f = f.astype(np.int64)
    scale = float(np.linalg.norm(v.max(0) - v.min(0)))
    out = np.zeros((len(pts), len(v)))
    for p, x in enumerate(pts):
        d = np.linalg.norm(v - x, axis=1)                       # (C,)
        if d.min() < EPS_VERTEX * scale:
            out[p, np.argmin(d)] = 1.0
            continue
        u = (v - x) / d[:, None]                                # (C, 3)
        # theta_i: angle subtended by the edge opposite corner i. The paper's 2 asin(l / 2) is
        # written as 2 atan2(l, |u_a + u_b|), the same angle without asin's lost digits near pi
        # (points on an edge or near one would otherwise miss the on-triangle test below).
        a, b = u[f[:, [1, 2, 0]]], u[f[:, [2, 0, 1]]]             # (M, 3, 3)
        theta = 2 * np.arctan2(np.linalg.norm(a - b, axis=2), np.linalg.norm(a + b, axis=2))
        h = theta.sum(axis=1) / 2
        on_face = np.flatnonzero(np.pi - h < eps)
        if len(on_face):
            t = on_face[0]
            ids = f[t]
            w = np.array([np.sin(theta[t, i]) * d[ids[(i + 2) % 3]] * d[ids[(i + 1) % 3]]
                          for i in range(3)])
            out[p, ids] = w / w.sum()
            continue
        sin_t = np.sin(theta)
        c = np.stack([2 * np.sin(h) * np.sin(h - theta[:, i])
                      / (sin_t[:, (i + 1) % 3] * sin_t[:, (i + 2) % 3]) - 1 for i in range(3)], axis=1)
        det = np.einsum("ij,ij->i", u[f[:, 0]], np.cross(u[f[:, 1]], u[f[:, 2]]))
        s = np.sign(det)[:, None] * np.sqrt(np.clip(1 - c ** 2, 0, None))
        keep = ~(np.abs(s) <= eps).any(axis=1)
        for i in range(3):
            ip, im = (i + 1) % 3, (i + 2) % 3
            w = ((theta[:, i] - c[:, ip] * theta[:, im] - c[:, im] * theta[:, ip])
                 / (d[f[:, i]] * sin_t[:, ip] * s[:, im]))
            np.add.at(out[p], f[keep, i], w[keep])
        out[p] /= out[p].sum()
    return out


# --- sparse top-k ----------------------------------------------------------------------------

def sparsify(weights: np.ndarray, k: int, points: np.ndarray | None = None,
             cage_vertices: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Keep the k largest-magnitude weights of each row -> (indices (P, k) int32, weights (P, k)
    float32).

    By default the kept weights are renormalised to sum to 1, which loses linear precision (MVC
    weights are global: dropping the small ones moves points by millimetres on a hair cage).
    With `points` (P, 3) and the rest `cage_vertices` (C, 3), the kept weights are instead
    corrected by the least-norm change that makes them sum to 1 AND reproduce the points on the
    rest cage, which restores linear precision: exact at rest and under any affine cage motion.
    Measure what remains (non-affine motion) with `sparse_error`.
    """
    w = np.asarray(weights)
    if w.ndim != 2:
        raise InputError(f"weights must be (P, C), got {w.shape}")
    if not 1 <= k <= w.shape[1]:
        raise InputError(f"k must lie in 1..{w.shape[1]}, got {k}")
    if k < w.shape[1]:
        idx = np.argpartition(-np.abs(w), k - 1, axis=1)[:, :k]
    else:
        idx = np.broadcast_to(np.arange(w.shape[1]), w.shape).copy()
    kept = np.take_along_axis(w, idx, axis=1).astype(np.float64)
    if (points is None) != (cage_vertices is None):
        raise InputError("give both points and cage_vertices for linear precision, or neither")
    if points is None:
        total = kept.sum(axis=1, keepdims=True)
        kept = kept / np.where(np.abs(total) > 1e-12, total, 1.0)
        return idx.astype(np.int32), kept.astype(np.float32)
    pts = np.asarray(points, np.float64)
    v = np.asarray(cage_vertices, np.float64)
    if pts.shape != (len(w), 3) or v.shape != (w.shape[1], 3):
        raise InputError(f"points must be ({len(w)}, 3) and cage_vertices ({w.shape[1]}, 3)")
    if k < 4:
        raise InputError("linear precision needs k >= 4")
    # constraints A w = b per point: A = [1 ... 1; c_j^T] (4, k), b = [1; x]
    a = np.concatenate([np.ones((len(w), 1, k)), np.swapaxes(v[idx], 1, 2)], axis=1)  # (P, 4, k)
    b = np.concatenate([np.ones((len(w), 1)), pts], axis=1)                             # (P, 4)
    r = b - np.einsum("pck,pk->pc", a, kept)
    gram = a @ np.swapaxes(a, 1, 2) + 1e-18 * np.eye(4)                                 # (P, 4, 4)
    lam = np.linalg.solve(gram, r[..., None])[..., 0]
    kept = kept + np.einsum("pck,pc->pk", a, lam)
    return idx.astype(np.int32), kept.astype(np.float32)


def sparse_apply(indices: np.ndarray, weights: np.ndarray, cage_vertices: np.ndarray) -> np.ndarray:
    """sum_k weights[p, k] * cage_vertices[indices[p, k]] -> (P, 3) float32."""
    v = np.asarray(cage_vertices, np.float32)
    return np.einsum("pk,pkc->pc", weights, v[indices]).astype(np.float32)


@dataclass(frozen=True)
class SparseError:
    """Position error of top-k weights on the rest cage (same units as the cage)."""

    k: int
    max_error: float
    mean_error: float


def sparse_error(indices: np.ndarray, weights: np.ndarray, cage_vertices: np.ndarray,
                 points: np.ndarray) -> SparseError:
    """Max and mean distance between the sparse result on `cage_vertices` (C, 3) and `points`
    (P, 3): the points themselves for the rest cage, or the dense result W @ V' for a deformed
    cage V'."""
    approx = sparse_apply(indices, weights, cage_vertices).astype(np.float64)
    err = np.linalg.norm(approx - np.asarray(points, np.float64), axis=1)
    return SparseError(int(indices.shape[1]), float(err.max(initial=0.0)), float(err.mean()) if len(err) else 0.0)
