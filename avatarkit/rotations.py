"""Rotation helpers shared by every layer. Quaternions are (w, x, y, z), unit length.

All functions are vectorised over leading axes. The quaternion helpers (`quat_normalize`,
`quat_multiply`, `quat_to_matrix`) compute in the input's dtype and return it; the conversions
that need the precision (`matrix_to_quat`, `axis_angle_to_matrix`, `matrix_to_axis_angle`)
compute in float64 and *return float64* whatever they are given: callers that store float32
cast.
"""
from __future__ import annotations

import numpy as np


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """q: (..., 4) -> unit quaternions with w >= 0 (a canonical sign)."""
    q = np.asarray(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    out = q / np.where(n > 0, n, 1)
    return np.where(out[..., :1] < 0, -out, out)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b for (..., 4) wxyz arrays (broadcasting)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """q: (..., 4) wxyz (normalised here) -> rotation matrices (..., 3, 3)."""
    q = np.asarray(q)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4) wxyz, w >= 0.

    Shepperd's method: pick the largest of (trace, diagonal) to divide by, so it is stable for
    every rotation, 180-degree turns included.
    """
    m = np.asarray(m, dtype=np.float64)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    t = np.trace(m, axis1=1, axis2=2)
    d = np.stack([t, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    k = np.argmax(d, axis=1)
    q = np.empty((len(m), 4))
    for case in range(4):
        s = k == case
        if not s.any():
            continue
        mm = m[s]
        if case == 0:
            r = np.sqrt(1.0 + t[s]) * 2
            q[s] = np.stack([0.25 * r, (mm[:, 2, 1] - mm[:, 1, 2]) / r,
                             (mm[:, 0, 2] - mm[:, 2, 0]) / r, (mm[:, 1, 0] - mm[:, 0, 1]) / r], 1)
        elif case == 1:
            r = np.sqrt(1.0 + mm[:, 0, 0] - mm[:, 1, 1] - mm[:, 2, 2]) * 2
            q[s] = np.stack([(mm[:, 2, 1] - mm[:, 1, 2]) / r, 0.25 * r,
                             (mm[:, 0, 1] + mm[:, 1, 0]) / r, (mm[:, 0, 2] + mm[:, 2, 0]) / r], 1)
        elif case == 2:
            r = np.sqrt(1.0 + mm[:, 1, 1] - mm[:, 0, 0] - mm[:, 2, 2]) * 2
            q[s] = np.stack([(mm[:, 0, 2] - mm[:, 2, 0]) / r, (mm[:, 0, 1] + mm[:, 1, 0]) / r,
                             0.25 * r, (mm[:, 1, 2] + mm[:, 2, 1]) / r], 1)
        else:
            r = np.sqrt(1.0 + mm[:, 2, 2] - mm[:, 0, 0] - mm[:, 1, 1]) * 2
            q[s] = np.stack([(mm[:, 1, 0] - mm[:, 0, 1]) / r, (mm[:, 0, 2] + mm[:, 2, 0]) / r,
                             (mm[:, 1, 2] + mm[:, 2, 1]) / r, 0.25 * r], 1)
    return quat_normalize(q).reshape(shape + (4,))


def shortest_arc(a: np.ndarray, b: np.ndarray, perp: np.ndarray | None = None) -> np.ndarray:
    """(N, 4) unit wxyz quaternions: the smallest rotation taking unit vectors a (N, 3) onto unit
    vectors b (N, 3). For b opposite a (w below 1e-6) the half turn about `perp` (N, 3), a unit
    vector normal to a, when given."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    q = np.concatenate([(1.0 + np.einsum("ij,ij->i", a, b))[:, None], np.cross(a, b)], axis=1)
    if perp is not None:
        flip = q[:, 0] < 1e-6
        q[flip] = np.concatenate([np.zeros((flip.sum(), 1)), np.asarray(perp, np.float64)[flip]], axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> cross-product matrices (..., 3, 3): _skew(a) @ b == cross(a, b)."""
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(v.shape[:-1] + (3, 3))


def axis_angle_to_matrix(aa: np.ndarray) -> np.ndarray:
    """Rodrigues: axis-angle vectors (..., 3) -> rotation matrices (..., 3, 3). Exact at 0."""
    aa = np.asarray(aa, dtype=np.float64)
    theta = np.linalg.norm(aa, axis=-1)  # (...)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    k = _skew(aa / safe[..., None])  # unit axis (for the rows that use it)
    s, c = np.sin(safe)[..., None, None], np.cos(safe)[..., None, None]
    eye = np.broadcast_to(np.eye(3), k.shape)
    full = eye + s * k + (1 - c) * (k @ k)
    # Near zero use the first-order series I + [aa]x, which is exact to O(theta^2).
    return np.where(small[..., None, None], eye + _skew(aa), full)


def matrix_to_axis_angle(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angle (..., 3), angle in [0, pi]."""
    q = matrix_to_quat(m)
    w = np.clip(q[..., 0], -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s[..., 0], w)[..., None]
    return np.where(s > 1e-12, v / np.where(s > 1e-12, s, 1) * angle, 2 * v)
