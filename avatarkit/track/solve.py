"""The tracker's per-frame fit: `face.fit`'s objective minimised by Levenberg-Marquardt in numpy.

Same model, camera and objective as `face.fit.fit_landmarks` with the identity fixed (see its
module docstring): landmark residuals in eye distances (outline points only across the
outline), the weak relative-depth term, and priors on expression and jaw. Parameters: head
rotation (3, axis-angle, updated additively: frame-to-frame steps are small), translation (3,
metres), jaw (3) and the leading `E` expression coefficients.

Why not the torch L-BFGS of `face.fit`: a video needs ~20 ms a frame, and for ~20 parameters and
~1,000 residuals a Gauss-Newton step with a finite-difference Jacobian evaluated in one batched
numpy pass (all parameter perturbations at once) converges in 2-4 steps from the previous
frame, ~50x faster. `face.fit.fit_landmarks` stays the reference: tests compare the two.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.face import fit as _face_fit
from avatarkit.face.fit import LandmarkFit, pixel_errors

_C = np.diag([1.0, -1.0, -1.0])
_STEP = 1e-6


def _rodrigues(aa: np.ndarray) -> np.ndarray:
    """aa (B, 3) -> (B, 3, 3) rotation matrices (float64)."""
    theta = np.linalg.norm(aa, axis=1)
    small = theta < 1e-12
    k = aa / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(aa), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -k[:, 2], k[:, 1]
    K[:, 1, 0], K[:, 1, 2] = k[:, 2], -k[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], (1 - np.cos(theta))[:, None, None]
    R = np.eye(3) + s * K + c * K @ K
    R[small] = np.eye(3)
    return R


@dataclass
class FrameProblem:
    """One model's per-frame problem reduced to the landmarks (built once per video).

    A landmark is a fixed barycentric mix of vertices, and the jaw blend is linear in the
    vertices, so with B the (K, U) barycentric matrix and w the jaw weights:
        landmark_k = (B v)_k + (R_jaw - I) ((B diag(w) v)_k - (B w)_k j)
    where v = base + exprdirs e and the jaw joint j = j0 + J_e e. Everything is precomputed at
    the K landmarks, so a frame costs O(K E) instead of O(U E)."""

    lm0: np.ndarray           # (K, 3) B base
    lm_expr: np.ndarray       # (K, 3, E) B exprdirs
    jw0: np.ndarray           # (K, 3) B diag(w) base
    jw_expr: np.ndarray       # (K, 3, E) B diag(w) exprdirs
    jw_sum: np.ndarray        # (K,) B w
    jaw_joint: np.ndarray     # (3,) with identity
    jaw_joint_expr: np.ndarray  # (3, E)
    num_expr: int = 0         # the first num_expr coefficients are expressions, the rest shape
    view: object = None       # a `face.view_correction.ViewCorrection` (None: off)
    centre: np.ndarray | None = None   # (3,) the rest landmarks' mean, where the view is seen from
    lm_pose: np.ndarray | None = None  # (K, 3, 9) B jaw posedirs (None: the model has none)
    jw_pose: np.ndarray | None = None  # (K, 3, 9) B diag(w) jaw posedirs

    @classmethod
    def from_landmark_model(cls, lm, shape: np.ndarray, expr_components: int,
                            shape_components: int = 0) -> "FrameProblem":
        """`shape` (S,) is the fixed identity; with shape_components > 0 the leading identity
        coefficients are fitted too (as offsets from `shape`), after the expressions: shape and
        expression are both linear bases, so they share one coefficient vector."""
        S = lm.shapedirs.shape[2]
        s = np.asarray(shape, np.float64).reshape(-1)[:S]
        k = len(s)
        base = lm.template + (lm.shapedirs[:, :, :k] @ s if k else 0.0)          # (U, 3)
        joint = lm.jaw_joint + (lm.jaw_joint_shape[:, :k] @ s if k else 0.0)
        E, F = int(expr_components), int(max(0, min(S, shape_components)))
        K, U = len(lm.bary), len(base)
        B = np.zeros((K, U))
        np.add.at(B, (np.repeat(np.arange(K), 3), lm.corner_rows.ravel()), lm.bary.ravel())
        Bw = B * lm.jaw_weight[None]
        C = E + F
        dirs = np.concatenate([lm.exprdirs[:, :, :E], lm.shapedirs[:, :, :F]], axis=2).reshape(U, 3 * C)
        joint_dirs = np.concatenate([lm.jaw_joint_expr[:, :E], lm.jaw_joint_shape[:, :F]], axis=1)
        lm0, jw0, jw_sum = B @ base, Bw @ base, Bw.sum(1)
        if getattr(lm, "offset", None) is not None:
            # an offset is a constant point added to the landmark, carried by the jaw at the
            # landmark's jaw weight (as `face.fit.LandmarkModel` does)
            lm0 = lm0 + lm.offset
            jw0 = jw0 + jw_sum[:, None] * lm.offset
        lm_pose = jw_pose = None
        if getattr(lm, "jaw_pose", None) is not None:
            # the jaw's pose correctives move the vertices before the jaw turns them, as the
            # expression blendshapes do: linear in vec(R_jaw - I)
            jp = lm.jaw_pose.reshape(U, 27)
            lm_pose, jw_pose = (B @ jp).reshape(K, 3, 9), (Bw @ jp).reshape(K, 3, 9)
        return cls(lm0, (B @ dirs).reshape(K, 3, C), jw0, (Bw @ dirs).reshape(K, 3, C),
                   jw_sum, joint, joint_dirs, E, lm_pose=lm_pose, jw_pose=jw_pose)

    def with_view(self, correction) -> "FrameProblem":
        """The same problem with a view correction (None: without): every landmark moves by
        the correction at the pose and jaw being fitted."""
        import dataclasses

        return dataclasses.replace(self, view=correction, centre=rest_points(self).mean(0))

    def posed_points(self, expr: np.ndarray, jaw: np.ndarray, R: np.ndarray, trans: np.ndarray) -> np.ndarray:
        """(B, K, 3) rest-frame landmarks with the view correction at each pose: expr (B, C),
        jaw (B, 3), R (B, 3, 3) head rotations, trans (B, 3)."""
        pts = self.points(expr, jaw)
        if self.view is not None:
            pts = pts + self.view.posed_offsets(R, trans, jaw[:, 0], self.centre)
        return pts

    @property
    def num_coefficients(self) -> int:
        return self.lm_expr.shape[2]

    def points(self, expr: np.ndarray, jaw: np.ndarray) -> np.ndarray:
        """expr (B, C), jaw (B, 3) -> landmarks (B, K, 3) in the rest frame."""
        B, (K, _, C) = len(expr), self.lm_expr.shape
        # (B, C) @ (C, 3K) products: ~20x faster than the equivalent einsum at these sizes
        lm = self.lm0[None] + (expr @ self.lm_expr.reshape(K * 3, C).T).reshape(B, K, 3)
        jw = self.jw0[None] + (expr @ self.jw_expr.reshape(K * 3, C).T).reshape(B, K, 3)
        joint = self.jaw_joint[None] + expr @ self.jaw_joint_expr.T                   # (B, 3)
        R = _rodrigues(jaw) - np.eye(3)
        if self.lm_pose is not None:
            feat = R.reshape(B, 9)
            lm = lm + (feat @ self.lm_pose.reshape(K * 3, 9).T).reshape(B, K, 3)
            jw = jw + (feat @ self.jw_pose.reshape(K * 3, 9).T).reshape(B, K, 3)
        arm = jw - self.jw_sum[None, :, None] * joint[:, None]                        # (B, K, 3)
        return lm + np.matmul(arm, R.transpose(0, 2, 1))

    def points_reference(self, lm_model, expr: np.ndarray, jaw: np.ndarray, shape: np.ndarray) -> np.ndarray:
        """The same from the vertices (`face.fit.LandmarkModel`), for tests: (K, 3)."""
        return lm_model.points_numpy(shape, expr, jaw)


def _unpack(p: np.ndarray, E: int):
    return p[:, 0:3], p[:, 3:6], p[:, 6:9], p[:, 9:9 + E]


def residuals(problem: FrameProblem, p: np.ndarray, targets, focal: float, depth_weight: float,
              expr_prior: float, jaw_prior: float, shape_prior: float | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """p (B, 9 + E) -> residual vectors (B, M) whose squared sum is the objective, and the
    projected landmarks (B, K, 2)."""
    shape_prior = _face_fit.SHAPE_PRIOR if shape_prior is None else shape_prior
    E = problem.num_expr
    rot, trans, jaw, expr = _unpack(p, problem.num_coefficients)
    R = _rodrigues(rot)
    pts = problem.posed_points(expr, jaw, R, trans)                                 # (B, K, 3)
    cam = np.matmul(pts, R.transpose(0, 2, 1)) + trans[:, None]
    cam[..., 1:] *= -1.0                                                           # OpenCV axes
    z = np.maximum(cam[..., 2], 1e-4)
    w, h = targets.size
    px = np.stack([focal * cam[..., 0] / z + w / 2, focal * cam[..., 1] / z + h / 2], axis=-1)
    d = (px - targets.xy[None]) / targets.iod                                      # (B, K, 2)
    n = targets.normal
    outline = np.abs(n).sum(1) > 0
    wt = np.sqrt(targets.weight / max(targets.weight.sum(), 1e-9))
    across = (d * n[None]).sum(-1)                                                  # (B, K)
    rx = np.where(outline[None], across, d[..., 0]) * wt
    ry = np.where(outline[None], 0.0, d[..., 1]) * wt
    parts = [rx, ry]
    if depth_weight > 0:
        zm = z.mean(axis=1, keepdims=True)
        model_z = focal * (z - zm) / zm
        mesh_z = targets.z - targets.z.mean()
        parts.append(np.sqrt(depth_weight / z.shape[1]) * (model_z - mesh_z[None]) / targets.iod)
    if E:
        parts.append(np.sqrt(expr_prior) * expr[:, :E])
    if expr.shape[1] > E:
        parts.append(np.sqrt(shape_prior) * expr[:, E:])
    parts.append(np.sqrt(jaw_prior) * jaw)
    return np.concatenate(parts, axis=1), px


def project(problem: FrameProblem, rotation, translation, jaw, expr, focal: float,
            size: tuple[int, int]) -> np.ndarray:
    """(K, 2) pixels of one frame's landmarks."""
    R = _rodrigues(np.asarray(rotation, np.float64)[None])
    pts = problem.posed_points(np.asarray(expr, np.float64)[None], np.asarray(jaw, np.float64)[None], R,
                               np.asarray(translation, np.float64)[None])[0]
    cam = pts @ R[0].T + np.asarray(translation, np.float64)
    cam[:, 1:] *= -1.0
    z = np.maximum(cam[:, 2], 1e-4)
    return np.stack([focal * cam[:, 0] / z + size[0] / 2, focal * cam[:, 1] / z + size[1] / 2], axis=1)


def rest_points(problem: FrameProblem) -> np.ndarray:
    """(K, 3) landmarks of the neutral face (no expression, jaw closed)."""
    return problem.points(np.zeros((1, problem.num_coefficients)), np.zeros((1, 3)))[0]


def fit_frame(problem: FrameProblem, targets, focal: float, start: LandmarkFit | None = None,
              initial: tuple[np.ndarray, np.ndarray] | None = None, iterations: int = 8,
              depth_weight: float | None = None, expr_prior: float | None = None,
              jaw_prior: float | None = None, shape: np.ndarray | None = None,
              shape_prior: float | None = None) -> LandmarkFit:
    """Minimise the objective from `start` (the previous frame) or `initial` (rotation,
    translation) with zero expression and jaw. `shape` (S,) is the identity the problem was
    built on; fitted shape coefficients (if the problem has them) are added to it. Returns a
    `LandmarkFit` like `fit_landmarks`."""
    depth_weight = _face_fit.DEPTH_WEIGHT if depth_weight is None else depth_weight
    expr_prior = _face_fit.EXPR_PRIOR if expr_prior is None else expr_prior
    jaw_prior = _face_fit.JAW_PRIOR if jaw_prior is None else jaw_prior
    shape_prior = _face_fit.SHAPE_PRIOR if shape_prior is None else shape_prior
    E, C = problem.num_expr, problem.num_coefficients
    p = np.zeros(9 + C)
    if start is not None:
        p[0:3], p[3:6], p[6:9] = start.rotation, start.translation, start.jaw
        p[9:9 + E] = np.concatenate([np.asarray(start.expr, np.float64), np.zeros(E)])[:E]
    elif initial is not None:
        p[0:3], p[3:6] = initial
    args = (targets, focal, depth_weight, expr_prior, jaw_prior, shape_prior)
    r, px = residuals(problem, p[None], *args)
    cost = float(r[0] @ r[0])
    mu = 1e-3
    P = len(p)
    for _ in range(iterations):
        batch = np.repeat(p[None], P, axis=0) + _STEP * np.eye(P)
        rb, _ = residuals(problem, batch, *args)
        J = (rb - r[0][None]) / _STEP                                   # (P, M): J transposed
        # einsum, not BLAS: OpenBLAS threads spin on matrices this small when the machine is
        # busy (measured: 10x slower per frame under load)
        g = np.einsum("pm,m->p", J, r[0])
        H = np.einsum("pm,qm->pq", J, J)
        improved = False
        for _ in range(6):
            delta = np.linalg.solve(H + mu * np.diag(np.diag(H) + 1e-12), -g)
            r_new, px_new = residuals(problem, (p + delta)[None], *args)
            c_new = float(r_new[0] @ r_new[0])
            if c_new < cost:
                p, r, px = p + delta, r_new, px_new
                converged = cost - c_new < 1e-9 * max(cost, 1e-12)
                cost, mu, improved = c_new, max(mu / 3, 1e-7), True
                break
            mu *= 8
        if not improved or converged:
            break
    rot, trans, jaw, coef = (a[0] for a in _unpack(p[None], C))
    s = np.zeros(C - E) if shape is None else np.asarray(shape, np.float64).copy()
    if C > E:
        s = np.concatenate([s, np.zeros(max(0, C - E - len(s)))])
        s[:C - E] += coef[E:]
    return LandmarkFit(rot.copy(), trans.copy(), s, coef[:E].copy(), jaw.copy(), float(focal),
                       pixel_errors(px[0], targets), {"total": cost})


def landmark_offsets(problem: FrameProblem, fits: list, targets: list, focal: float) -> np.ndarray:
    """(K, 3) rest-frame offsets that move each landmark onto where the face mesh put it, the
    per-landmark median over frames (`fits`, `targets`: one `LandmarkFit` / `LandmarkTargets`
    per frame). A frame's pixel residual is carried back at the landmark's depth into the
    camera's image plane and turned into the head's rest frame by the fitted rotation, so
    each frame constrains the two directions across its view (a frame says nothing about
    depth along its own ray). Outline points get none: they slide along the silhouette."""
    K = problem.lm0.shape[0]
    steps = []
    for fit, tg in zip(fits, targets):
        w, h = tg.size
        Rb = _rodrigues(np.asarray(fit.rotation, np.float64)[None])
        # the view correction at this frame's pose included: the offsets hold only what it left
        pts = problem.posed_points(np.asarray(fit.expr, np.float64)[None], np.asarray(fit.jaw, np.float64)[None],
                                   Rb, np.asarray(fit.translation, np.float64)[None])[0]
        R = Rb[0]
        cam = pts @ R.T + np.asarray(fit.translation, np.float64)
        cam[:, 1:] *= -1.0                                              # OpenCV axes
        z = np.maximum(cam[:, 2], 1e-4)
        px = np.stack([focal * cam[:, 0] / z + w / 2, focal * cam[:, 1] / z + h / 2], axis=1)
        d = np.zeros((K, 3))
        d[:, :2] = (tg.xy - px) * (z / focal)[:, None]                  # OpenCV camera, metres
        d[np.abs(tg.normal).sum(1) > 0] = 0.0
        steps.append((d * np.array([1.0, -1.0, -1.0])) @ R)             # view frame -> rest: R^T
    offset = np.median(np.stack(steps), axis=0)
    return offset - rigid_part(offset, rest_points(problem), np.abs(targets[0].normal).sum(1) == 0)


def rigid_part(offset: np.ndarray, points: np.ndarray, use: np.ndarray) -> np.ndarray:
    """(K, 3) the small rigid motion (w x p + t) closest to `offset` (K, 3) at `points` (K, 3)
    over the rows `use` (least squares; zeros elsewhere): the part of a calibration that would
    only turn or shift the whole face, which the pose already accounts for."""
    p = points - points[use].mean(0)
    K = len(p)
    A = np.zeros((K, 3, 6))
    A[:, :, 3:] = np.eye(3)
    A[:, 0, 1], A[:, 0, 2] = p[:, 2], -p[:, 1]        # w x p, rows: x = w_y p_z - w_z p_y
    A[:, 1, 0], A[:, 1, 2] = -p[:, 2], p[:, 0]        # y = w_z p_x - w_x p_z
    A[:, 2, 0], A[:, 2, 1] = p[:, 1], -p[:, 0]        # z = w_x p_y - w_y p_x
    x = np.linalg.lstsq(A[use].reshape(-1, 6), offset[use].reshape(-1), rcond=None)[0]
    out = (A @ x)
    out[~use] = 0.0
    return out
