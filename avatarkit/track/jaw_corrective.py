"""Learn a subject's jaw corrective from a tracked video: how the mouth opens beyond the model.

Why: a head model's mouth opens as its template's does. On the grey clip the man's lower lip
drops about twice as far as the template's for the same jaw rotation (the widest frames: his
outer lower lip 13-15 px below the fitted one while the chin is matched to 2 px), so the avatar
shows a half-open mouth. One photo cannot know how a person's mouth opens; a talking video
shows it (docs/video-build.md, "The mouth's corrective").

What (`fit_jaw_corrective` over a `TrackResult`; the video build's `fit_avatar_corrective`
tracks the video with the built avatar first, so the corrective is learned on the head and
identity it will be driven with):

1. Residuals. Every frame with a face is fitted by the tracker's objective (`solve.fit_frame`,
   warm-started frame to frame as `track.tracker` does) with the head model carrying the
   current corrective and WITHOUT the lips' landmarks (`LIPS_FIT_WEIGHT`): the head, jaw and
   expression are read from the rest of the face (the chin below the lip says how far the jaw
   opened), so the lips' residuals are all of what the model lacks. With them in, the fit
   opened the jaw further to chase the lip (a known drop: the opening read 1.28x, and only
   ~40 % of the drop was left in the residuals per round). Without every landmark within
   `MOUTH_RADIUS` (the chin's front too) the grey clip's jaw read less than half open (95th
   percentile 0.074 against 0.17 rad) and the lower lip's slope came out 3x. Each mouth
   landmark's pixel residual is carried into the head's frame at its depth (as
   `solve.landmark_offsets` does for its static offsets), the part of it the frame sees: the
   two directions across the frame's view.
2. Slopes. Per mouth landmark, the residual is fitted as a + s D (+ q Y, `POSE_TERMS`) over
   the frames: a a static offset (what the tracker's per-landmark calibration holds), s =
   `head.jaw_corrective.opening_feature` of the frame's fitted jaw (sin of the opening), D (3,)
   the landmark's motion per unit of opening that the model lacks, q the head's turn from its
   median (axis-angle; with its products, `POSE_DEGREE`) and Y the face mesh's view-dependent
   reading; each frame constrains only what it sees (least squares over the frames' view
   planes), a ridge `SLOPE_RIDGE` holds D and Y at zero where the jaw or the head hardly moves.
   The landmark's jaw weight is undone (the corrective moves the vertex before the jaw turns it).
   The guard: a landmark's D is kept only where the frames support it (`supported_slopes`:
   Hotelling's T^2 of D against the scatter of the D fitted with one block of `SLOPE_BLOCK`
   frames left out, F test at `SLOPE_LEVEL`), else zero. The face mesh's reading errors are
   correlated in time and move the chin (so the fitted opening) and the lips together: without
   the guard the sample avatar turning (a mouth that never moves) taught 17 mm at 0.3 rad, the
   template rendered talking (a mouth that opens as the model's) 21 mm.
3. Spread. The landmarks' D become a vertex field (`spread`): a membrane over the vertices
   within `SPREAD_REACH` of a fitted landmark that meets the landmarks' D (least squares) and
   is pinned to zero at the region's edge; its edges between vertices apart in jaw weight are
   weak (`SPREAD_JAW`), so the lower lip's drop does not pull the upper lip across the mouth's
   crease. Every vertex beyond the region gets exactly zero.

Steps 1-3 are repeated `ROUNDS` times (each adds to the corrective: the fit's jaw and
expression give back what they took of the mouth's opening). The corrective is a
`head.jaw_corrective.JawCorrective` on the opening feature only; zero at jaw 0.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from avatarkit.head.jaw_corrective import JawCorrective, apply_jaw_corrective, opening_feature

#: the landmarks whose residuals are fitted: not on the face's outline, within this many metres
#: of the lips' centre (lips, the skin around them, the chin's front)
MOUTH_RADIUS = 0.03
#: ridge on a landmark's slope, as this much rms opening (sin) more in every frame: a video whose
#: jaw does not move learns nothing
SLOPE_RIDGE = 0.02
#: the spread reaches this far (metres) from the fitted landmarks; its membrane's stiffness and
#: how far apart in jaw weight two vertices are before their edge stops carrying the field
SPREAD_REACH = 0.015
SPREAD_SMOOTH = 0.05
SPREAD_JAW = 0.3
#: the lips' landmarks' weight in the frames' fits that measure the residuals (0: the head and
#: jaw read from the rest of the face only)
LIPS_FIT_WEIGHT = 0.0
#: fit, spread and refit this many times (each round takes up part of what the last left: the
#: chin below the lip, kept in the frames' fits, gives back part of the drop as jaw opening)
ROUNDS = 3
#: fit each landmark's residual with terms in the head's turn too (`supported_slopes`): linear
#: (POSE_DEGREE 1) or linear and quadratic (2)
POSE_TERMS = True
POSE_DEGREE = 2
#: fewer frames with a face than this: no corrective
MIN_FRAMES = 20
#: a landmark's slope is kept only where the video supports it (`supported_slopes`): its Hotelling
#: T^2 against the scatter of the slopes fitted with one block of `SLOPE_BLOCK` consecutive
#: frames left out must pass the F test at `SLOPE_LEVEL`; SLOPE_BLOCK None: every slope kept.
#: 16 frames: the shared clips' mouth residuals stay correlated for ~12-14 frames (lag-8
#: autocorrelation 0.41-0.47, first below 0.2 at lag 12), so shorter blocks are not independent
SLOPE_BLOCK: int | None = 16
SLOPE_LEVEL = 0.99


@dataclass
class CorrectiveFit:
    """corrective: the learned `JawCorrective` (None: too few frames); figures: what the report
    says (frames used, the opening's range, per round the mouth landmarks' rms residual in px)."""

    corrective: JawCorrective | None
    figures: dict = field(default_factory=dict)


def mouth_rows(embedding, rest_points: np.ndarray, radius: float | None = None) -> np.ndarray:
    """Indices of the embedding's rows fitted (module docstring): not on the face outline and
    within `radius` of the outer lips' centre; rest_points (K, 3)."""
    radius = MOUTH_RADIUS if radius is None else radius
    from avatarkit.face.correspondence import FACE_OVAL, LIPS_OUTER

    idx = np.asarray(embedding.mesh_index)
    lips = np.isin(idx, LIPS_OUTER)
    if not lips.any():
        return np.zeros(0, np.int64)
    centre = rest_points[lips].mean(0)
    near = np.linalg.norm(rest_points - centre, axis=1) <= radius
    return np.flatnonzero(near & ~np.isin(idx, FACE_OVAL))


def landmark_jaw_weights(lm) -> np.ndarray:
    """(K,) each landmark's jaw weight (`face.fit.LandmarkModel`)."""
    return (lm.bary * lm.jaw_weight[lm.corner_rows]).sum(1)


def view_residuals(problem, fit, targets, focal: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame's landmark residuals carried into the head's frame (K, 3) metres (zero along
    the view's depth), the (3, 3) projector onto the plane the frame sees, in that frame, and
    the residuals' lengths in pixels (K,)."""
    from avatarkit.track.solve import _rodrigues

    w, h = targets.size
    Rb = _rodrigues(np.asarray(fit.rotation, np.float64)[None])
    t = np.asarray(fit.translation, np.float64)
    pts = problem.posed_points(np.asarray(fit.expr, np.float64)[None], np.asarray(fit.jaw, np.float64)[None],
                               Rb, t[None])[0]
    R = Rb[0]
    cam = pts @ R.T + t
    cam[:, 1:] *= -1.0                                              # OpenCV axes
    z = np.maximum(cam[:, 2], 1e-4)
    px = np.stack([focal * cam[:, 0] / z + w / 2, focal * cam[:, 1] / z + h / 2], axis=1)
    d = np.zeros((len(pts), 3))
    d[:, :2] = (targets.xy - px) * (z / focal)[:, None]
    rest = (d * np.array([1.0, -1.0, -1.0])) @ R                    # view frame -> head: R^T
    plane = R.T @ np.diag([1.0, 1.0, 0.0]) @ R
    return rest, plane, np.linalg.norm(targets.xy - px, axis=1)


def landmark_slopes(residuals: np.ndarray, planes: np.ndarray, opening: np.ndarray, jaw: np.ndarray,
                    jaw_weight: np.ndarray, ridge: float | None = None, pose: np.ndarray | None = None
                    ) -> np.ndarray:
    """(K, 3) each landmark's motion per unit of opening beyond the model (module docstring,
    step 2); the arguments as `supported_slopes`', untested."""
    ridge = SLOPE_RIDGE if ridge is None else ridge
    return supported_slopes(residuals, planes, opening, jaw, jaw_weight, ridge, pose)[0]


def supported_slopes(residuals: np.ndarray, planes: np.ndarray, opening: np.ndarray, jaw: np.ndarray,
                     jaw_weight: np.ndarray, ridge: float | None = None, pose: np.ndarray | None = None,
                     blocks: np.ndarray | None = None, level: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """(K, 3) each landmark's motion per unit of opening beyond the model (module docstring,
    step 2). residuals (T, K, 3) head frame; planes (T, 3, 3) the frames' view projectors;
    opening (T,); jaw (T, 3) axis-angle; jaw_weight (K,); pose (T, 3) the frames' head
    rotations (axis-angle) or None: with them, each landmark's residual may also move linearly
    with the head's turn away from its median (three more 3-vectors, as ridge-held as the
    slope), so the face mesh's view-dependent reading (docs/face.md) does not pass for a jaw
    corrective where the fitted opening moves with the turn.

    With `POSE_DEGREE` 2 the turn's terms are quadratic too (six more 3-vectors): over the
    synthetic video's 85 degrees of turn the face mesh's bias is not linear in it, while over a
    talking clip's few degrees the products hardly move and the ridge holds them at zero.

    blocks (T,) the frames' block numbers (contiguous runs of frames) or None: with them, each
    landmark's slope is tested (`slope_statistic`) and set to zero unless the data support it
    at `level` (None: `SLOPE_LEVEL`). Returns the slopes (K, 3), each landmark's statistic (K,)
    (zeros untested) and the threshold it had to pass (inf untested: fewer than 5 blocks tests
    nothing)."""
    ridge = SLOPE_RIDGE if ridge is None else ridge
    from avatarkit.track.solve import _rodrigues

    T, K, _ = residuals.shape
    Rj = _rodrigues(np.asarray(jaw, np.float64)) - np.eye(3)                 # (T, 3, 3)
    q = np.zeros((T, 0)) if pose is None else np.asarray(pose, np.float64) - np.median(pose, axis=0)
    if POSE_DEGREE >= 2 and q.shape[1]:
        q = np.concatenate([q, np.stack([q[:, i] * q[:, j] for i in range(3) for j in range(i, 3)], 1)], 1)
    Q = q.shape[1]
    P = 6 + 3 * Q
    out, stat = np.zeros((K, 3)), np.zeros(K)
    lam = np.diag([1e-6] * 3 + [ridge ** 2] * (3 + 3 * Q))                      # per frame
    ids = None if blocks is None else np.unique(np.asarray(blocks), return_inverse=True)[1]
    nb = 0 if ids is None else int(ids.max()) + 1
    threshold = slope_threshold(nb, SLOPE_LEVEL if level is None else level)
    for k in range(K):
        M = np.eye(3) + jaw_weight[k] * Rj                                     # rest -> posed
        G = planes @ M                                                         # (T, 3, 3)
        parts = [G, opening[:, None, None] * G] + [q[:, j, None, None] * planes for j in range(Q)]
        A = np.concatenate(parts, axis=2)                                      # (T, 3, 6 + 3Q)
        Nt = np.einsum("tia,tib->tab", A, A)                                   # per frame
        bt = np.einsum("tia,ti->ta", A, np.einsum("tij,tj->ti", planes, residuals[:, k]))
        out[k] = np.linalg.solve(Nt.sum(0) + T * lam, bt.sum(0))[3:6]
        if np.isfinite(threshold):
            Nb = np.zeros((nb, P, P))
            bb = np.zeros((nb, P))
            np.add.at(Nb, ids, Nt)
            np.add.at(bb, ids, bt)
            counts = np.bincount(ids, minlength=nb)
            held = np.stack([np.linalg.solve(Nt.sum(0) - Nb[j] + (T - counts[j]) * lam, bt.sum(0) - bb[j])[3:6]
                             for j in range(nb)])
            stat[k] = slope_statistic(out[k], held)
            if stat[k] <= threshold:
                out[k] = 0.0
    return out, stat, threshold


def slope_statistic(slope: np.ndarray, held: np.ndarray) -> float:
    """Hotelling's T^2 of a landmark's slope (3,) against its delete-one-block jackknife
    covariance: held (B, 3) the slope fitted with each block of frames left out. The frames'
    errors are correlated in time (the face mesh's reading of one frame is like its
    neighbours'), so the scatter of independent frames would overstate what a video of them
    shows; blocks of frames are nearly independent of each other."""
    B = len(held)
    dev = held - held.mean(0)
    cov = (B - 1) / B * dev.T @ dev
    return float(slope @ np.linalg.solve(cov + 1e-18 * np.eye(3), slope))


def slope_threshold(blocks: int, level: float | None = None) -> float:
    """The T^2 a slope must pass at `level` with `blocks` jackknife blocks: the jackknife
    covariance has blocks - 1 degrees of freedom, so T^2 (blocks - 3) / (3 (blocks - 1)) is
    F(3, blocks - 3) under no slope; inf with fewer than 5 blocks (the test has no power)."""
    if blocks < 5:
        return float("inf")
    from scipy.stats import f

    level = SLOPE_LEVEL if level is None else level
    return float(3 * (blocks - 1) / (blocks - 3) * f.ppf(level, 3, blocks - 3))


def spread(rest_vertices: np.ndarray, faces: np.ndarray, vertex_jaw: np.ndarray, bary_rows: np.ndarray,
           values: np.ndarray, reach: float | None = None, jaw_width: float | None = None,
           smooth: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The vertex field the landmarks' `values` make (module docstring, step 3): over the
    vertices within `reach` of a landmark, the field D minimising
        sum_k |(B D)_k - values_k|^2 + smooth sum_edges w_ab |D_a - D_b|^2
    with D = 0 on every vertex beyond (a membrane pinned to zero at the region's edge). An edge
    between vertices apart in jaw weight is weak (w_ab = exp(-(jw_a - jw_b)^2 / (2 jaw_width^2))),
    so the lower lip's drop does not drag the upper lip across the mouth's crease. A membrane
    keeps the field within the landmarks' values (no overshoot: exact interpolation by
    radial basis functions swung the mouth corners' vertices 3x beyond any landmark, where
    close landmarks disagree); a kernel-weighted mean did not overshoot either but fell short
    of the landmarks (a known drop recovered at ~45 % in three rounds).

    rest_vertices (V, 3); faces (F, 3); vertex_jaw (V,) jaw weights; bary_rows (K, V) the
    landmarks as mixes of vertices; values (K, 3). Returns (vertex_index (n,), field (n, 3))."""
    reach = SPREAD_REACH if reach is None else reach
    jaw_width = SPREAD_JAW if jaw_width is None else jaw_width
    smooth = SPREAD_SMOOTH if smooth is None else smooth
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    centres = bary_rows @ rest_vertices
    d2 = ((rest_vertices[:, None, :] - centres[None]) ** 2).sum(-1)           # (V, K)
    inside = d2.min(1) <= reach ** 2
    region = np.flatnonzero(inside)
    V, n = len(rest_vertices), len(region)
    local = np.full(V, -1)
    local[region] = np.arange(n)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    e = e[inside[e[:, 0]] | inside[e[:, 1]]]
    w = np.exp(-(vertex_jaw[e[:, 0]] - vertex_jaw[e[:, 1]]) ** 2 / (2 * jaw_width ** 2))
    # the membrane's Laplacian over the region; an edge to a vertex outside pins toward zero
    ia, ib = local[e[:, 0]], local[e[:, 1]]
    rows, cols, vals = [], [], []
    for a, b in ((ia, ib), (ib, ia)):
        ok = a >= 0
        rows += [a[ok]]
        cols += [a[ok]]
        vals += [w[ok]]
        both = ok & (b >= 0)
        rows += [a[both]]
        cols += [b[both]]
        vals += [-w[both]]
    L = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    B = sp.csr_matrix(bary_rows[:, region])
    A = (B.T @ B + smooth * L + 1e-9 * sp.identity(n)).tocsc()
    field = np.asarray(spsolve(A, np.asarray(B.T @ values)))
    return region, field.reshape(n, 3)


def _bary_matrix(lm, num_vertices: int, rows: np.ndarray) -> np.ndarray:
    """(len(rows), V) the rows' landmarks as mixes of the model's vertices."""
    B = np.zeros((len(rows), num_vertices))
    corners = lm.used[lm.corner_rows[rows]]                                   # (k, 3) vertex ids
    for c in range(3):
        np.add.at(B, (np.arange(len(rows)), corners[:, c]), lm.bary[rows, c])
    return B


def fit_corrective(model, shape: np.ndarray, embedding, targets: list, focal: float, options=None,
                   rounds: int | None = None) -> CorrectiveFit:
    """The corrective learned from `targets` (one `face.fit.LandmarkTargets` per frame with a
    face, in the video's order; a None entry is a frame without one) for `model` (without a
    corrective) with identity `shape` and the tracker's `embedding` (its calibrated offsets
    included); focal: the tracker's. options: the `TrackOptions` the frames are fitted with."""
    rounds = ROUNDS if rounds is None else rounds
    from avatarkit.face.correspondence import LIPS_INNER, LIPS_OUTER
    from avatarkit.face.fit import LandmarkModel
    from avatarkit.head.model import HeadParams
    from avatarkit.track.tracker import FrameTracker, TrackOptions

    present = [t for t in targets if t is not None]
    if len(present) < MIN_FRAMES:
        return CorrectiveFit(None, {"frames": len(present), "skipped": f"fewer than {MIN_FRAMES} frames with a face"})
    options = options or TrackOptions(focal=focal)
    shape = np.asarray(shape, np.float64).reshape(-1)
    lm0 = LandmarkModel(model, embedding)
    V = model.num_vertices
    params = HeadParams(shape=np.concatenate([shape, np.zeros(max(0, model.num_shape - len(shape)))])[:model.num_shape]
                        .astype(np.float32), expr=np.zeros((1, model.num_expr), np.float32))
    rest = model.forward(params)[0][0].astype(np.float64)
    from avatarkit.track.solve import FrameProblem, rest_points

    rows = mouth_rows(embedding, rest_points(FrameProblem.from_landmark_model(lm0, shape, 0)))
    B = _bary_matrix(lm0, V, rows)
    lips = rows[np.isin(np.asarray(embedding.mesh_index)[rows], LIPS_OUTER + LIPS_INNER)]
    jw_vertex = model.weights[:, 2].astype(np.float64)
    jw_rows = landmark_jaw_weights(lm0)[rows]
    field = np.zeros((V, 3))
    corrective = None
    figures = {"frames": len(present), "landmarks": int(len(rows)), "rounds": []}
    for _ in range(rounds + 1):
        current = apply_jaw_corrective(model, corrective) if corrective is not None else model
        ft = FrameTracker(current, shape, present[0].size, options, embedding)
        res, planes, jaws, err, turns, order = [], [], [], [], [], []
        for i, tg in enumerate(targets):
            if tg is None:
                ft.reset()
                continue
            weight = tg.weight.copy()
            weight[lips] *= LIPS_FIT_WEIGHT
            fit = ft.fit_targets(dataclasses.replace(tg, weight=weight))
            r, p, e = view_residuals(ft.problem, fit, tg, ft.focal)
            res.append(r[rows])
            err.append(e[rows])
            planes.append(p)
            jaws.append(fit.jaw)
            turns.append(fit.rotation)
            order.append(i)
        res, planes, jaws = np.stack(res), np.stack(planes), np.stack(jaws)
        s = opening_feature(jaws)
        err = np.stack(err)
        wide = s >= np.percentile(s, 90)
        figures["rounds"].append({"mouth_rms_px": round(float(np.sqrt((err ** 2).mean())), 3),
                                  "mouth_rms_px_widest_tenth": round(float(np.sqrt((err[wide] ** 2).mean())), 3),
                                  "opening_p5_p95": [round(float(v), 4) for v in np.percentile(s, [5, 95])]})
        if len(figures["rounds"]) > rounds:
            break
        blocks = None if SLOPE_BLOCK is None else np.asarray(order) // SLOPE_BLOCK
        slopes, stat, threshold = supported_slopes(res, planes, s, jaws, jw_rows,
                                                   pose=np.stack(turns) if POSE_TERMS else None, blocks=blocks)
        if blocks is not None:
            figures["rounds"][-1]["slopes_kept"] = [int((stat > threshold).sum()), int(len(stat))]
        near, add = spread(rest, model.faces, jw_vertex, B, slopes)
        field[near] += add
        moved = np.flatnonzero(np.abs(field).sum(1) > 0)
        corrective = JawCorrective.from_opening(moved, field[moved])
    if corrective is not None:
        figures.update(corrective.summary())
    return CorrectiveFit(corrective, figures)


def fit_jaw_corrective(result, rounds: int | None = None, span: tuple[int, int] | None = None) -> CorrectiveFit:
    """`fit_corrective` over a `TrackResult`'s frames with a face (its model, identity, calibrated
    embedding, focal; the face meshes when it kept them, else its stored 2-D points); span:
    [start, end) video frames it may learn from (None: all; `avatarkit evaluate` keeps the
    clip's second half out of the build)."""
    rounds = ROUNDS if rounds is None else rounds
    from avatarkit.face.fit import LandmarkTargets
    from avatarkit.track.joint_identity import targets_from_points
    from avatarkit.track.tracker import TrackOptions

    size = (int(result.camera.width), int(result.camera.height))
    emb = result.embedding
    targets = []
    for t in range(result.num_frames):
        f = int(result.frame_index[t])
        if not result.found[t] or (span is not None and not span[0] <= f < span[1]):
            targets.append(None)
        elif result.meshes is not None and result.meshes[t] is not None:
            targets.append(LandmarkTargets.from_mesh(result.meshes[t], emb, size))
        else:
            targets.append(targets_from_points(result.landmarks[t], emb, size))
    options = TrackOptions(focal=float(result.camera.fx))
    return fit_corrective(result.model, np.asarray(result.clip.shape, np.float64), emb, targets,
                          float(result.camera.fx), options, rounds)


def fit_avatar_corrective(avatar, video, tracking, rounds: int | None = None,
                          span: tuple[int, int] | None = None) -> CorrectiveFit:
    """The corrective for `avatar` (built without one) learned from `video`: the video tracked
    with the avatar's own head model and identity (`track_video(avatar=)`, the face meshes of
    `tracking`, a `TrackResult` of the same video, reused), then `fit_jaw_corrective` over the
    frames in `span` ([start, end) video frames; None: all). Learned
    on the build's own tracking (the template with the tracking's identity) instead, the
    avatar's tracking read the grey clip's jaw 0.21 rad open at the widest frames where that
    one read 0.17, and took back part of the drop (docs/video-build.md)."""
    rounds = ROUNDS if rounds is None else rounds
    from avatarkit.track.video import tracked_with_built_avatar

    with tracked_with_built_avatar(avatar, video, tracking.meshes) as (_, result):
        return fit_jaw_corrective(result, rounds, span)


__all__ = ["CorrectiveFit", "MIN_FRAMES", "SLOPE_BLOCK", "SLOPE_LEVEL", "LIPS_FIT_WEIGHT", "MOUTH_RADIUS", "POSE_TERMS", "ROUNDS", "SLOPE_RIDGE", "SPREAD_JAW", "SPREAD_REACH", "SPREAD_SMOOTH",
           "fit_corrective", "fit_jaw_corrective", "landmark_jaw_weights", "landmark_slopes",
           "mouth_rows", "slope_statistic", "slope_threshold", "spread", "supported_slopes", "view_residuals"]
