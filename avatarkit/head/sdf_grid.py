"""`HeadSDF`: a grid signed distance of the rest head (negative inside): what the hair is grown on
(recon), kept out of (assembly, push-out) and collides with (sim).

The grid lives in the rest head's coordinates. At a posed frame whose head-joint skinning
transform is T (rest -> posed, 4x4), a world point x is looked up at T^-1 x and the gradient is
rotated back by T's rotation, so one grid serves every pose of the rigid skull.

Values are built from dense, deterministic surface samples: the distance to the nearest sample,
signed by that sample's face normal; within a few sample spacings of the surface the distance to
the sample's face plane is used instead, which is exact on flat parts and removes the sampling
bias where it matters (the zero crossing). The sign from the nearest face normal is the usual
pseudo-normal test; it needs no watertight mesh (FLAME has eye and neck holes), and it is right
everywhere near a head-like surface. Gradients are central differences of the grid, normalised,
and interpolated trilinearly like the values, so normals vary smoothly across cells.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from avatarkit.errors import InputError

#: half-width, in grid nodes, of the band around the surface whose values are computed directly
_BAND = 4
#: unit (metres) of `HeadSDF.cell_floor`: 0.1 mm steps up to 25.5 mm in one byte
CELL_STEP = 0.0001


def _cell_corners(grid: np.ndarray) -> list[np.ndarray]:
    """The 8 corner values of every cell of a node grid (nx, ny, nz): views of shape
    (nx - 1, ny - 1, nz - 1)."""
    return [grid[dx:grid.shape[0] - 1 + dx, dy:grid.shape[1] - 1 + dy, dz:grid.shape[2] - 1 + dz]
            for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]


def trilinear(grid: np.ndarray, uc: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of grid (nx, ny, nz, C) at grid coordinates uc (P, 3), already
    clamped to [0, n - 1] -> (P, C) float64 (the numpy twin of `_kernels.trilinear`)."""
    n = np.asarray(grid.shape[:3])
    i0 = np.minimum(np.floor(uc).astype(np.int64), n - 2)
    t = uc - i0
    out = np.zeros((len(uc), grid.shape[3]))
    for dx in (0, 1):
        wx = t[:, 0] if dx else 1 - t[:, 0]
        for dy in (0, 1):
            wy = t[:, 1] if dy else 1 - t[:, 1]
            for dz in (0, 1):
                wz = t[:, 2] if dz else 1 - t[:, 2]
                out += (wx * wy * wz)[:, None] * grid[i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz]
    return out


@dataclass(eq=False)
class HeadSDF:
    """values_grad: (nx, ny, nz, 4) float32, [..., 0] signed distance (m), [..., 1:] unit gradient.
    origin: (3,) the position of grid node (0, 0, 0); spacing: node distance in metres.
    from_values: the gradients are central differences of the float32 distances themselves (what
    a rig file's load rebuilds, `hair_rig.sdf_from_values`), not of the float64 ones `build` had."""

    values_grad: np.ndarray
    origin: np.ndarray
    spacing: float
    from_values: bool = False

    def __post_init__(self):
        self.values_grad = np.ascontiguousarray(self.values_grad, dtype=np.float32)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if self.values_grad.ndim != 4 or self.values_grad.shape[3] != 4 or min(self.values_grad.shape[:3]) < 2:
            raise InputError(f"SDF grid must have shape (nx, ny, nz, 4) with n >= 2, "
                             f"got {self.values_grad.shape}")
        if not (np.isfinite(self.spacing) and self.spacing > 0):
            raise InputError(f"SDF spacing must be > 0, got {self.spacing}")
        self.spacing = float(self.spacing)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.values_grad.shape[:3])

    @functools.cached_property
    def cell_floor(self) -> np.ndarray:
        """(nx - 1, ny - 1, nz - 1) uint8: per grid cell, the smallest of its 8 corner values in
        units of CELL_STEP, rounded down (0 for anything below one step, 255 from 25.5 mm). A
        trilinear lookup in the cell is a convex blend of the corners, and `query` only adds
        to it, so code * CELL_STEP is a lower bound of every value in the cell (up to float32
        rounding of the blend, ~1e-7 m): one byte read tells a point far from the head (2 MB
        for the 32 MB grid)."""
        low = np.min(np.stack(_cell_corners(self.values_grad[..., 0])), axis=0).astype(np.float64)
        return np.clip(np.floor(low / CELL_STEP - 1e-6), 0, 255).astype(np.uint8)

    @classmethod
    def build(cls, vertices: np.ndarray, faces: np.ndarray, spacing: float = 0.0025,
              margin: float = 0.04) -> "HeadSDF":
        """Grid SDF of the mesh (vertices (V,3), faces (F,3)) over its bounding box + margin."""
        value, lo = distance_grid(vertices, faces, spacing, margin)
        grad = np.stack(np.gradient(value, spacing), axis=-1)
        grad /= np.maximum(np.linalg.norm(grad, axis=-1, keepdims=True), 1e-12)
        return cls(np.concatenate([value[..., None], grad], axis=-1), lo, spacing)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """points: (P, 3) in the rest head frame -> (distance (P,), unit gradient (P, 3)), float64.

        Outside the grid the value at the nearest grid point plus the distance to the grid box
        (an upper bound that keeps growing away from the head)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = np.asarray(self.shape)
        u = (p - self.origin) / self.spacing
        uc = np.clip(u, 0.0, n - 1)
        outside = np.linalg.norm(u - uc, axis=1) * self.spacing
        out = trilinear(self.values_grad, uc)
        grad = out[:, 1:] / np.maximum(np.linalg.norm(out[:, 1:], axis=1, keepdims=True), 1e-12)
        return out[:, 0] + outside, grad

    def query_posed(self, points: np.ndarray, transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (P, 3) against the head posed by `transform` (4, 4), rest -> posed."""
        t = np.asarray(transform, dtype=np.float64)
        r, trans = t[:3, :3], t[:3, 3]
        local = (np.asarray(points, dtype=np.float64) - trans) @ r  # r^-1 = r^T for rigid
        d, g = self.query(local)
        return d, g @ r.T


def distance_grid(vertices: np.ndarray, faces: np.ndarray, spacing: float = 0.0025,
                  margin: float = 0.04) -> tuple[np.ndarray, np.ndarray]:
    """The signed distances of `HeadSDF.build` without its gradients: (values (nx, ny, nz)
    float64, origin (3,)) over the mesh's bounding box + margin (module docstring)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise InputError(f"head vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
        raise InputError(f"head faces must be (F, 3) indices into {len(v)} vertices")
    if not (spacing > 0 and margin >= 0):
        raise InputError("SDF spacing must be > 0 and margin >= 0")
    lo = v.min(axis=0) - margin
    dims = np.ceil((v.max(axis=0) + margin - lo) / spacing).astype(int) + 1
    samples, normals = _surface_samples(v, f, spacing / 2)
    # Exact-ish values only in a band of nodes around the surface (a kd-tree query far from
    # a round surface degenerates: every sample is almost equally near); elsewhere the
    # distance to the nearest band node is added to that node's value (Euclidean transform).
    occupied = np.zeros(dims, bool)
    cell = np.clip(np.rint((samples - lo) / spacing).astype(np.int64), 0, dims - 1)
    occupied[cell[:, 0], cell[:, 1], cell[:, 2]] = True
    band = ndimage.binary_dilation(occupied, np.ones((3, 3, 3), bool), iterations=_BAND)
    band_idx = np.argwhere(band)
    nodes = lo + spacing * band_idx
    dist, idx = cKDTree(samples).query(nodes, workers=-1)
    offset = nodes - samples[idx]
    plane = np.einsum("ij,ij->i", offset, normals[idx])
    value = np.zeros(dims)
    value[band] = np.where(dist < 3 * spacing, plane, np.copysign(dist, plane))
    far, nearest = ndimage.distance_transform_edt(~band, sampling=spacing, return_indices=True)
    near_value = value[nearest[0], nearest[1], nearest[2]]
    return np.where(band, value, np.copysign(np.abs(near_value) + far, near_value)), lo


def _surface_samples(v: np.ndarray, f: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on every face on a barycentric lattice finer than `step`, with the face normals.
    Deterministic (no random sampling) so the same mesh always gives the same grid."""
    tri = v[f]                                                        # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    # degenerate faces have no normal and no area: leave them out
    norm = np.linalg.norm(n, axis=1)
    keep = norm > 1e-14
    tri, n = tri[keep], n[keep] / norm[keep, None]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    divisions = np.maximum(1, np.ceil(longest / step)).astype(int)
    points, normals = [], []
    for d in np.unique(divisions):
        sel = divisions == d
        i, j = np.meshgrid(np.arange(d + 1), np.arange(d + 1), indexing="ij")
        ok = i + j <= d
        bary = np.stack([i[ok], j[ok], d - i[ok] - j[ok]], axis=1) / d  # (L, 3)
        pts = np.einsum("lk,fkc->flc", bary, tri[sel])
        points.append(pts.reshape(-1, 3))
        normals.append(np.repeat(n[sel], len(bary), axis=0))
    return np.concatenate(points), np.concatenate(normals)


__all__ = ["CELL_STEP", "HeadSDF", "distance_grid", "trilinear"]
