"""Signed-distance primitives for the procedural template head (Inigo Quilez's formulas).

Every function takes points `p: (N, 3)` and returns distances `(N,)` (negative inside). The
ellipsoid and the tapered capsule are bounds rather than exact distances; that is enough for
marching cubes and for Newton projection onto the zero set, which only need a smooth field
whose gradient does not vanish near the surface.
"""
from __future__ import annotations

import numpy as np


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("ij,ij->i", a, a))


def ellipsoid(p: np.ndarray, centre, radii, rotation: np.ndarray | None = None) -> np.ndarray:
    """Ellipsoid with semi-axes `radii` (3,), optionally turned by `rotation` (3, 3) (local -> world)."""
    q = p - np.asarray(centre, dtype=p.dtype)
    if rotation is not None:
        q = q @ np.asarray(rotation, dtype=p.dtype)  # world -> local: R^T q, row-vector form
    inv = 1.0 / np.asarray(radii, dtype=p.dtype)
    k0 = _norm(q * inv)
    k1 = _norm(q * (inv * inv))
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def sphere(p: np.ndarray, centre, radius: float) -> np.ndarray:
    return _norm(p - np.asarray(centre, dtype=p.dtype)) - radius


def tapered_capsule(p: np.ndarray, a, b, ra: float, rb: float) -> np.ndarray:
    """Segment a-b swept by a sphere whose radius goes linearly from `ra` to `rb`."""
    a = np.asarray(a, dtype=p.dtype)
    ab = np.asarray(b, dtype=p.dtype) - a
    h = np.clip(((p - a) @ ab) / float(ab @ ab), 0.0, 1.0)
    return _norm(p - a - h[:, None] * ab) - (ra + (rb - ra) * h)


def elliptic_cylinder(p: np.ndarray, y0: float, y1: float, rx: float, rz: float,
                      x0: float = 0.0, z0: float = 0.0, lean: float = 0.0, round_r: float = 0.0):
    """Upright cylinder with elliptic cross-section (rx, rz) between heights y0 < y1.

    `lean` shifts the axis along +z per metre of height (a neck leans forward); `round_r`
    rounds the cap edges.
    """
    x = p[:, 0] - x0
    z = p[:, 2] - z0 - lean * (p[:, 1] - y0)
    k = np.sqrt((x / rx) ** 2 + (z / rz) ** 2)
    d_side = (k - 1.0) * min(rx, rz) + round_r
    d_cap = np.maximum(y0 - p[:, 1], p[:, 1] - y1) + round_r
    outside = np.sqrt(np.maximum(d_side, 0) ** 2 + np.maximum(d_cap, 0) ** 2)
    return outside + np.minimum(np.maximum(d_side, d_cap), 0.0) - round_r


def smooth_union(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum: blends the two surfaces over a band of width ~k."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def smooth_subtract(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """`a` minus `b` with a rounded rim. Never smaller than the sharp max(a, -b): the result
    stays outside `b` everywhere, which keeps carved pockets clear of what sits in them."""
    return -smooth_union(-a, b, k)


def rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((np.asarray(x) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


class Csg:
    """A field built by smooth unions and subtractions of primitives, evaluated with culling.

    Each primitive comes with a bounding sphere (centre, radius). Where a point lies farther than
    radius + k + `band` from it, the primitive cannot change the smooth union or subtraction there
    (it is at least k beyond the current value) except far from the surface, so it is skipped:
    values within `band` of the surface and the sign everywhere are exact, which is all marching
    cubes and surface projection need, at a fraction of the cost of evaluating everything.
    """

    def __init__(self, band: float = 0.02):
        self.band = band
        self.ops: list[tuple] = []

    def add(self, fn, centre, radius: float, k: float, subtract: bool = False) -> "Csg":
        self.ops.append((fn, np.asarray(centre, dtype=np.float64), float(radius), float(k), subtract))
        return self

    def __call__(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        d = None
        for fn, c, r, k, subtract in self.ops:
            if d is None:
                d = fn(p)
                continue
            q = p - c
            reach = r + k + self.band
            near = np.flatnonzero(np.einsum("ij,ij->i", q, q) < reach * reach)
            if len(near) == 0:
                continue
            if len(near) == len(p):
                d = smooth_subtract(d, fn(p), k) if subtract else smooth_union(d, fn(p), k)
                continue
            sub = fn(p[near])
            d[near] = smooth_subtract(d[near], sub, k) if subtract else smooth_union(d[near], sub, k)
        return d
