"""Hair relative to the head: hair Gaussians and cage vertices in the frames of scalp triangles.

Paper section 3.2: "by defining the hair in the local coordinates of the nearest scalp mesh ...
hairstyle transfer across different identities can be easily achieved". Every hair Gaussian is
bound to its nearest SCALP triangle of the source's rest head (`TriangleBinding` with the
candidates restricted to the head model's `scalp` faces): its orientation q', scale s' and SH
are stored in that triangle's frame (t, R, k) and come back as q = q_R q', s = k s' on any head
with the same topology.

Positions. With one triangle per point (`neighbours=1`) a position is mu = k R mu' + t of its
nearest triangle, exactly as above. Long hair hangs 20 cm from the scalp, ~40 triangle sizes:
where the target's shape bends neighbouring triangles differently, two neighbouring hair
Gaussians bound to two different triangles move apart (a few mm for one standard deviation of
head width on the template). So by default a position is the weighted mean of its re-expression
in the frames of its `neighbours` nearest scalp triangles (by centroid distance d_j), with
weights w_j ~ (1 - d_j / d_{K+1})^2 that reach zero just as a triangle leaves the K nearest: the
re-seated hair is a continuous function of where it was. Each re-expression is exact for the
source head itself and for any similarity transform of it (uniform scale, rigid motion), so the
mean is too. Cage vertices are expressed the same way.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rig.binding import TriangleBinding, local_to_world, world_to_local
from avatarkit.rig.frames import degenerate_faces, frames_and_degenerate

#: scalp triangles each position is expressed in (1 = the paper's nearest triangle only)
NEIGHBOURS = 8
SCALP = "scalp"


def scalp_faces(head_model) -> np.ndarray:
    """Indices (S,) int64 of the head model's scalp faces (all three vertices in the `scalp`
    region; two of three if that leaves none). InputError if the model has no scalp."""
    if SCALP not in getattr(head_model, "regions", {}):
        raise InputError(f"the head model has no {SCALP!r} region to seat hair on "
                         f"(it has {', '.join(sorted(head_model.regions)) or 'no regions'})")
    ids = head_model.region_faces(SCALP, "all")
    if len(ids) == 0:
        ids = head_model.region_faces(SCALP, "majority")
    if len(ids) == 0:
        raise InputError(f"the head model's {SCALP!r} region holds no faces")
    return ids


def check_same_topology(source_head, target_head, source_name: str = "the hair source",
                        target_name: str = "the target") -> None:
    """InputError unless both head models share one mesh topology (vertex count and faces)."""
    a, b = source_head, target_head
    if a.num_vertices != b.num_vertices or a.num_faces != b.num_faces:
        raise InputError(f"different head model topology: {source_name}'s head has {a.num_vertices} "
                         f"vertices and {a.num_faces} faces, {target_name}'s {b.num_vertices} and "
                         f"{b.num_faces}; hair moves only between heads of one model")
    if not np.array_equal(a.faces, b.faces):
        bad = int(np.flatnonzero((a.faces != b.faces).any(axis=1))[0])
        raise InputError(f"different head model topology: {source_name}'s and {target_name}'s heads "
                         f"have the same counts but face {bad} differs ({a.faces[bad].tolist()} vs "
                         f"{b.faces[bad].tolist()}); hair moves only between heads of one model")


def _usable_scalp(head_model, vertices: np.ndarray) -> np.ndarray:
    ids = scalp_faces(head_model)
    ids = ids[~degenerate_faces(vertices, head_model.faces[ids])]
    if len(ids) == 0:
        raise InputError("every scalp triangle of the head is degenerate (no area)")
    return ids


def _anchor_points(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, allowed: np.ndarray,
                   neighbours: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (P, 3) in the frames of their K nearest allowed triangles -> face ids (P, K) int32,
    local positions (P, K, 3) float64, weights (P, K) float64 (rows sum to 1)."""
    from scipy.spatial import cKDTree

    from avatarkit.rig.nearest import nearest_faces

    p = np.asarray(points, np.float64).reshape(-1, 3)
    k = int(min(neighbours, len(allowed)))
    if k == 1:
        exclude = np.ones(len(faces), bool)
        exclude[allowed] = False
        ids, _ = nearest_faces(p, vertices, faces, exclude=exclude)
        ids = ids[:, None]
        w = np.ones((len(p), 1))
    else:
        centroids = vertices[faces[allowed]].mean(axis=1)
        extra = 1 if k < len(allowed) else 0
        d, j = cKDTree(centroids).query(p, k=k + extra)
        if extra:
            reach = d[:, -1:]
            d, j = d[:, :k], j[:, :k]
        else:  # every allowed triangle is in: the farthest keeps a small weight
            reach = d[:, -1:] * 1.5 + 1e-12
        w = (1.0 - d / np.maximum(reach, 1e-12)) ** 2 + 1e-12
        w /= w.sum(axis=1, keepdims=True)
        ids = allowed[j]
    n = ids.size
    origins, rotations, scales, _ = frames_and_degenerate(vertices, faces)
    local, _, _ = world_to_local(origins, rotations, scales, ids.ravel(), np.repeat(p, ids.shape[1], 0),
                                 np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.ones((n, 3)))
    return ids.astype(np.int32), local.reshape(ids.shape + (3,)), w


@dataclass(eq=False)
class ScalpHair:
    """A hairstyle expressed relative to the scalp of a head model's topology.

    binding: the hair Gaussians on their nearest scalp triangles (face ids index the full head
    `faces`; orientation, scale and SH are taken from it); point_faces (N + C, K) int32,
    point_local (N + C, K, 3) float64 and point_weights (N + C, K): the positions of the N hair
    Gaussians then the C cage vertices in the frames of their K nearest scalp triangles;
    cage_faces (M, 3): the cage's triangles (None without a cage).
    """

    binding: TriangleBinding
    point_faces: np.ndarray
    point_local: np.ndarray
    point_weights: np.ndarray
    cage_faces: np.ndarray | None = None

    def __post_init__(self):
        k = self.point_faces.shape[1] if self.point_faces.ndim == 2 else -1
        if self.point_faces.ndim != 2 or self.point_local.shape != self.point_faces.shape + (3,) \
                or self.point_weights.shape != self.point_faces.shape or k < 1:
            raise InputError("point_faces (P, K), point_local (P, K, 3) and point_weights (P, K) "
                             "must agree")
        if len(self.point_faces) < len(self.binding):
            raise InputError(f"{len(self.point_faces)} anchored points for {len(self.binding)} "
                             "hair Gaussians")

    @property
    def n_hair(self) -> int:
        return len(self.binding)

    @property
    def n_cage(self) -> int:
        return len(self.point_faces) - self.n_hair

    @property
    def neighbours(self) -> int:
        return int(self.point_faces.shape[1])

    @classmethod
    def bind(cls, hair: GaussianSet, head_model, rest_vertices: np.ndarray, cage=None,
             neighbours: int | None = None) -> "ScalpHair":
        """Express `hair` (and the `cage` around it, if given) relative to the scalp of
        `head_model` posed as `rest_vertices` (V, 3) (the avatar's rest head)."""
        neighbours = NEIGHBOURS if neighbours is None else neighbours
        if not isinstance(hair, GaussianSet):
            raise InputError("hair must be a GaussianSet")
        if len(hair) == 0:
            raise InputError("there are no hair Gaussians to express relative to the scalp")
        if isinstance(neighbours, bool) or int(neighbours) != neighbours or neighbours < 1:
            raise InputError(f"neighbours must be a positive integer, got {neighbours!r}")
        v = np.asarray(rest_vertices, np.float64)
        faces = head_model.faces
        allowed = _usable_scalp(head_model, v)
        exclude = np.ones(len(faces), bool)
        exclude[allowed] = False
        from avatarkit.rig.nearest import nearest_faces

        ids, _ = nearest_faces(hair.means, v, faces, exclude=exclude)
        binding = TriangleBinding.bind(hair, v, faces, face_ids=ids.astype(np.int32), rotate_sh=True)
        points = hair.means
        cage_faces = None
        if cage is not None:
            points = np.concatenate([np.asarray(hair.means, np.float64),
                                     np.asarray(cage.vertices, np.float64)])
            cage_faces = np.asarray(cage.faces, np.int32)
        pf, pl, pw = _anchor_points(points, v, faces, allowed, int(neighbours))
        return cls(binding, pf, pl, pw, cage_faces)

    # -- re-expression ---------------------------------------------------------------------------
    def _frames(self, rest_vertices: np.ndarray):
        v = np.asarray(rest_vertices, np.float64)
        faces = self.binding.faces
        if v.ndim != 2 or v.shape[1] != 3:
            raise InputError(f"head vertices must have shape (V, 3), got {v.shape}")
        if faces.size and faces.max() >= len(v):
            raise InputError(f"the hair was bound to a head of more than {len(v)} vertices")
        if not np.isfinite(v).all():
            raise InputError("head vertices contain non-finite values")
        origins, rotations, scales, degenerate = frames_and_degenerate(v, faces)
        used = np.unique(self.point_faces)
        if degenerate[used].any():
            bad = int(used[degenerate[used]][0])
            raise InputError(f"scalp triangle {bad} has collapsed (no area) on the target head")
        return v, origins, rotations, scales

    def points_to_world(self, rest_vertices: np.ndarray) -> np.ndarray:
        """(N + C, 3) float64: hair positions then cage vertices seated on the head
        `rest_vertices` (V, 3) of the same topology."""
        _, origins, rotations, scales = self._frames(rest_vertices)
        n = self.point_faces.size
        means, _, _ = local_to_world(origins, rotations, scales, self.point_faces.ravel(),
                                     self.point_local.reshape(-1, 3), np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
                                     np.ones((n, 3)))
        means = means.reshape(self.point_local.shape)
        return np.einsum("pk,pkc->pc", self.point_weights, means)

    def to_world(self, rest_vertices: np.ndarray):
        """The hair (`GaussianSet`, extras as bound, no `binding`) and the cage vertices (C, 3)
        (None without a cage) seated on the head `rest_vertices` (V, 3)."""
        self._frames(rest_vertices)
        points = self.points_to_world(rest_vertices)
        hair = self.binding.to_world(np.asarray(rest_vertices, np.float64))
        extras = {k: x for k, x in hair.extras.items() if k != "binding"}
        hair = hair.replace(means=points[:self.n_hair], extras=extras)
        cage = points[self.n_hair:] if self.cage_faces is not None else None
        return hair, cage


__all__ = ["NEIGHBOURS", "ScalpHair", "check_same_topology", "scalp_faces"]
