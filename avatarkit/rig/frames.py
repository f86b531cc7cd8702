"""Per-triangle frames that Gaussians ride on (GaussianAvatars, Qian et al. 2024).

For triangle (v0, v1, v2), as GaussianAvatars' `compute_face_orientation` computes them:

    origin   t  = (v0 + v1 + v2) / 3                       (the centroid)
    e0          = unit(v1 - v0)
    n           = unit(e0 x (v2 - v0))                      (the face normal, CCW winding)
    b           = -unit(n x e0)   (= e0 x n)
    rotation R  = [e0 | n | b]    (columns)
    scale    k  = (|v1 - v0| + |b . (v2 - v0)|) / 2

`|b . (v2 - v0)|` is the distance of v2 from the line through v0 and v1 (the triangle's height
over edge v0v1), so k is the mean of that edge's length and the height, as DESIGN.md says.
R is a proper rotation (det +1): n x (e0 x n) = e0. Note that b points *away* from v2 (for
e0 = +x, v2 - v0 = +y: n = +z and b = -y); GaussianAvatars negates n x e0 to make the frame
right-handed ("will have artifacts without negation").

A Gaussian with local values (mu', q', s') on that triangle has world values
mu = k R mu' + t, q = q_R * q', s = k s'.
"""
from __future__ import annotations

import numpy as np

from avatarkit.errors import InputError

#: a triangle whose v0v1 edge is shorter than this (metres) has no direction
MIN_EDGE = 1e-12
#: ... or whose height over that edge is below this fraction of the edge has no normal
MIN_RELATIVE_HEIGHT = 1e-9


def _check(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim < 2 or v.shape[-1] != 3:
        raise InputError(f"vertices must have shape (..., V, 3), got {v.shape}")
    if not np.issubdtype(v.dtype, np.number):
        raise InputError(f"vertices must be numeric, got dtype {v.dtype}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"faces must be an integer array of shape (F, 3), got {f.shape} {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= v.shape[-2]):
        raise InputError(f"faces index vertices 0..{int(f.max())} but there are only {v.shape[-2]}")
    return v, f


def triangle_frames(vertices: np.ndarray, faces: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames of every triangle, batched over leading axes of `vertices`.

    vertices: (..., V, 3); faces: (F, 3) int.
    Returns origins (..., F, 3), rotations (..., F, 3, 3) (columns e0, n, b) and scales (..., F),
    computed in float64 and returned in the vertices' float type (float32 for integer input).
    Degenerate triangles (see `degenerate_faces`) get the identity rotation: their frame is
    meaningless, so callers that need one (binding) reject them.
    """
    return frames_and_degenerate(vertices, faces)[:3]


def frames_and_degenerate(vertices: np.ndarray, faces: np.ndarray):
    """`triangle_frames` plus the `degenerate_faces` mask (..., F), computed in one pass."""
    v, f = _check(vertices, faces)
    out_dtype = v.dtype if np.issubdtype(v.dtype, np.floating) else np.float32
    v = v.astype(np.float64, copy=False)
    v0, v1, v2 = v[..., f[:, 0], :], v[..., f[:, 1], :], v[..., f[:, 2], :]
    origins = (v0 + v1 + v2) / 3.0
    rotations, scales, degenerate = _rotations_scales(v0, v1, v2)
    return origins.astype(out_dtype), rotations.astype(out_dtype), scales.astype(out_dtype), degenerate


def _rotations_scales(v0, v1, v2):
    """float64 (..., F, 3) corners -> rotations (..., F, 3, 3), scales (..., F), degenerate (..., F)."""
    d1 = v1 - v0
    d2 = v2 - v0
    len0 = np.linalg.norm(d1, axis=-1)
    e0 = d1 / np.where(len0 > MIN_EDGE, len0, 1.0)[..., None]
    nraw = np.cross(e0, d2)
    height = np.linalg.norm(nraw, axis=-1)  # |e0 x d2| is the height over edge v0v1
    degenerate = (len0 <= MIN_EDGE) | (height <= MIN_RELATIVE_HEIGHT * len0)
    n = nraw / np.where(degenerate, 1.0, height)[..., None]
    b = np.cross(e0, n)  # == -(n x e0); already unit since e0 and n are orthonormal
    rotations = np.stack([e0, n, b], axis=-1)
    rotations = np.where(degenerate[..., None, None], np.eye(3), rotations)
    # GaussianAvatars' height term is |b . d2|; for orthonormal (e0, n, b) that equals |e0 x d2|.
    scales = 0.5 * (len0 + height)
    return rotations, scales, degenerate


def degenerate_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Boolean mask (..., F): triangles with no well-defined frame (zero edge or zero area)."""
    return frames_and_degenerate(vertices, faces)[3]


def points_on_triangles(tri: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One point uniformly by area on each triangle tri (n, 3, 3) -> (n, 3): barycentrics
    (1 - sqrt r1, sqrt r1 (1 - r2), sqrt r1 r2) with r1, r2 drawn from `rng` in that order (every
    sampler of the head's surface draws them so; changing the order changes their avatars)."""
    n = len(tri)
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
    return np.einsum("nk,nkc->nc", bary, tri)
