"""`HeadSkin`: the posed head's distance for the hair simulation, through inverse skinning of the
rest head's grid (`head.sdf_grid.HeadSDF`): a point is carried back to the rest head by the
skinning of the joints near it (the jaw moves the chin's distance), then looked up in the grid.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.head.sdf_grid import HeadSDF, trilinear

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


__all__ = ["HeadSkin"]
