"""`TriangleBinding`: Gaussians that ride the triangles of a deforming mesh (GaussianAvatars).

Each Gaussian is stored in the frame of its triangle (`rig.frames`): local mean mu', local
orientation q', local scale s'. With the triangle's frame (t, R, k) in a posed mesh:

    mu = k R mu' + t        q = q_R * q'        s = k s'            (local -> world)
    mu' = R^T (mu - t) / k  q' = q_R^-1 * q     s' = s / k          (world -> local)

View-dependent colour (SH bands >= 1) is stored in the triangle frame too (`sh_frame="local"`)
and turned with the triangle, so a Gaussian keeps its appearance as the head turns.
GaussianAvatars itself never rotates SH (`sh_frame="world"`): use that for sets trained that way.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rig.frames import _check, degenerate_faces, frames_and_degenerate, triangle_frames
from avatarkit.rig.nearest import nearest_faces
from avatarkit.rig.sh_rotation import rotate_sh_indexed
from avatarkit.rotations import matrix_to_quat, quat_multiply

SH_FRAMES = ("local", "world")

#: Gaussians x frames handled per vectorised block in batched `to_world` (bounds memory)
_BLOCK = 1 << 16


def _conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def local_to_world(origins, rotations, scales, face_ids, local_means, local_quats, local_scales):
    """Local Gaussian values -> world, for one or many mesh poses.

    origins (..., F, 3), rotations (..., F, 3, 3), scales (..., F): triangle frames;
    face_ids (N,) int; local_means (N, 3), local_quats (N, 4) wxyz, local_scales (N, 3).
    Returns means (..., N, 3), quats (..., N, 4), scales (..., N, 3) in float64.
    """
    t = np.asarray(origins, np.float64)[..., face_ids, :]
    r = np.asarray(rotations, np.float64)
    k = np.asarray(scales, np.float64)[..., face_ids, None]
    q_r = matrix_to_quat(r)[..., face_ids, :]
    r = r[..., face_ids, :, :]
    mu = np.einsum("...ij,...j->...i", r, np.asarray(local_means, np.float64))
    means = k * mu + t
    quats = quat_multiply(q_r, np.asarray(local_quats, np.float64))
    return means, quats, k * np.asarray(local_scales, np.float64)


def world_to_local(origins, rotations, scales, face_ids, means, quats, gaussian_scales):
    """Inverse of `local_to_world` for one mesh pose: origins (F, 3), rotations (F, 3, 3),
    scales (F,), face_ids (N,), world means (N, 3), quats (N, 4), scales (N, 3) -> local
    means (N, 3), quats (N, 4), scales (N, 3) in float64."""
    t = np.asarray(origins, np.float64)[face_ids]
    r = np.asarray(rotations, np.float64)
    k = np.asarray(scales, np.float64)[face_ids, None]
    q_r = matrix_to_quat(r)[face_ids]
    r = r[face_ids]
    mu = np.einsum("nji,nj->ni", r, np.asarray(means, np.float64) - t) / k
    q = quat_multiply(_conj(q_r), np.asarray(quats, np.float64))
    return mu, q, np.asarray(gaussian_scales, np.float64) / k


@dataclass(eq=False)
class TriangleBinding:
    """N Gaussians bound to the triangles of a mesh topology.

    faces: (F, 3) int32 topology the binding refers to; face_ids: (N,) int32 host triangle per
    Gaussian; local: the Gaussians in triangle-local form (means mu', quats q', scales s' in
    units of the triangle scale; opacities, SH and extras as bound); sh_frame: "local" (SH bands
    turn with the triangle) or "world" (GaussianAvatars: they do not).
    """

    faces: np.ndarray
    face_ids: np.ndarray
    local: GaussianSet
    sh_frame: str = "local"

    def __post_init__(self):
        f = np.asarray(self.faces)
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer) or (f.size and f.min() < 0):
            raise InputError(f"faces must be non-negative integers of shape (F, 3), got {f.shape} {f.dtype}")
        self.faces = np.ascontiguousarray(f, dtype=np.int32)
        if not isinstance(self.local, GaussianSet):
            raise InputError("local must be a GaussianSet")
        ids = np.asarray(self.face_ids)
        if ids.shape != (len(self.local),) or not np.issubdtype(ids.dtype, np.integer):
            raise InputError(f"face_ids must be integers of shape ({len(self.local)},), got {ids.shape} {ids.dtype}")
        if ids.size and (ids.min() < 0 or ids.max() >= len(self.faces)):
            bad = int(np.flatnonzero((ids < 0) | (ids >= len(self.faces)))[0])
            raise InputError(f"face_ids[{bad}] = {int(ids[bad])} is not a triangle index "
                             f"(the mesh has {len(self.faces)} triangles)")
        self.face_ids = np.ascontiguousarray(ids, dtype=np.int32)
        if self.sh_frame not in SH_FRAMES:
            raise InputError(f"sh_frame must be one of {SH_FRAMES}, got {self.sh_frame!r}")
        self._used = None  # the distinct face ids, found on first use
        if "binding" in self.local.extras:  # face_ids is the one source of truth
            self.local = self.local.replace(
                extras={k: v for k, v in self.local.extras.items() if k != "binding"})

    # --- construction -------------------------------------------------------------------
    @classmethod
    def bind(cls, gaussians: GaussianSet, vertices: np.ndarray, faces: np.ndarray,
             face_ids: np.ndarray | None = None, *, rotate_sh: bool = True,
             candidates: int = 8) -> "TriangleBinding":
        """Bind world-space Gaussians to the mesh (vertices (V, 3), faces (F, 3)) they sit on.

        face_ids (N,): host triangle per Gaussian; by default the triangle closest to each
        Gaussian's mean (degenerate triangles are never chosen). rotate_sh: store SH in the
        triangle frame so view-dependent colour turns with the mesh (sh_frame "local").
        """
        v, f = _check(vertices, faces)
        if v.ndim != 2:
            raise InputError(f"bind needs one mesh pose: vertices (V, 3), got {v.shape}")
        if not np.isfinite(v).all():
            raise InputError("vertices contain non-finite values")
        degenerate = degenerate_faces(v, f)
        if face_ids is None:
            if len(f) == 0:
                raise InputError("the mesh has no triangles")
            ids, _ = nearest_faces(gaussians.means, v, f, exclude=degenerate, candidates=candidates)
        else:
            ids = np.asarray(face_ids)
            if ids.shape != (len(gaussians),) or not np.issubdtype(ids.dtype, np.integer):
                raise InputError(f"face_ids must be integers of shape ({len(gaussians)},), got {ids.shape}")
            if ids.size and (ids.min() < 0 or ids.max() >= len(f)):
                raise InputError(f"face_ids must lie in 0..{len(f) - 1}")
            if degenerate[ids].any():
                bad = int(ids[degenerate[ids]][0])
                raise InputError(f"triangle {bad} is degenerate (no area): Gaussians cannot ride it")
        binding = cls(f, ids.astype(np.int32), gaussians, "local" if rotate_sh else "world")
        return binding.to_local(gaussians, v)

    @classmethod
    def from_local(cls, local: GaussianSet, faces: np.ndarray, face_ids: np.ndarray | None = None,
                   sh_frame: str = "world") -> "TriangleBinding":
        """Wrap Gaussians already in triangle-local form (a GaussianAvatars `point_cloud.ply`:
        local means/scales/rotations plus a `binding` extra). face_ids default to that extra."""
        if face_ids is None:
            if "binding" not in local.extras:
                raise InputError("local Gaussians have no 'binding' extra; pass face_ids")
            face_ids = local.extras["binding"].astype(np.int64)
        return cls(faces, face_ids, local, sh_frame)

    # --- properties ---------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.local)

    @property
    def local_means(self) -> np.ndarray:
        return self.local.means

    @property
    def local_quats(self) -> np.ndarray:
        return self.local.quats

    @property
    def local_scales(self) -> np.ndarray:
        return self.local.scales

    def local_gaussians(self) -> GaussianSet:
        """The local set with the `binding` extra (GaussianAvatars' PLY layout)."""
        return self.local.replace(extras={**self.local.extras, "binding": self.face_ids})

    # --- posing -------------------------------------------------------------------------
    def _frames(self, vertices: np.ndarray, first_frame: int = 0):
        v, f = _check(vertices, self.faces)
        if not np.isfinite(v).all():
            raise InputError("vertices contain non-finite values")
        origins, rotations, scales, degenerate = frames_and_degenerate(v.astype(np.float64, copy=False), f)
        if self._used is None:
            self._used = np.unique(self.face_ids)
        deg = degenerate[..., self._used]
        if deg.any():
            where = np.argwhere(deg)[0]
            face = int(self._used[where[-1]])
            frame = f" in frame {first_frame + int(where[0])}" if deg.ndim == 2 else ""
            raise InputError(f"triangle {face} collapsed{frame} (zero area); its Gaussians have no frame")
        return v, origins, rotations, scales

    def to_world(self, vertices: np.ndarray) -> "GaussianSet | PosedGaussians":
        """Pose the Gaussians on a mesh: vertices (V, 3) -> GaussianSet, or (T, V, 3) ->
        `PosedGaussians` with (T, N, ...) arrays. The world set carries the `binding` extra (N,)
        int32 so PLY files keep the host triangle of every Gaussian."""
        v = np.asarray(vertices)
        if v.ndim == 2:
            _, origins, rotations, scales = self._frames(v)
            return self._world_set(origins, rotations, scales)
        if v.ndim != 3:
            raise InputError(f"vertices must have shape (V, 3) or (T, V, 3), got {v.shape}")
        n_t, n = len(v), len(self)
        means = np.empty((n_t, n, 3), np.float32)
        quats = np.empty((n_t, n, 4), np.float32)
        gscales = np.empty((n_t, n, 3), np.float32)
        step = max(1, _BLOCK // max(n, 1))
        for a in range(0, n_t, step):
            _, origins, rotations, scales = self._frames(v[a:a + step], a)
            m, q, s = local_to_world(origins, rotations, scales, self.face_ids, self.local.means,
                                     self.local.quats, self.local.scales)
            means[a:a + step] = m
            quats[a:a + step] = q / np.linalg.norm(q, axis=-1, keepdims=True)
            gscales[a:a + step] = s
        return PosedGaussians(means, quats, gscales, self, v)

    def _world_set(self, origins, rotations, scales) -> GaussianSet:
        m, q, s = local_to_world(origins, rotations, scales, self.face_ids, self.local.means,
                                 self.local.quats, self.local.scales)
        sh = self.local.sh
        if self.sh_frame == "local" and self.local.sh_degree > 0:
            sh = rotate_sh_indexed(sh, rotations, self.face_ids)
        extras = {**self.local.extras, "binding": self.face_ids.copy()}
        return GaussianSet(m, q / np.linalg.norm(q, axis=1, keepdims=True), s,
                           self.local.opacities, sh, extras)

    def to_local(self, gaussians: GaussianSet, vertices: np.ndarray) -> "TriangleBinding":
        """A binding on the same triangles whose world pose on `vertices` (V, 3) is `gaussians`
        (N Gaussians in the order of this binding). Extras other than `binding` are kept."""
        if len(gaussians) != len(self):
            raise InputError(f"{len(gaussians)} Gaussians given but the binding has {len(self)}")
        v = np.asarray(vertices)
        if v.ndim != 2:
            raise InputError(f"to_local needs one mesh pose: vertices (V, 3), got {v.shape}")
        _, origins, rotations, scales = self._frames(v)
        m, q, s = world_to_local(origins, rotations, scales, self.face_ids, gaussians.means,
                                 gaussians.quats, gaussians.scales)
        sh = gaussians.sh
        if self.sh_frame == "local" and gaussians.sh_degree > 0:
            sh = rotate_sh_indexed(sh, np.swapaxes(rotations, -1, -2), self.face_ids)
        extras = {k: x for k, x in gaussians.extras.items() if k != "binding"}
        local = GaussianSet(m, q / np.linalg.norm(q, axis=1, keepdims=True), s,
                            gaussians.opacities, sh, extras)
        return TriangleBinding(self.faces, self.face_ids, local, self.sh_frame)

    def subset(self, index) -> "TriangleBinding":
        """The binding of some Gaussians (boolean mask (N,) or indices)."""
        idx = np.asarray(index)
        return TriangleBinding(self.faces, self.face_ids[idx], self.local.subset(idx), self.sh_frame)

    def __repr__(self) -> str:
        return (f"TriangleBinding(n={len(self)}, faces={len(self.faces)}, "
                f"sh_degree={self.local.sh_degree}, sh_frame={self.sh_frame!r})")


@dataclass(eq=False)
class PosedGaussians:
    """World poses of a binding over T mesh poses: means (T, N, 3), quats (T, N, 4) wxyz unit,
    scales (T, N, 3), float32. `frame(t)` gives frame t as a full GaussianSet (SH turned,
    opacities and extras included)."""

    means: np.ndarray
    quats: np.ndarray
    scales: np.ndarray
    binding: TriangleBinding
    vertices: np.ndarray  # (T, V, 3) the mesh poses

    def __len__(self) -> int:
        return len(self.means)

    def frame(self, t: int) -> GaussianSet:
        v = np.asarray(self.vertices[t], np.float64)
        origins, rotations, scales = triangle_frames(v, self.binding.faces)
        return self.binding._world_set(origins, rotations, scales)
