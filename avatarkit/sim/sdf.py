"""`HeadSDF`: a grid signed distance of the rest head (negative inside) for collision queries.

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
    origin: (3,) the position of grid node (0, 0, 0); spacing: node distance in metres."""

    values_grad: np.ndarray
    origin: np.ndarray
    spacing: float

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
        value = np.where(band, value, np.copysign(np.abs(near_value) + far, near_value))
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


@dataclass(eq=False)
class HeadSkin:
    """The head's skinning weights as a field over space, so the rest SDF can follow an LBS head
    (jaw, neck) and not only the rigid skull.

    weights: (nx, ny, nz, JMAX) float32 on a coarse grid: at each node, the weights of `joints`
    of the rest head vertex nearest to it (weights of other joints are added to slot 0);
    joints: (J,) the head model's joint ids, joints[0] the head joint (J <= JMAX);
    origin (3,), spacing: the grid. A posed world point x is taken to the rest frame by the head
    joint, x0 = T_0^-1 x; if the field there is not all head joint, by the inverse of the blend,
    x_rest = (sum_j w_j(x0) T_j)^-1 x (inverse LBS with the weights of the nearest region).
    """

    weights: np.ndarray
    joints: np.ndarray
    origin: np.ndarray
    spacing: float

    #: slots in `weights` (the kernel's vec4)
    JMAX = 4

    def __post_init__(self):
        self.weights = np.ascontiguousarray(self.weights, dtype=np.float32)
        self.joints = np.asarray(self.joints, dtype=np.int64).reshape(-1)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if self.weights.ndim != 4 or self.weights.shape[3] != self.JMAX or min(self.weights.shape[:3]) < 2:
            raise InputError(f"skin weights must have shape (nx, ny, nz, {self.JMAX}), got {self.weights.shape}")
        if not 1 <= len(self.joints) <= self.JMAX:
            raise InputError(f"a head skin needs 1 to {self.JMAX} joints, got {len(self.joints)}")
        self.spacing = float(self.spacing)

    @classmethod
    def rigid(cls, head_joint: int = 0) -> "HeadSkin":
        """The whole head on one joint (the rigid skull of a head without skinning)."""
        w = np.zeros((2, 2, 2, cls.JMAX), np.float32)
        w[..., 0] = 1.0
        return cls(w, [head_joint], np.zeros(3), 1.0)

    @classmethod
    def build(cls, rest_vertices: np.ndarray, skin_weights: np.ndarray, head_joint: int,
              joints=None, sdf: "HeadSDF | None" = None, spacing: float = 0.01,
              margin: float = 0.06) -> "HeadSkin":
        """rest_vertices (V, 3), skin_weights (V, J) of the head model; joints: the joints to
        follow besides head_joint (default: the up to 3 others with the most weight); the grid
        covers the SDF's box (or the head's box + margin) at `spacing`."""
        from scipy.spatial import cKDTree

        v = np.asarray(rest_vertices, dtype=np.float64)
        w = np.asarray(skin_weights, dtype=np.float64)
        if w.ndim != 2 or len(w) != len(v):
            raise InputError(f"skin weights must have shape ({len(v)}, J), got {w.shape}")
        if joints is None:
            total = w.sum(axis=0)
            total[head_joint] = -1
            if w.shape[1] == 5:  # FLAME: the eyeballs sit inside their sockets, out of reach
                total[3:] = -1
            joints = [j for j in np.argsort(-total, kind="stable")[:cls.JMAX - 1] if total[j] > 0]
        joints = [int(head_joint)] + [int(j) for j in joints if int(j) != head_joint]
        if sdf is not None:
            lo = sdf.origin
            hi = sdf.origin + sdf.spacing * (np.asarray(sdf.shape) - 1)
        else:
            lo, hi = v.min(axis=0) - margin, v.max(axis=0) + margin
        dims = np.maximum(2, np.ceil((hi - lo) / spacing).astype(int) + 1)
        axes = [lo[k] + spacing * np.arange(dims[k]) for k in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        _, nearest = cKDTree(v).query(nodes, workers=-1)
        out = np.zeros((len(nodes), cls.JMAX))
        out[:, :len(joints)] = w[nearest][:, joints]
        out[:, 0] += 1.0 - out.sum(axis=1)  # joints not followed ride the head joint
        return cls(out.reshape(*dims, cls.JMAX), joints, lo, spacing)

    def weights_at(self, points: np.ndarray) -> np.ndarray:
        """Trilinear weights (P, JMAX) at rest-frame points (P, 3), clamped to the grid."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = np.asarray(self.weights.shape[:3])
        uc = np.clip((p - self.origin) / self.spacing, 0.0, n - 1)
        return trilinear(self.weights, uc)

    def to_rest(self, points: np.ndarray, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (P, 3) with the joints' transforms (J, 4, 4) (rest -> posed, this skin's
        joints in order) -> rest-frame points (P, 3) and the linear part (P, 3, 3) of each point's
        blended transform (the head joint's rotation where the field is all head joint)."""
        from avatarkit.sim._skin_math import RIGID_WEIGHT

        t = np.asarray(transforms, dtype=np.float64)
        x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        q = (x - t[0, :3, 3]) @ t[0, :3, :3]
        lin = np.broadcast_to(t[0, :3, :3], (len(x), 3, 3)).copy()
        if len(self.joints) > 1 and len(x):
            w = self.weights_at(q)
            blend = w[:, 0] < RIGID_WEIGHT
            if blend.any():
                wb = w[blend, :len(self.joints)]
                a = np.einsum("pj,jab->pab", wb, t[:len(self.joints), :3, :3])
                b = np.einsum("pj,ja->pa", wb, t[:len(self.joints), :3, 3])
                q[blend] = np.linalg.solve(a, (x[blend] - b)[..., None])[..., 0]
                lin[blend] = a
        return q, lin

    def query_posed(self, sdf: HeadSDF, points: np.ndarray, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (P, 3) against the posed head (this skin's joints' transforms (J, 4, 4)):
        distance (P,) and unit world normal (P, 3). The posed head is the union of its skinned
        pieces: the rest SDF at `to_rest`'s point and, for every other joint j, at T_j^-1 x where
        that point lies in j's region (weight > 1/2); the smallest distance wins (a point the
        jaw swung onto is inside the jaw whatever the skull's preimage of it is)."""
        t = np.asarray(transforms, dtype=np.float64)
        x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        q, lin = self.to_rest(x, t)
        d, g = sdf.query(q)
        n = np.linalg.solve(np.transpose(lin, (0, 2, 1)), g[..., None])[..., 0]
        for j in range(1, min(len(self.joints), len(t))):
            qj = (x - t[j, :3, 3]) @ t[j, :3, :3]
            mine = self.weights_at(qj)[:, j] > 0.5
            if mine.any():
                dj, gj = sdf.query(qj[mine])
                closer = dj < d[mine]
                idx = np.flatnonzero(mine)[closer]
                d[idx] = dj[closer]
                n[idx] = gj[closer] @ t[j, :3, :3].T
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return d, n
