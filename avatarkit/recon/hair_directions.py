"""Hair strand directions from several calibrated views (a video build's keyframes): each view's
2D hair orientation field (`recon.hair_strands.hair_flow`, the single-view build's), lifted to
3D by intersecting the planes the views allow.

One view. A strand segment through X with 3D direction d projects onto the image line through
X's pixel with the 2D orientation f = (f_x, f_y) there. Every d that projects onto that line lies
in the plane through the camera centre C, X and the back-projected image direction
    a = (f_x / fx) e_x + (f_y / fy) e_y        (e_x, e_y: the camera's right / down axes)
so the view says n . d = 0 with the plane normal n = unit((X - C) x a) (`direction_planes`).
One view leaves the depth component open (the single-view build guesses it from the head's
tangent plane, `hair_strands.flow_to_tangent`).

Several views (`solve_directions`). d minimises, over unit vectors,
    sum_k w_k (n_k . d)^2  +  PRIOR_WEIGHT * (sum_k w_k) * |d - (d . d0) d0|^2
i.e. d is the eigenvector of the smallest eigenvalue of
    M = sum_k w_k n_k n_k^T + PRIOR_WEIGHT (sum_k w_k) (I - d0 d0^T)
(a batched 3x3 `numpy.linalg.eigh`); d0 is today's single-view direction. Two views whose
planes cross at a fair angle fix d; the small prior only decides what nearly parallel planes
(views from almost the same side) leave open. The sense of d follows d0 (orientations are
sign-free). The slow reference `solve_directions_reference` minimises the same objective by
brute force over a dense set of directions on the sphere, one Gaussian at a time.

Weights (`strand_directions`): a view counts for a hair Gaussian when it sees it (the colour
blend's visibility, `multiview.view_samples`, restricted to the view's hair pixels, without its
facing cut: hair seen at a grazing angle, such as the top of the head from the front, still
shows its orientation) with weight sharpness x the flow's coherence there (the reference x
`REFERENCE_WEIGHT`); views with coherence below `MIN_COHERENCE` give nothing (no visible
strand structure). Only Gaussians at least `MIN_VIEWS` views constrain change: where one view
alone sees a Gaussian the single-view estimate is kept (`orient_hair` rotates the rest).
"""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.hair_strands import hair_flow, unit_vectors
from avatarkit.recon.image_sampling import lookup
from avatarkit.recon.multiview import View, view_samples
from avatarkit.rotations import matrix_to_quat, quat_to_matrix
from avatarkit.recon import multiview as _multiview  # its switches read at call time

#: the prior toward today's single-view direction, relative to the views' summed weight
PRIOR_WEIGHT = 0.002
#: a view's flow below this coherence shows no strand structure (the single-view growth's cut)
MIN_COHERENCE = 0.05
#: views needed before a Gaussian's direction is taken from the views
MIN_VIEWS = 2


def direction_planes(points: np.ndarray, flow2d: np.ndarray, camera) -> np.ndarray:
    """Unit normals (N, 3) of the planes through `camera`'s centre that contain every 3D
    direction projecting onto the image orientations flow2d (N, 2) (pixels, x right, y down) at
    points (N, 3) (module docstring)."""
    r = np.asarray(camera.rotation, np.float64)            # rows: camera x, y, z in the world
    f = np.asarray(flow2d, np.float64)
    a = (f[:, :1] / camera.fx) * r[0] + (f[:, 1:] / camera.fy) * r[1]
    ray = np.asarray(points, np.float64) - np.asarray(camera.camera_center, np.float64)[None]
    return unit_vectors(np.cross(ray, a))


def solve_directions(planes: np.ndarray, weights: np.ndarray, prior: np.ndarray,
                     prior_weight: float | None = None) -> np.ndarray:
    """Unit directions (N, 3) from plane normals (V, N, 3) with weights (V, N) >= 0 and the
    prior directions (N, 3) (module docstring); the sense of each follows its prior. Rows
    without weight return the prior."""
    prior_weight = PRIOR_WEIGHT if prior_weight is None else prior_weight
    n = np.asarray(planes, np.float64)
    w = np.asarray(weights, np.float64)
    d0 = unit_vectors(np.asarray(prior, np.float64))
    m = np.einsum("vn,vni,vnj->nij", w, n, n)
    total = w.sum(axis=0)
    m += (prior_weight * total)[:, None, None] * (np.eye(3)[None] - np.einsum("ni,nj->nij", d0, d0))
    _, vec = np.linalg.eigh(m)
    d = vec[:, :, 0]
    d *= np.where(np.einsum("ij,ij->i", d, d0) < 0, -1.0, 1.0)[:, None]
    return np.where((total > 0)[:, None], d, d0)


def fibonacci_sphere(count: int) -> np.ndarray:
    """count (count, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(count) + 0.5
    z = 1 - 2 * i / count
    phi = np.pi * (1 + 5 ** 0.5) * i
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def solve_directions_reference(planes: np.ndarray, weights: np.ndarray, prior: np.ndarray,
                               prior_weight: float | None = None, samples: int = 60_000) -> np.ndarray:
    """`solve_directions` by brute force: per Gaussian, the objective at `samples` directions
    over the sphere (about 0.9 degrees apart at 60k), the best one taken. Slow; for tests."""
    prior_weight = PRIOR_WEIGHT if prior_weight is None else prior_weight
    cand = fibonacci_sphere(samples)
    out = np.empty((planes.shape[1], 3))
    for i in range(planes.shape[1]):
        d0 = prior[i] / np.linalg.norm(prior[i])
        w = weights[:, i]
        cost = sum(w[k] * (cand @ planes[k, i]) ** 2 for k in range(len(w)))
        cost = cost + prior_weight * w.sum() * (1 - (cand @ d0) ** 2)
        best = cand[int(np.argmin(cost))] if w.sum() > 0 else d0
        out[i] = best if best @ d0 >= 0 else -best
    return out


def view_flow(view: View, scale_px: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(flow (H, W, 2), coherence (H, W)) of the view's hair pixels, or None for a view without
    labels or hair."""
    from avatarkit.recon.segment import HAIR

    if view.labels is None:
        return None
    hair = np.asarray(view.labels) == HAIR
    if not hair.any():
        return None
    return hair_flow(view.image, hair, scale_px)


def strand_directions(union: GaussianSet, normals: np.ndarray, hair_rows: np.ndarray, current: np.ndarray,
                      views: list[View], scale_px: float, min_views: int | None = None,
                      prior_weight: float | None = None):
    """Directions of the hair Gaussians `union[hair_rows]` from the views (module docstring).
    union: everything that occludes (bald + hair); normals (len(union), 3) outward; current
    (H, 3): today's directions of those hair Gaussians. Returns (directions (H, 3), used (H,)
    bool: at least min_views views constrained it, info)."""
    min_views = MIN_VIEWS if min_views is None else min_views
    prior_weight = PRIOR_WEIGHT if prior_weight is None else prior_weight
    from avatarkit.recon.segment import HAIR

    hair_rows = np.asarray(hair_rows, bool)
    means = np.asarray(union.means, np.float64)[hair_rows]
    planes, weights, per_view = [], [], []
    for v in views:
        fc = view_flow(v, scale_px)
        if fc is None:
            continue
        flow, coherence = fc
        # no facing cut: hair seen at a grazing angle (the top of the head from the front) still
        # shows its strands' orientation; the flow's coherence says how clearly
        s = view_samples(union, normals, v, sample_labels=(HAIR,), min_cos=-1.0)
        px, _ = v.camera.project(means)
        px = np.where(np.isfinite(px), px, -1.0)
        coh = lookup(coherence, px)
        w = float(v.sharpness) * (_multiview.REFERENCE_WEIGHT if v.reference else 1.0) * coh
        w = np.where(s.seen[hair_rows] & (coh >= MIN_COHERENCE), w, 0.0)
        f2 = np.stack([lookup(flow[..., 0], px), lookup(flow[..., 1], px)], axis=1)
        planes.append(direction_planes(means, f2, v.camera))
        weights.append(w)
        per_view.append(int((w > 0).sum()))
    current = unit_vectors(np.asarray(current, np.float64))
    if not planes:
        return current, np.zeros(len(means), bool), {"views_with_flow": 0}
    planes, weights = np.stack(planes), np.stack(weights)
    used = (weights > 0).sum(axis=0) >= min_views
    out = current.copy()
    if used.any():
        out[used] = solve_directions(planes[:, used], weights[:, used], current[used], prior_weight)
    turn = np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", out[used], current[used])), 0, 1)))
    info = {"views_with_flow": len(planes), "per_view": per_view, "from_views": int(used.sum()), "of": len(means),
            "median_turn_deg": round(float(np.median(turn)), 2) if len(turn) else 0.0}
    return out, used, info


def strand_axes(gaussians: GaussianSet) -> np.ndarray:
    """(N, 3) each Gaussian's first axis (a strand segment's direction)."""
    return quat_to_matrix(gaussians.quats.astype(np.float64))[:, :, 0]


def orient_hair(hair: GaussianSet, directions: np.ndarray, rows: np.ndarray) -> GaussianSet:
    """The hair with the first axis of Gaussians `rows` (N,) bool turned onto directions (N, 3)
    (rows elsewhere ignored); the third axis stays as near the old one as it can (out of the
    scalp), scales, colours and the other Gaussians unchanged."""
    rows = np.asarray(rows, bool)
    if not rows.any():
        return hair
    rot = quat_to_matrix(hair.quats[rows].astype(np.float64))
    t = unit_vectors(np.asarray(directions, np.float64)[rows])
    nrm = rot[:, :, 2] - np.einsum("ij,ij->i", rot[:, :, 2], t)[:, None] * t
    # the old third axis along the new direction: take the old second axis instead
    flat = np.linalg.norm(nrm, axis=1) < 1e-3
    nrm[flat] = np.cross(t[flat], rot[flat, :, 1])
    nrm = unit_vectors(nrm)
    new = np.stack([t, np.cross(nrm, t), nrm], axis=2)
    quats = hair.quats.copy()
    quats[rows] = matrix_to_quat(new).astype(np.float32)
    return hair.replace(quats=quats)


def orient_from_views(bald: GaussianSet, hair: GaussianSet, views: list[View], sdf, scale_px: float):
    """The video build's step: hair re-oriented from every view (`strand_directions` with the
    head SDF's normals, `orient_hair`). Returns (hair, info)."""
    if len(hair) == 0 or len(views) < 2:
        return hair, {"from_views": 0, "of": len(hair)}
    union = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    _, normals = sdf.query(union.means)
    rows = np.zeros(len(union), bool)
    rows[len(bald):] = True
    dirs, used, info = strand_directions(union, normals, rows, strand_axes(hair), views, scale_px)
    return orient_hair(hair, dirs, used), info


__all__ = ["MIN_COHERENCE", "MIN_VIEWS", "PRIOR_WEIGHT", "direction_planes", "fibonacci_sphere", "orient_from_views",
           "orient_hair", "solve_directions", "solve_directions_reference", "strand_axes", "strand_directions",
           "view_flow"]
