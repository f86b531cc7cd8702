"""The fixed correspondence between MediaPipe's face mesh and a head model's surface.

A `LandmarkEmbedding` puts chosen face-mesh points (`landmark_indices` into the 468) on the
head model as barycentric points on its triangles: point k is
    sum_j lmk_b_coords[k, j] * vertices[faces[lmk_face_idx[k], j]].
The file format is FLAME's published `mediapipe_landmark_embedding.npz` (keys `lmk_face_idx`
(K,), `lmk_b_coords` (K, 3), `landmark_indices` (K,); FLAME's has K = 105), so a user's
FLAME embedding and ours read the same way.

For the built-in template head the embedding is made by `make_template_embedding` and shipped
as `data/template_mediapipe_embedding.npz`; `scripts/make_face_correspondence.py` re-makes it:
the template head is rendered (bald Gaussians on its surface, our CPU renderer) from a few
views with known cameras, the face mesh runs on each render, and every landmark's pixel is
triangulated from the views whose ray through it hits the head (linear DLT with the known
cameras), then put on the surface where the frontal camera's ray through it hits. Points on the
face's outline (`FACE_OVAL`) are where the silhouette happens to be in a view, so they are
cast from the frontal view alone. Triangulating over yaw -45..45 and pitch +-15 degrees makes
one point that best agrees with what the mesh model says in all of them (its answers drift
with the view on a head whose proportions are not a person's); landmarks whose point still
misses the views' answers by more than `MAX_RESIDUAL` eye distances (RMS) are left out.
A second file, for the mirror-averaged face mesh (`face_landmarks(mirror=True)`, what
`avatarkit face` fits), is made the same way from that mesh at the 35 views of
`MIRROR_TEMPLATE_VIEWS` (`template_embedding(mirror=True)`): on 120 shaded renders of the
template (benchmarks/face.py) the fit on it reads the pose 2.19 deg median against 2.37 on the
plain mesh's embedding (docs/face.md, session 10).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError

#: MediaPipe's FACEMESH_FACE_OVAL, in order around the face (forehead, subject's left side, chin, right side)
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
             152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)
#: FACEMESH_LIPS: the outer contour (from the subject's right corner 61 along the lower lip, back
#: along the upper) and the inner one (from 78)
LIPS_OUTER = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267, 0, 37, 39, 40, 185)
LIPS_INNER = (78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 415, 310, 311, 312, 13, 82, 81, 80, 191)
#: the inner contour's lower half (corners excluded): the edge of the lower lip, which the jaw carries
LOWER_INNER_LIP = (95, 88, 178, 87, 14, 317, 402, 318, 324)
#: a vertex the jaw carries: skinning weight to the jaw at least this
JAW_CARRIED = 0.5
#: a few named mesh points
NAMED = {"nose_tip": 1, "chin": 152, "forehead": 10, "mouth_right": 61, "mouth_left": 291,
         "upper_lip": 13, "lower_lip": 14, "right_eye_outer": 33, "right_eye_inner": 133,
         "left_eye_inner": 362, "left_eye_outer": 263}
TEMPLATE_FILE = Path(__file__).with_name("data") / "template_mediapipe_embedding.npz"
#: views the template embedding is made from: (yaw, pitch) degrees; the first is frontal
#: landmarks whose surface point misses the mesh model's answers by more than this RMS over the
#: views (in eye distances) are left out of the template's embedding
MAX_RESIDUAL = 0.08
TEMPLATE_VIEWS = ((0.0, 0.0), (-15.0, 0.0), (15.0, 0.0), (-30.0, 0.0), (30.0, 0.0), (-45.0, 0.0),
                  (45.0, 0.0), (0.0, -15.0), (0.0, 15.0))
#: the embedding for the mirror-averaged face mesh (`face_landmarks(mirror=True)`, what
#: `avatarkit face` fits): made from that mesh, at every view of a grid (yaw -45..45 by 15,
#: pitch -20..20 by 10 degrees; the frontal one first), so the vertical placement of each point
#: is triangulated from pitched views too, not only its horizontal one from turned views
MIRROR_TEMPLATE_FILE = Path(__file__).with_name("data") / "template_mediapipe_embedding_mirror.npz"
MIRROR_TEMPLATE_VIEWS = ((0.0, 0.0),) + tuple((float(y), float(p)) for y in range(-45, 46, 15)
                                             for p in range(-20, 21, 10) if (y, p) != (0, 0))


@dataclass(frozen=True, eq=False)
class LandmarkEmbedding:
    """face_idx (K,) int64 triangles; bary (K, 3) float64 barycentric coordinates;
    mesh_index (K,) int64: which of the 468 face-mesh points each one is; offset (K, 3)
    float64 metres in the head's rest frame added to each point, or None (the files: FLAME's
    and ours have none). Offsets are the tracker's per-video landmark calibration
    (`track.tracker.FrameTracker.calibrate`): where this person's face-mesh points sit beyond
    what the identity coefficients can shape; they move with the head and, at the point's jaw
    weight, the jaw."""

    face_idx: np.ndarray
    bary: np.ndarray
    mesh_index: np.ndarray
    offset: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.face_idx)

    def points(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(K, 3) landmark positions on a mesh (vertices (V, 3), faces (F, 3)) at rest
        (offsets added as they are: exact for a mesh without jaw rotation)."""
        tri = np.asarray(vertices, np.float64)[np.asarray(faces)[self.face_idx]]
        p = np.einsum("kj,kjd->kd", self.bary, tri)
        return p if self.offset is None else p + self.offset

    def with_offset(self, offset: np.ndarray | None) -> "LandmarkEmbedding":
        """The same points with `offset` (K, 3) metres (None: none)."""
        off = None if offset is None else np.asarray(offset, np.float64).reshape(len(self), 3)
        return LandmarkEmbedding(self.face_idx, self.bary, self.mesh_index, off)

    def check(self, num_faces: int, source=None) -> "LandmarkEmbedding":
        if len(self) == 0:
            raise FormatError("landmark embedding is empty", source)
        if self.face_idx.min() < 0 or self.face_idx.max() >= num_faces:
            raise FormatError(f"landmark embedding names triangle {int(self.face_idx.max())} but the head "
                              f"model has {num_faces}", source)
        if self.mesh_index.min() < 0 or self.mesh_index.max() >= 468:
            raise FormatError("landmark_indices must lie in 0..467 (MediaPipe's face mesh)", source)
        return self

    def save(self, path: str | os.PathLike) -> None:
        from avatarkit.fileio import atomic_path

        with atomic_path(path, ".npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, lmk_face_idx=self.face_idx.astype(np.int64),
                         lmk_b_coords=self.bary.astype(np.float64),
                         landmark_indices=self.mesh_index.astype(np.int64))


def read_embedding(path: str | os.PathLike, num_faces: int | None = None) -> LandmarkEmbedding:
    """Read a FLAME-style `mediapipe_landmark_embedding.npz`. Raises InputError / FormatError."""
    from avatarkit.fileio import read_npz

    p = Path(path)
    if not p.is_file():
        raise InputError("landmark embedding file not found", p)
    data = read_npz(p)
    need = ("lmk_face_idx", "lmk_b_coords", "landmark_indices")
    missing = [k for k in need if k not in data]
    if missing:
        raise FormatError(f"not a face-mesh landmark embedding: missing {', '.join(missing)} (keys: "
                          f"{', '.join(sorted(data)) or 'none'}); expected FLAME's "
                          "mediapipe_landmark_embedding.npz", p)
    try:
        face_idx = np.asarray(data["lmk_face_idx"]).astype(np.int64).reshape(-1)
        bary = np.asarray(data["lmk_b_coords"], np.float64).reshape(-1, 3)
        index = np.asarray(data["landmark_indices"]).astype(np.int64).reshape(-1)
    except (TypeError, ValueError):
        raise FormatError("landmark embedding arrays are not numeric", p) from None
    if not (len(face_idx) == len(bary) == len(index)):
        raise FormatError(f"landmark embedding arrays disagree in length: lmk_face_idx {len(face_idx)}, "
                          f"lmk_b_coords {len(bary)}, landmark_indices {len(index)}", p)
    if not np.isfinite(bary).all() or np.abs(bary.sum(axis=1) - 1).max() > 1e-3:
        raise FormatError("lmk_b_coords rows must be finite and sum to 1", p)
    emb = LandmarkEmbedding(face_idx, bary, index)
    return emb.check(num_faces, p) if num_faces is not None else emb


def template_embedding(mirror: bool = False) -> LandmarkEmbedding:
    """The shipped embedding of the built-in template head: for the plain face mesh, or with
    `mirror` for the mirror-averaged one (`face_landmarks(mirror=True)`; each made from the
    mesh it is used with)."""
    return read_embedding(MIRROR_TEMPLATE_FILE if mirror else TEMPLATE_FILE)


def embedding_for(model, path: str | os.PathLike | None = None, mirror: bool = False,
                  carry_jaw: bool = True) -> LandmarkEmbedding | None:
    """The embedding to use with `model`: `path` if given, the shipped one for the template
    (for the mirror-averaged face mesh with `mirror`; with `carry_jaw` its lower inner lip
    carried by the jaw, `carried_by_jaw`), None for any other model without a file (the fit
    then uses the few named landmarks).

    carry_jaw: for fits that have a jaw (the tracker). The portrait fits (the build's
    `recon.fit`, `avatarkit face`) have none, and there the re-hosted points follow the
    expressions that pull the lower lip instead, which moved the sample portrait's fitted
    rotation by 1.9 degrees and cost its front view 0.2 dB (28.30 -> 28.10): they pass False."""
    if path is not None:
        return read_embedding(path, model.num_faces)
    if model.name == "template":
        file = MIRROR_TEMPLATE_FILE if mirror else TEMPLATE_FILE
        emb = template_embedding(mirror).check(model.num_faces, file)
        return carried_by_jaw(emb, model) if carry_jaw else emb
    return None


def carried_by_jaw(embedding: LandmarkEmbedding, model, mesh_points=None,
                   min_weight: float | None = None) -> LandmarkEmbedding:
    """The same landmarks with those of `mesh_points` that sit where the jaw does not reach
    re-hosted on the nearest vertex of the head model's lips that the jaw carries (skinning
    weight >= `min_weight`), with the offset that keeps each one's rest position.

    Why: the template's embedding is cast from renders of its closed mouth, where the face
    mesh's lower inner lip lies on the upper lip's surface (jaw weight 0): a fit can then open
    those points only through expressions that pull the upper lip down, and the avatar's
    mouth hardly opens (grey clip: the inner-lip gap detected on the renders grew 0.20 px per
    pixel of the video's). At rest nothing moves; with the jaw open the points follow the lower
    lip. Rows whose host already has the jaw's weight, and other models' embeddings, are left
    as they are."""
    mesh_points = LOWER_INNER_LIP if mesh_points is None else mesh_points
    min_weight = JAW_CARRIED if min_weight is None else min_weight
    from avatarkit.face.fit import JAW_JOINT

    faces = np.asarray(model.faces)
    if model.weights.shape[1] <= JAW_JOINT or "lips" not in model.regions:
        return embedding
    w = np.asarray(model.weights[:, JAW_JOINT], np.float64)
    rest = np.asarray(model.v_template, np.float64)
    carried = np.flatnonzero(model.region_mask("lips") & (w >= min_weight))
    if len(carried) == 0:
        return embedding
    rows = [k for k, m in enumerate(np.asarray(embedding.mesh_index)) if int(m) in set(mesh_points)]
    bary_w = np.einsum("kj,kj->k", embedding.bary, w[faces[embedding.face_idx]])
    rows = [k for k in rows if bary_w[k] < min_weight]
    if not rows:
        return embedding
    points = embedding.points(rest, faces)                                   # (K, 3) offsets included
    face_idx, bary = embedding.face_idx.copy(), embedding.bary.copy()
    offset = np.zeros((len(embedding), 3)) if embedding.offset is None else embedding.offset.copy()
    # a triangle holding each vertex, and the vertex's corner in it
    tri_of = np.full(len(rest), -1, np.int64)
    corner = np.zeros(len(rest), np.int64)
    for j in range(3):
        tri_of[faces[:, j]] = np.arange(len(faces))
        corner[faces[:, j]] = j
    for k in rows:
        v = carried[np.argmin(np.linalg.norm(rest[carried] - points[k], axis=1))]
        face_idx[k] = tri_of[v]
        bary[k] = np.eye(3)[corner[v]]
        offset[k] = points[k] - rest[v]
    return LandmarkEmbedding(face_idx, bary, embedding.mesh_index, offset)


# ---------------------------------------------------------------------------------------------
# making the template's embedding

def ray_triangle_hits(origin: np.ndarray, dirs: np.ndarray, tri: np.ndarray,
                      chunk: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit of each ray (origin (3,), dirs (R, 3)) on triangles tri (F, 3, 3)
    (Moller-Trumbore, both sides). Returns face index (R,) (-1: no hit), barycentric (R, 3)
    and distance along the ray (R,)."""
    o = np.asarray(origin, np.float64)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    tvec = o - v0                                      # (F, 3)
    qvec = np.cross(tvec, e1)                          # (F, 3)
    R = len(dirs)
    best_f = np.full(R, -1, np.int64)
    best_t = np.full(R, np.inf)
    best_b = np.zeros((R, 3))
    for s in range(0, R, chunk):
        d = np.asarray(dirs[s:s + chunk], np.float64)    # (r, 3)
        pvec = np.cross(d[:, None, :], e2[None])         # (r, F, 3)
        det = np.einsum("rfk,fk->rf", pvec, e1)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        u = np.einsum("rfk,fk->rf", pvec, tvec) * inv
        v = np.einsum("rk,fk->rf", d, qvec) * inv
        t = np.einsum("fk,fk->f", e2, qvec)[None] * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
        t = np.where(hit, t, np.inf)
        f = np.argmin(t, axis=1)
        tt = t[np.arange(len(d)), f]
        found = np.isfinite(tt)
        rows = np.arange(s, s + len(d))[found]
        best_f[rows] = f[found]
        best_t[rows] = tt[found]
        uu, vv = u[np.arange(len(d)), f][found], v[np.arange(len(d)), f][found]
        best_b[rows] = np.stack([1 - uu - vv, uu, vv], axis=1)
    return best_f, best_b, best_t


def pixel_rays(camera, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre (3,) and unit world directions (N, 3) through pixels xy (N, 2)."""
    m = np.asarray(camera.world_to_camera, np.float64)
    r, t = m[:3, :3], m[:3, 3]
    centre = -r.T @ t
    d = np.stack([(xy[:, 0] - camera.cx) / camera.fx, (xy[:, 1] - camera.cy) / camera.fy,
                  np.ones(len(xy))], axis=1) @ r   # camera -> world: R^T d, as rows
    return centre, d / np.linalg.norm(d, axis=1, keepdims=True)


def _projection(camera) -> np.ndarray:
    """(3, 4) pixel projection matrix of a camera."""
    k = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    return k @ np.asarray(camera.world_to_camera, np.float64)[:3]


def triangulate(cameras, xy: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(N, 3) points from pixels xy (views, N, 2) where seen (views, N) (linear DLT)."""
    P = np.stack([_projection(c) for c in cameras])                 # (views, 3, 4)
    out = np.full((xy.shape[1], 3), np.nan)
    for n in range(xy.shape[1]):
        rows = []
        for v in np.flatnonzero(seen[:, n]):
            x, y = xy[v, n]
            rows += [x * P[v, 2] - P[v, 0], y * P[v, 2] - P[v, 1]]
        if len(rows) >= 4:
            a = np.array(rows)
            x = np.linalg.svd(a)[2][-1]
            out[n] = x[:3] / x[3]
    return out


def _ray_through(frontal, cameras, xy, hits_f, oval):
    """Rays from the frontal camera through the triangulated landmarks (outline points: their
    frontal pixel, as the outline is a silhouette and differs from view to view)."""
    seen = hits_f >= 0
    seen[1:, oval] = False
    pts = triangulate(cameras, xy, seen)
    px = xy[0].copy()
    ok = np.isfinite(pts).all(axis=1) & ~oval
    px[ok] = frontal.project(pts[ok])[0]
    return pixel_rays(frontal, px)


def make_template_embedding(views=None, size: int = 512, n_gaussians: int = 80000,
                            seed: int = 0, max_residual: float | None = None,
                            mirror: bool = False) -> tuple[LandmarkEmbedding, dict]:
    """The template's embedding (module docstring) and a report: per view, the detection score,
    the face-mesh presence and the share of landmarks whose ray hit the head. mirror: from the
    mirror-averaged face mesh (`MIRROR_TEMPLATE_FILE` is made with it and
    `MIRROR_TEMPLATE_VIEWS`); the views are (yaw, pitch) degrees, the frontal one first."""
    views = TEMPLATE_VIEWS if views is None else views
    max_residual = MAX_RESIDUAL if max_residual is None else max_residual
    import math

    from avatarkit.face.detect import detect_faces
    from avatarkit.face.landmarks import face_landmarks
    from avatarkit.head.model import HeadModel
    from avatarkit.recon.fit import synthetic_head_view

    model = HeadModel.template()
    rest = model.v_template.astype(np.float64)
    tri = rest[model.faces]
    oval = np.zeros(468, bool)
    oval[list(FACE_OVAL)] = True
    hits_f = np.full((len(views), 468), -1, np.int64)
    hits_b = np.zeros((len(views), 468, 3))
    report = {}
    pixels, cameras = [], []
    for i, (yaw, pitch) in enumerate(views):
        rot = (math.radians(pitch), math.radians(yaw), 0.0)
        view = synthetic_head_view(rotation=rot, size=size, distance=0.5, n_gaussians=n_gaussians, seed=seed)
        faces = detect_faces(view.image)
        if not faces:
            raise InputError(f"no face found on the template rendered at yaw {yaw}, pitch {pitch}")
        face = max(faces, key=lambda f: f.score)
        # the mesh kind the embedding is for: the plain one (the build, the tracker) or the
        # mirror-averaged one (`avatarkit face`)
        mesh = face_landmarks(view.image, face, mirror=mirror)
        centre, dirs = pixel_rays(view.truth.camera, mesh.points[:, :2].astype(np.float64))
        f, b, _ = ray_triangle_hits(centre, dirs, tri)
        hits_f[i], hits_b[i] = f, b
        pixels.append(mesh.points[:, :2].astype(np.float64))
        if i == 0:
            iod0 = float(np.linalg.norm(mesh.iris_centers[1] - mesh.iris_centers[0]))
        cameras.append(view.truth.camera)
        report[f"yaw{yaw:+.0f}_pitch{pitch:+.0f}"] = {"score": round(face.score, 3),
                                                      "presence": round(mesh.presence, 3),
                                                      "hit_share": round(float((f >= 0).mean()), 3)}
    # Triangulate each landmark from the views that see it (linear DLT over their projection
    # matrices), then put it on the surface where the frontal view's ray through it hits.
    face_idx = np.full(468, -1, np.int64)
    bary = np.zeros((468, 3))
    xs = np.stack(pixels)                                           # (views, 468, 2)
    f0, b0, _ = ray_triangle_hits(*_ray_through(cameras[0], cameras, xs, hits_f, oval), tri)
    face_idx, bary = f0, b0
    # how well each landmark's surface point agrees with the mesh model across the views:
    # RMS reprojection error in units of the frontal eye distance; unstable ones are dropped
    surface = np.einsum("kj,kjd->kd", bary, tri[np.maximum(face_idx, 0)])
    seen = hits_f >= 0
    seen[1:, oval] = False
    err = np.stack([np.linalg.norm(c.project(surface)[0] - xs[v], axis=1) for v, c in enumerate(cameras)])
    rms = np.sqrt(np.where(seen, err ** 2, 0).sum(0) / np.maximum(seen.sum(0), 1)) / iod0
    keep = (face_idx >= 0) & (rms <= max_residual)
    report["rms_residual_iod_percentiles_10_50_90"] = [round(float(v), 4) for v in
                                                        np.percentile(rms[face_idx >= 0], [10, 50, 90])]
    report["landmarks"] = int(keep.sum())
    return LandmarkEmbedding(face_idx[keep], bary[keep], np.flatnonzero(keep)), report
