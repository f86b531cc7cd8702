"""Harmonic (membrane) filling of image regions: the smooth fill behind the bald filter.

Inside `region` each pixel becomes the mean of its 4 neighbours (the discrete Laplace equation);
neighbours in `known` are fixed values (Dirichlet), neighbours in neither set are ignored (a
no-flux, Neumann border), so e.g. a background fill never pulls colour from the face.
`harmonic_fill` solves the sparse system directly (exact; cost grows quickly with the region);
`harmonic_fill_fast` solves a downscaled copy and then only a thin band along the region's
border at full resolution, with the upsampled coarse solution fixed inside the band.
"""
from __future__ import annotations

import math

import numpy as np

from avatarkit.errors import InputError


def _check(values, region, known):
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 2:
        values = values[:, :, None]
    region = np.asarray(region, dtype=bool)
    known = np.asarray(known, dtype=bool) & ~region
    if values.shape[:2] != region.shape or region.shape != known.shape:
        raise InputError(f"values {values.shape[:2]}, region {region.shape} and known {known.shape} "
                         f"must have the same height and width")
    return values, region, known


def _unreachable(region: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Region pixels whose 4-connected component touches no known pixel (nothing to solve from)."""
    from scipy import ndimage

    lab, n = ndimage.label(region)
    if n == 0:
        return np.zeros_like(region)
    near_known = ndimage.binary_dilation(known) & region
    ok = np.zeros(n + 1, bool)
    ok[np.unique(lab[near_known])] = True
    ok[0] = True
    return ~ok[lab]


def harmonic_fill(values: np.ndarray, region: np.ndarray, known: np.ndarray,
                  fallback: np.ndarray | None = None) -> np.ndarray:
    """Solve the discrete Laplace equation inside `region` exactly (sparse LU).

    values: (H, W, C) or (H, W); only its `known` pixels are read.
    region, known: (H, W) bool; pixels in both count as region.
    fallback: (C,) value for region components with no known neighbour (default: zeros).
    Returns (H, W, C) float64: `values` outside the region, the harmonic fill inside.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    values, region, known = _check(values, region, known)
    out = values.copy()
    if not region.any():
        return out
    lost = _unreachable(region, known)
    if lost.any():
        out[lost] = 0.0 if fallback is None else np.asarray(fallback, dtype=np.float64)
        region = region & ~lost
        if not region.any():
            return out
    H, W, C = values.shape
    idx = np.full((H, W), -1, np.int64)
    ys, xs = np.nonzero(region)
    n = len(ys)
    idx[ys, xs] = np.arange(n)
    diag = np.zeros(n)
    rhs = np.zeros((n, C))
    rows, cols = [], []
    for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        qy, qx = ys + dy, xs + dx
        inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
        p = np.nonzero(inside)[0]
        qy, qx = qy[inside], qx[inside]
        in_region = region[qy, qx]
        in_known = known[qy, qx]
        diag[p[in_region | in_known]] += 1.0
        rows.append(p[in_region])
        cols.append(idx[qy[in_region], qx[in_region]])
        np.add.at(rhs, p[in_known], values[qy[in_known], qx[in_known]])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    a = sp.csc_matrix((np.concatenate([diag, -np.ones(len(r))]),
                       (np.concatenate([np.arange(n), r]), np.concatenate([np.arange(n), c]))), shape=(n, n))
    out[ys, xs] = splu(a).solve(rhs)
    return out


def harmonic_fill_fast(values: np.ndarray, region: np.ndarray, known: np.ndarray,
                       fallback: np.ndarray | None = None, work_size: int = 384) -> np.ndarray:
    """`harmonic_fill` for large images: exact below `work_size` px, else two-level.

    The coarse level solves the problem downscaled so its longer side is `work_size`; the fine
    level re-solves only the region pixels within a few coarse pixels of its border, with the
    upsampled coarse solution as fixed values deeper inside. Harmonic functions are smooth away
    from their boundary, so the interior error is the coarse discretisation error (small).
    """
    import cv2

    values, region, known = _check(values, region, known)
    H, W, C = values.shape
    k = work_size / max(H, W)
    if k >= 1.0 or region.sum() < 4 * work_size:
        return harmonic_fill(values, region, known, fallback)
    size = (max(2, round(W * k)), max(2, round(H * k)))

    def down(a):
        return cv2.resize(a.astype(np.float32), size, interpolation=cv2.INTER_AREA)

    kw = down(known)
    # Masked average: region pixels (e.g. hair colours) must not leak into the coarse knowns.
    vlo = np.stack([down(values[:, :, i] * known) for i in range(C)], axis=2) / np.maximum(kw, 1e-6)[:, :, None]
    rlo = down(region) > 0.5
    klo = (kw > 0.5) & ~rlo
    coarse_lo = harmonic_fill(vlo, rlo, klo, fallback)
    coarse = cv2.resize(coarse_lo.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
    coarse = coarse.reshape(H, W, C).astype(np.float64)

    band = math.ceil(3.0 / k) + 2
    dist = cv2.distanceTransform(region.astype(np.uint8), cv2.DIST_L2, 3)
    interior = region & (dist > band)
    v2 = values.copy()
    v2[interior] = coarse[interior]
    return harmonic_fill(v2, region & ~interior, known | interior, fallback)
