"""Fitting a head model to face-mesh landmarks: the core the portrait build (`recon.fit`) and
the video tracker (`track/`) share.

Camera and frames are `recon.fit`'s: a pinhole (focal `f` px, principal point at the image
centre), the head in its rest frame, posed by (rotation (3,) axis-angle, translation (3,)) into
a view frame looking down -Z with +Y up; OpenCV camera = diag(1, -1, -1) @ view.

Model side. Landmark k is the barycentric point `LandmarkEmbedding` gives on the model's
triangles, on the mesh
    v = template + shapedirs @ shape + exprdirs @ expr,
then turned about the jaw joint by `jaw` (axis-angle) with the model's skinning weight to the
jaw (LBS with every other joint at rest; the head's global pose is the camera's). FLAME's pose
correctives are left out (millimetres around the jaw).

What `fit_landmarks` minimises, in units of the eye distance `iod` (pixels), with
`LandmarkTargets` weights w_k:
    sum_k w_k |pi(X_k) - x_k|^2 / sum_k w_k                      (points)
  where a point on the face outline (`FACE_OVAL`) counts only across the outline
  (its residual projected on the outline's normal n_k), and its weight is scaled by
  `outline_weight` (default `OUTLINE_WEIGHT`): the outline of a face in a photo is its
  silhouette, which slides over the head's surface as the head turns, so the fixed
  correspondence holds only across it, and even there only roughly;
  + depth_weight * mean_k ((d_k - mean d) - (z_k - mean z))^2    (relative depth, weak)
  where d_k = f (Zcam_k - mean Zcam) / mean Zcam is the model's depth in pixels and z_k the
  face mesh's z;
  + shape_prior |shape|^2 + expr_prior |expr|^2 + jaw_prior |jaw|^2  (coefficients are in
  standard deviations).
`fit_landmarks` runs by default without the depth term and with the outline at a tenth of the
inner points' weight (`FIT_DEPTH_WEIGHT`, `OUTLINE_WEIGHT`). Measured on shaded renders of the
template with known pose (`benchmarks/face.py`; 12 cases of seed 0 and 12 held-out ones of seed
1): the solvePnP start (inner points, no depth) reads the pose to 2.01 / 2.07 deg median, and
the fit with the depth term (0.05) and full-weight outline moved it to 2.69 / 3.89 deg. The
face mesh's z and its outline both carry the pose with a bias the inner points do not; without
the depth term 2.27 / 2.33, with the outline also at 0.1 1.77 / 2.00 (at 0 1.81 / 1.95; a
tenth keeps the outline's hold on the face's width). The build's portrait fit
(`recon.fit.fit_head`) keeps `DEPTH_WEIGHT` in its own objective.
The start is OpenCV's solvePnP on the rest model's landmarks (no guess of the pose needed);
then L-BFGS (torch, float64) on the pose, then on everything asked for.

For a video (issue 16): identity fixed (`fit_shape=False`, `shape=` the build's), per frame
`fit_landmarks(..., expr_components=E, fit_jaw=True, start=previous frame's LandmarkFit)`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avatarkit.face.correspondence import FACE_OVAL, LandmarkEmbedding

_CV = np.diag([1.0, -1.0, -1.0])
JAW_JOINT = 2
#: default weights of the objective (module docstring); DEPTH_WEIGHT is `landmark_loss`'s (the
#: build's portrait fit), FIT_DEPTH_WEIGHT and OUTLINE_WEIGHT `fit_landmarks`'
DEPTH_WEIGHT = 0.05
FIT_DEPTH_WEIGHT = 0.0
OUTLINE_WEIGHT = 0.1
SHAPE_PRIOR = 1e-3
EXPR_PRIOR = 1e-3
JAW_PRIOR = 1e-2
#: `fit_landmarks`' view correction (`face.view_correction.resolve`): off. On the shaded template
#: stills of benchmarks/face.py (seeds 0-2, 36 cases) the full correction brings the reprojection
#: from 1.98 to 0.78 px but the rotation from 2.25 to 2.51 deg (it over-corrects the pitch there:
#: signed error -0.15 -> +0.15 x pitch), and on the avatar built from samples/portrait.jpg
#: 10.20 -> 11.41 deg (docs/face.md, Figures).
FIT_VIEW_CORRECTION = None


@dataclass(eq=False)
class LandmarkTargets:
    """What the face mesh saw, for the landmarks of an embedding (row k = embedding row k).

    xy: (K, 2) pixels; z: (K,) face-mesh depth in pixels (smaller = nearer); weight: (K,);
    normal: (K, 2) unit normal of the face outline for outline points, zeros elsewhere;
    iod: pixels between the eye centres (the unit of the objective); size: (width, height).
    """

    xy: np.ndarray
    z: np.ndarray
    weight: np.ndarray
    normal: np.ndarray
    iod: float
    size: tuple[int, int]

    @classmethod
    def from_mesh(cls, mesh, embedding: LandmarkEmbedding, size: tuple[int, int],
                  weights: dict[int, float] | None = None) -> "LandmarkTargets":
        """Targets from a `FaceMesh` (468 points). weights: mesh index -> weight (default 1)."""
        pts = np.asarray(mesh.points, np.float64)
        idx = embedding.mesh_index
        normal = np.zeros((len(idx), 2))
        oval = list(FACE_OVAL)
        pos = {m: i for i, m in enumerate(oval)}
        for k, m in enumerate(idx):
            if m in pos:
                i = pos[int(m)]
                tangent = pts[oval[(i + 1) % len(oval)], :2] - pts[oval[i - 1], :2]
                n = np.array([-tangent[1], tangent[0]])
                normal[k] = n / max(np.linalg.norm(n), 1e-9)
        w = np.ones(len(idx))
        for m, v in (weights or {}).items():
            w[idx == m] = v
        eyes = np.asarray(mesh.iris_centers, np.float64)
        iod = float(np.linalg.norm(eyes[1] - eyes[0]))
        if not iod > 1.0:   # irises on top of each other: a profile; use the outer eye corners
            iod = max(float(np.linalg.norm(pts[263, :2] - pts[33, :2])), 1.0)
        return cls(pts[idx, :2], pts[idx, 2], w, normal, iod, (int(size[0]), int(size[1])))


@dataclass(eq=False)
class LandmarkFit:
    """rotation (3,), translation (3,) (view frame, module docstring); shape (S,), expr (E,),
    jaw (3,) float64; focal px; errors: (K,) pixels between the fitted model's projected
    landmarks and the targets (across the outline only for outline points); loss terms."""

    rotation: np.ndarray
    translation: np.ndarray
    shape: np.ndarray
    expr: np.ndarray
    jaw: np.ndarray
    focal: float
    errors: np.ndarray
    loss: dict = field(default_factory=dict)

    @property
    def median_error(self) -> float:
        return float(np.median(self.errors))


class LandmarkModel:
    """The landmark points of a head model as a differentiable function of (shape, expr, jaw).

    Only the vertices of the embedding's triangles are evaluated."""

    def __init__(self, model, embedding: LandmarkEmbedding):
        self.model = model
        self.embedding = embedding
        corners = np.asarray(model.faces)[embedding.face_idx]            # (K, 3)
        self.used, inverse = np.unique(corners.ravel(), return_inverse=True)
        self.corner_rows = inverse.reshape(-1, 3)                          # (K, 3) rows of `used`
        self.bary = np.asarray(embedding.bary, np.float64)
        self.offset = None if embedding.offset is None else np.asarray(embedding.offset, np.float64)
        u = self.used
        self.template = model.v_template[u].astype(np.float64)            # (U, 3)
        self.shapedirs = model.shapedirs[u].astype(np.float64)            # (U, 3, S)
        self.exprdirs = model.exprdirs[u].astype(np.float64)              # (U, 3, E)
        self.jaw_weight = model.weights[u, JAW_JOINT].astype(np.float64) if model.weights.shape[1] > JAW_JOINT \
            else np.zeros(len(u))
        # the jaw joint is regressed from the whole shaped mesh: linear in shape and expression
        jr = model.J_regressor
        row = np.asarray(jr[JAW_JOINT].toarray()).ravel() if hasattr(jr, "toarray") else np.asarray(jr[JAW_JOINT])
        V = model.num_vertices
        self.jaw_joint = row @ model.v_template.astype(np.float64)
        self.jaw_joint_shape = np.einsum("v,vdk->dk", row, model.shapedirs.astype(np.float64)) \
            if model.num_shape else np.zeros((3, 0))
        self.jaw_joint_expr = np.einsum("v,vdk->dk", row, model.exprdirs.astype(np.float64)) \
            if model.num_expr else np.zeros((3, 0))
        # the jaw's pose correctives (posedirs rows 9..17: FLAME's own, and a subject's learned
        # `head.jaw_corrective`): (U, 3, 9) per unit of vec(R_jaw - I), None when all zero
        self.jaw_pose = None
        pd = getattr(model, "posedirs", None)
        if pd is not None and model.num_joints == 5:
            jp = np.asarray(pd[9:18], np.float64).reshape(9, V, 3)[:, u].transpose(1, 2, 0)
            if np.any(jp):
                self.jaw_pose = np.ascontiguousarray(jp)
        del V

    def points(self, shape=None, expr=None, jaw=None):
        """(K, 3) torch float64 landmarks in the rest frame; shape (k,), expr (e,), jaw (3,)
        tensors (leading coefficients; None = zeros)."""
        import torch

        from avatarkit.head.lbs import axis_angle_to_matrix_torch

        t = lambda a: torch.from_numpy(a)
        v = t(self.template)
        joint = t(self.jaw_joint)
        if shape is not None and len(shape):
            k = len(shape)
            v = v + t(self.shapedirs[:, :, :k]) @ shape
            joint = joint + t(self.jaw_joint_shape[:, :k]) @ shape
        if expr is not None and len(expr):
            e = len(expr)
            v = v + t(self.exprdirs[:, :, :e]) @ expr
            joint = joint + t(self.jaw_joint_expr[:, :e]) @ expr
        r = axis_angle_to_matrix_torch(jaw) if jaw is not None else None
        if r is not None and self.jaw_pose is not None:
            v = v + t(self.jaw_pose) @ (r - torch.eye(3, dtype=r.dtype)).reshape(9)
        if r is not None:
            turned = (v - joint) @ r.T + joint
            w = t(self.jaw_weight)[:, None]
            v = v + w * (turned - v)
        tri = v[torch.from_numpy(self.corner_rows)]                     # (K, 3, 3)
        out = (t(self.bary)[:, :, None] * tri).sum(1)
        if self.offset is not None:
            # an offset rides on its point: turned by the jaw at the point's jaw weight
            off = t(self.offset)
            if r is not None:
                wk = (t(self.bary) * t(self.jaw_weight)[torch.from_numpy(self.corner_rows)]).sum(1)[:, None]
                off = off + wk * (off @ r.T - off)
            out = out + off
        return out

    def points_numpy(self, shape=None, expr=None, jaw=None) -> np.ndarray:
        import torch

        f = lambda a: None if a is None else torch.as_tensor(np.asarray(a, np.float64))
        with torch.no_grad():
            return self.points(f(shape), f(expr), f(jaw)).numpy()


def project_torch(points, rotation, translation, focal: float, size):
    """Rest-frame points (K, 3) -> pixels (K, 2) and camera depth (K,) (torch)."""
    import torch

    from avatarkit.head.lbs import axis_angle_to_matrix_torch

    r = axis_angle_to_matrix_torch(rotation)
    c = (points @ r.T + translation) @ torch.from_numpy(_CV).T
    z = c[:, 2].clamp_min(1e-4)
    w, h = size
    return torch.stack([focal * c[:, 0] / z + w / 2, focal * c[:, 1] / z + h / 2], dim=1), z


def landmark_loss(px, depth, targets: LandmarkTargets, focal: float, depth_weight: float | None = None):
    """The image terms of the objective (module docstring) as a dict of torch scalars.
    px: (K, 2) projected model landmarks; depth: (K,) their camera depths."""
    depth_weight = DEPTH_WEIGHT if depth_weight is None else depth_weight
    import torch

    t = lambda a: torch.from_numpy(np.asarray(a, np.float64))
    d = (px - t(targets.xy)) / targets.iod
    n = t(targets.normal)
    across = (d * n).sum(1)
    outline = n.abs().sum(1) > 0
    r2 = torch.where(outline, across ** 2, (d ** 2).sum(1))
    w = t(targets.weight)
    out = {"points": (w * r2).sum() / w.sum().clamp_min(1e-9)}
    if depth_weight > 0:
        zm = depth.mean()
        model_z = focal * (depth - zm) / zm
        mesh_z = t(targets.z) - float(np.mean(targets.z))
        out["depth"] = depth_weight * (((model_z - mesh_z) / targets.iod) ** 2).mean()
    return out


def pixel_errors(px: np.ndarray, targets: LandmarkTargets) -> np.ndarray:
    """(K,) pixels: full distance, or across the outline for outline points."""
    d = np.asarray(px) - targets.xy
    across = np.abs((d * targets.normal).sum(1))
    outline = np.abs(targets.normal).sum(1) > 0
    return np.where(outline, across, np.linalg.norm(d, axis=1))


def with_outline_weight(targets: LandmarkTargets, outline_weight: float) -> LandmarkTargets:
    """The same targets with the outline points' weights scaled by outline_weight."""
    outline = np.abs(targets.normal).sum(1) > 0
    return LandmarkTargets(targets.xy, targets.z, np.where(outline, outline_weight, 1.0) * targets.weight,
                           targets.normal, targets.iod, targets.size)


def initial_pose(points: np.ndarray, targets: LandmarkTargets, focal: float) -> tuple[np.ndarray, np.ndarray]:
    """(rotation (3,), translation (3,)) from OpenCV's solvePnP of rest-frame landmarks
    (K, 3) against the targets (outline points left out: they slide)."""
    import cv2
    from scipy.spatial.transform import Rotation

    inner = np.abs(targets.normal).sum(1) == 0
    w, h = targets.size
    k = np.array([[focal, 0, w / 2], [0, focal, h / 2], [0, 0, 1.0]])
    obj = np.ascontiguousarray(points[inner], np.float64)
    img = np.ascontiguousarray(targets.xy[inner], np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_EPNP)
    # OpenCV camera = C @ view frame, C = diag(1, -1, -1): R = C R_cv, t = C t_cv
    rotation = Rotation.from_matrix(_CV @ cv2.Rodrigues(rvec)[0]).as_rotvec()
    return rotation, (_CV @ tvec.reshape(3))


_UNSET = object()  # view_correction's default: FIT_VIEW_CORRECTION read at call time (None is a value: off)


def fit_landmarks(model, embedding: LandmarkEmbedding, targets: LandmarkTargets, focal: float, *,
                  shape=None, fit_shape: bool = True, shape_components: int | None = None,
                  expr_components: int = 0, fit_jaw: bool = False, start: LandmarkFit | None = None,
                  iterations: int = 60, depth_weight: float | None = None,
                  outline_weight: float | None = None, shape_prior: float | None = None,
                  expr_prior: float | None = None, jaw_prior: float | None = None,
                  landmark_model: LandmarkModel | None = None,
                  view_correction=_UNSET) -> LandmarkFit:
    """Pose (and shape / expression / jaw, as asked) of `model` from landmark targets.

    shape: (S,) identity to start from (fit_shape=True) or keep (False); shape_components:
    leading identity coefficients fitted (default all); expr_components: leading expression
    coefficients fitted (0: none); fit_jaw: the jaw's rotation; start: a previous fit to start
    from (a video's previous frame) instead of solvePnP. landmark_model: reuse one across calls
    (video). outline_weight: scales the outline points' weights (1: as the targets say).
    view_correction: None (off, the default: `FIT_VIEW_CORRECTION`), "full" (the built-in
    correction, when the embedding is the template's; else none), "dynamic" (its part that
    moves with the view) or a `face.view_correction.ViewCorrection`: each model landmark is
    moved by the correction at the pose and jaw being fitted (a function of the parameters,
    differentiated through), so the model predicts where the face mesh reads the point from
    this view.
    Returns a `LandmarkFit` (its errors: every point, the outline's across it, unweighted).
    """
    depth_weight = FIT_DEPTH_WEIGHT if depth_weight is None else depth_weight
    outline_weight = OUTLINE_WEIGHT if outline_weight is None else outline_weight
    shape_prior = SHAPE_PRIOR if shape_prior is None else shape_prior
    expr_prior = EXPR_PRIOR if expr_prior is None else expr_prior
    jaw_prior = JAW_PRIOR if jaw_prior is None else jaw_prior
    view_correction = FIT_VIEW_CORRECTION if view_correction is _UNSET else view_correction
    import torch

    from avatarkit.lbfgs import LBFGS
    from avatarkit.recon.fit import torch_single_thread

    from avatarkit.face.view_correction import resolve

    lm = landmark_model or LandmarkModel(model, embedding)
    correction = resolve(view_correction, embedding)
    if outline_weight != 1.0:
        targets = with_outline_weight(targets, outline_weight)
    S, E = model.num_shape, model.num_expr
    shape0 = np.zeros(S) if shape is None else np.asarray(shape, np.float64).reshape(-1)[:S]
    shape0 = np.concatenate([shape0, np.zeros(S - len(shape0))])
    k = (S if shape_components is None else max(0, min(S, int(shape_components)))) if fit_shape else 0
    e = max(0, min(E, int(expr_components)))
    expr0 = np.zeros(E) if start is None else np.concatenate([start.expr, np.zeros(E)])[:E]
    jaw0 = np.zeros(3) if start is None else np.asarray(start.jaw, np.float64)
    if start is not None:
        rot0, trans0 = np.asarray(start.rotation, np.float64), np.asarray(start.translation, np.float64)
    else:
        rot0, trans0 = initial_pose(lm.points_numpy(shape0), targets, focal)
    depth0 = max(-float(trans0[2]), 1e-3)

    f64 = lambda a: torch.tensor(np.asarray(a, np.float64), dtype=torch.float64)
    rot = f64(rot0).requires_grad_(True)
    dtrans = torch.zeros(3, dtype=torch.float64, requires_grad=True)   # in units of the distance
    dshape = torch.zeros(k, dtype=torch.float64, requires_grad=True)
    dexpr = torch.zeros(e, dtype=torch.float64, requires_grad=True)
    jaw = f64(jaw0).requires_grad_(True)
    base_shape, base_expr, base_trans = f64(shape0), f64(expr0), f64(trans0)
    centre = lm.points_numpy(shape0).mean(0)     # the head's centre for the view's direction

    def current():
        s = base_shape.clone()
        if k:
            s = torch.cat([s[:k] + dshape, s[k:]])
        x = base_expr.clone()
        if e:
            x = torch.cat([x[:e] + dexpr, x[e:]])
        return s, x

    def losses():
        s, x = current()
        pts = lm.points(s, x, jaw if (fit_jaw or np.any(jaw0)) else None)
        trans = base_trans + depth0 * dtrans
        if correction is not None:
            from avatarkit.head.lbs import axis_angle_to_matrix_torch

            pts = pts + correction.posed_offsets_torch(axis_angle_to_matrix_torch(rot), trans, jaw[0], centre)
        px, z = project_torch(pts, rot, trans, focal, targets.size)
        out = landmark_loss(px, z, targets, focal, depth_weight)
        if k:
            out["shape_prior"] = shape_prior * (s[:k] ** 2).sum()
        if e:
            out["expr_prior"] = expr_prior * (x[:e] ** 2).sum()
        if fit_jaw:
            out["jaw_prior"] = jaw_prior * (jaw ** 2).sum()
        return out, px

    def run(params):
        opt = LBFGS(params, lr=1.0, max_iter=iterations, line_search_fn="strong_wolfe",
                                tolerance_grad=1e-10, tolerance_change=1e-13, history_size=20)

        def closure():
            opt.zero_grad()
            loss = sum(losses()[0].values())
            loss.backward()
            return loss
        opt.step(closure)

    with torch_single_thread():
        run([rot, dtrans])
        rest = [p for p, on in ((dshape, k), (dexpr, e), (jaw, fit_jaw)) if on]
        if rest:
            run([rot, dtrans] + rest)
        with torch.no_grad():
            terms, px = losses()
            s, x = current()
    return LandmarkFit(rot.detach().numpy().copy(), (trans0 + depth0 * dtrans.detach().numpy()).copy(),
                       s.numpy().copy(), x.numpy().copy(), jaw.detach().numpy().copy(), float(focal),
                       pixel_errors(px.numpy(), targets), {n: float(v) for n, v in terms.items()})
