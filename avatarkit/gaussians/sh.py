"""Real spherical harmonics exactly as 3DGS evaluates them (degree 0..3).

Coefficient k of a band is the k-th term of the INRIA `eval_sh` expansion, so arrays we read
from PLY files and colours we render agree with every 3DGS tool.
"""
from __future__ import annotations

import numpy as np

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)

#: number of coefficients per colour channel for SH degree 0..3
SH_COUNTS = (1, 4, 9, 16)


def degree_from_count(k: int) -> int:
    """Coefficients per channel (1, 4, 9, 16) -> SH degree; ValueError otherwise."""
    if k not in SH_COUNTS:
        raise ValueError(f"{k} SH coefficients per channel is not a degree 0..3 layout")
    return SH_COUNTS.index(k)


def rgb_to_dc(rgb: np.ndarray) -> np.ndarray:
    """Colour in [0,1] (..., 3) -> DC coefficient (..., 3)."""
    return (np.asarray(rgb) - 0.5) / SH_C0


def dc_to_rgb(dc: np.ndarray) -> np.ndarray:
    """DC coefficient (..., 3) -> colour (..., 3) (not clamped)."""
    return np.asarray(dc) * SH_C0 + 0.5


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """dirs: (M, 3) unit view directions -> basis values (M, (degree+1)^2), 3DGS sign conventions."""
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    cols = [np.full_like(x, SH_C0)]
    if degree > 0:
        cols += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree > 1:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        cols += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2 * zz - xx - yy),
                 SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree > 2:
        cols += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * xy * z, SH_C3[2] * y * (4 * zz - xx - yy),
                 SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                 SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(cols, axis=1)


def eval_sh(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """sh: (M, K, 3), dirs: (M, 3) unit -> colour (M, 3) = sum_k basis_k * sh_k + 0.5, clamped >= 0."""
    k = sh.shape[1]
    basis = sh_basis(dirs, degree_from_count(k))
    return np.maximum(np.einsum("mk,mkc->mc", basis, sh) + 0.5, 0.0)


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def sh_rotation(rotation: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per-band matrices M_l ((2l+1)x(2l+1)) so that coefficients c' = M_l c rotate the function.

    With f(d) = Y(d) . c, the rotated function is f'(d) = f(R^T d) = Y(R^T d) . c = Y(d) . (M c).
    M_l is the exact least-squares solution on 64 well-spread directions (bands are closed under
    rotation, so the fit is exact up to float64 rounding).
    """
    r = np.asarray(rotation, dtype=np.float64)
    dirs = _fibonacci_sphere(64)
    a = sh_basis(dirs, degree)
    b = sh_basis(dirs @ r, degree)  # rows are (R^T d)^T
    mats = []
    for l in range(1, degree + 1):
        sl = slice(l * l, (l + 1) * (l + 1))
        m, *_ = np.linalg.lstsq(a[:, sl], b[:, sl], rcond=None)
        mats.append(m)  # Y_l(R^T d) = Y_l(d) @ m  ->  c' = m @ c
    return mats


def rotate_sh(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """sh: (N, K, 3) coefficient-major -> coefficients of the same colours under `rotation` (3,3)."""
    k = sh.shape[1]
    degree = degree_from_count(k)
    if degree == 0:
        return sh.copy()
    out = np.array(sh, dtype=np.float64)
    for l, m in enumerate(sh_rotation(rotation, degree), start=1):
        sl = slice(l * l, (l + 1) * (l + 1))
        out[:, sl] = np.einsum("ij,njc->nic", m, out[:, sl])
    return out.astype(sh.dtype)
