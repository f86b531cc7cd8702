"""Rotate spherical-harmonic colour with many different rotations at once.

`gaussians.sh.rotate_sh` rotates a whole set by one matrix; a rigged set needs one rotation per
triangle. The band matrices are found the same way (bands are closed under rotation, so a
least-squares fit on a few well-spread directions is exact to rounding), batched over
rotations, with the pseudo-inverse of the fixed basis computed once.
"""
from __future__ import annotations

import functools

import numpy as np

from avatarkit.gaussians.sh import degree_from_count, sh_basis

_N_DIRS = 16  # >= 2l+1 = 7 for degree 3 (the fit is exact); more only costs time


@functools.lru_cache(maxsize=4)
def _fit(degree: int) -> tuple[np.ndarray, list[np.ndarray]]:
    i = np.arange(_N_DIRS) + 0.5
    phi = np.arccos(1 - 2 * i / _N_DIRS)
    theta = np.pi * (1 + 5 ** 0.5) * i
    dirs = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    a = sh_basis(dirs, degree)
    pinvs = [np.linalg.pinv(a[:, l * l:(l + 1) * (l + 1)]) for l in range(1, degree + 1)]
    return dirs, pinvs


def sh_band_matrices(rotations: np.ndarray, degree: int) -> list[np.ndarray]:
    """rotations (M, 3, 3) -> [M_l (M, 2l+1, 2l+1) for l = 1..degree], c' = M_l c per rotation."""
    r = np.asarray(rotations, dtype=np.float64)
    dirs, pinvs = _fit(degree)
    rotated = dirs @ r  # (M, D, 3): row d of each is (R^T d)^T
    b = sh_basis(rotated.reshape(-1, 3), degree).reshape(len(r), len(dirs), -1)
    return [p @ b[:, :, l * l:(l + 1) * (l + 1)] for l, p in enumerate(pinvs, start=1)]


def rotate_sh_indexed(sh: np.ndarray, rotations: np.ndarray, index: np.ndarray) -> np.ndarray:
    """sh (N, K, 3); rotations (M, 3, 3); index (N,) into rotations -> rotated sh (N, K, 3).

    Gaussian i's colour is rotated by rotations[index[i]]; the DC band never changes.
    """
    sh = np.asarray(sh)
    degree = degree_from_count(sh.shape[1])
    if degree == 0 or len(sh) == 0:
        return sh.copy()
    used, inverse = np.unique(np.asarray(index), return_inverse=True)
    mats = sh_band_matrices(np.asarray(rotations)[used], degree)
    out = np.array(sh, dtype=np.float64)
    for l, m in enumerate(mats, start=1):
        sl = slice(l * l, (l + 1) * (l + 1))
        out[:, sl] = m[inverse] @ out[:, sl]
    return out.astype(sh.dtype)
