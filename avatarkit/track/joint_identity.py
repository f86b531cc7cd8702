"""One identity shape fitted jointly to the landmarks of several views (the video build's keyframes).

One view leaves the face's depth and size open: a frontal landmark set is explained nearly as
well by a flatter or a bigger head further away. Seen from several head poses the same shape
must explain every view, which fixes what one view cannot.

Problem: per view k its pose (rotation, translation), jaw and the leading expression
coefficients; shared by all views the identity coefficients. The residuals are the tracker's
(`solve.residuals`: landmark distances in eye distances, outline points across the outline,
priors), one block per view; the shape prior is counted once over all views (each block
carries 1/K of it) so more views weigh more against the prior. Minimised by the same
Levenberg-Marquardt scheme as `solve.fit_frame`, with a finite-difference Jacobian per view
(a view's residuals depend on its own parameters and the shared shape only).

`fit_identity_reference` minimises the same objective with scipy's least_squares (slow, obvious):
the tests compare the two.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.face.fit import LandmarkTargets
from avatarkit.track.solve import _STEP, FrameProblem, residuals

#: the tracker's priors (`track.tracker.TrackOptions`)
EXPR_PRIOR = 1e-2
JAW_PRIOR = 1e-3
#: prior per squared shape coefficient. The portrait fit's `face.fit.SHAPE_PRIOR` (2e-3) is set
#: against its silhouette and width terms too; against landmarks alone (residuals ~1/60 IOD) it
#: holds the shape at the mean. Measured on 5 synthetic views with 1 px noise (tests): landmark
#: geometry error 2.45 mm at 2e-3 (template: 2.63), 1.35 mm at 1e-4, 0.80 mm at 1e-6, where single
#: views (0.7-1.0 mm) fit the noise as well as the joint fit.
JOINT_SHAPE_PRIOR = 1e-4


@dataclass
class JointFit:
    """shape (S,) identity; rotation, translation, jaw (K, 3) per view (view frame of
    `face.fit`); expr (K, E); cost: the objective; median_error_px (K,) per view."""

    shape: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    jaw: np.ndarray
    expr: np.ndarray
    cost: float
    median_error_px: np.ndarray


class _MeshPoints:
    """The parts of a `FaceMesh` `LandmarkTargets.from_mesh` reads, from stored points."""

    def __init__(self, points: np.ndarray):
        p = np.asarray(points, np.float64)
        self.points = np.concatenate([p[:, :2], np.zeros((len(p), 1))], axis=1)
        # eye centres from the eye corners (the tracking file keeps no iris): only the unit
        self.iris_centers = np.stack([(p[33, :2] + p[133, :2]) / 2, (p[362, :2] + p[263, :2]) / 2])


def targets_from_points(points: np.ndarray, embedding, size: tuple[int, int]) -> LandmarkTargets:
    """`LandmarkTargets` from a tracking's stored face-mesh points (468, 2) pixels."""
    return LandmarkTargets.from_mesh(_MeshPoints(points), embedding, size)


def _view_params(rot, trans, jaw, expr) -> np.ndarray:
    return np.concatenate([rot, trans, jaw, expr])


def _cost_parts(problem, P, shape, targets, focal, prior):
    """Residual vector (M,) of all views for per-view parameters P (K, 9 + E) and shape (F,)."""
    out = []
    for k, t in enumerate(targets):
        p = np.concatenate([P[k], shape])[None]
        r, _ = residuals(problem, p, t, focal, 0.0, EXPR_PRIOR, JAW_PRIOR, prior)
        out.append(r[0])
    return np.concatenate(out)


def fit_joint_identity(problem: FrameProblem, targets: list[LandmarkTargets], focal: float,
                       rotation: np.ndarray, translation: np.ndarray, shape: np.ndarray | None = None,
                       iterations: int = 30, shape_prior: float | None = None) -> JointFit:
    """Fit (module docstring). problem: built with a zero base shape and `shape_components`
    F > 0 (`FrameProblem.from_landmark_model(lm, zeros, E, shape_components=F)`); targets: one
    per view; rotation, translation (K, 3): starting poses (e.g. the tracker's); shape: (F,)
    starting identity (default 0)."""
    shape_prior = JOINT_SHAPE_PRIOR if shape_prior is None else shape_prior
    E, C = problem.num_expr, problem.num_coefficients
    F = C - E
    K = len(targets)
    if K == 0 or F <= 0:
        raise ValueError("the joint fit needs views and a problem with shape coefficients")
    n = 9 + E
    P = np.zeros((K, n))
    P[:, 0:3] = np.asarray(rotation, np.float64).reshape(K, 3)
    P[:, 3:6] = np.asarray(translation, np.float64).reshape(K, 3)
    s = np.zeros(F) if shape is None else np.asarray(shape, np.float64).reshape(-1)[:F].copy()
    prior = shape_prior / K
    args = lambda t: (t, focal, 0.0, EXPR_PRIOR, JAW_PRIOR, prior)   # noqa: E731

    def view_residuals(k, p_batch):
        return residuals(problem, p_batch, *args(targets[k]))[0]

    r_views = [view_residuals(k, np.concatenate([P[k], s])[None])[0] for k in range(K)]
    cost = float(sum(r @ r for r in r_views))
    mu = 1e-3
    total = K * n + F
    for _ in range(iterations):
        g = np.zeros(total)
        H = np.zeros((total, total))
        for k in range(K):
            base = np.concatenate([P[k], s])
            batch = np.repeat(base[None], n + F, axis=0) + _STEP * np.eye(n + F)
            J = (view_residuals(k, batch) - r_views[k][None]) / _STEP          # (n + F, M_k)
            cols = np.concatenate([np.arange(k * n, (k + 1) * n), np.arange(K * n, total)])
            g[cols] += np.einsum("pm,m->p", J, r_views[k])
            H[np.ix_(cols, cols)] += np.einsum("pm,qm->pq", J, J)
        improved = converged = False
        for _ in range(6):
            delta = np.linalg.solve(H + mu * np.diag(np.diag(H) + 1e-12), -g)
            P_new = P + delta[:K * n].reshape(K, n)
            s_new = s + delta[K * n:]
            r_new = [view_residuals(k, np.concatenate([P_new[k], s_new])[None])[0] for k in range(K)]
            c_new = float(sum(r @ r for r in r_new))
            if c_new < cost:
                converged = cost - c_new < 1e-9 * max(cost, 1e-12)
                P, s, r_views, cost = P_new, s_new, r_new, c_new
                mu, improved = max(mu / 3, 1e-7), True
                break
            mu *= 8
        if not improved or converged:
            break
    return _result(problem, P, s, cost, targets, focal, prior)


def _result(problem, P, s, cost, targets, focal, prior) -> JointFit:
    from avatarkit.face.fit import pixel_errors

    E = problem.num_expr
    errors = []
    for k, t in enumerate(targets):
        _, px = residuals(problem, np.concatenate([P[k], s])[None], *(t, focal, 0.0, EXPR_PRIOR,
                                                                       JAW_PRIOR, prior))
        errors.append(float(np.median(pixel_errors(px[0], t))))
    return JointFit(s.copy(), P[:, 0:3].copy(), P[:, 3:6].copy(), P[:, 6:9].copy(), P[:, 9:9 + E].copy(),
                    float(cost), np.asarray(errors))


def fit_identity_reference(problem: FrameProblem, targets: list[LandmarkTargets], focal: float,
                           rotation: np.ndarray, translation: np.ndarray, shape: np.ndarray | None = None,
                           shape_prior: float | None = None) -> JointFit:
    """The same objective minimised by scipy.optimize.least_squares over all parameters at once
    (slow: a dense finite-difference Jacobian of the whole problem)."""
    shape_prior = JOINT_SHAPE_PRIOR if shape_prior is None else shape_prior
    from scipy.optimize import least_squares

    E, C = problem.num_expr, problem.num_coefficients
    F, K, n = C - E, len(targets), 9 + problem.num_expr
    x0 = np.zeros(K * n + F)
    P0 = x0[:K * n].reshape(K, n)
    P0[:, 0:3] = rotation
    P0[:, 3:6] = translation
    if shape is not None:
        x0[K * n:] = np.asarray(shape, np.float64)[:F]
    prior = shape_prior / K
    fun = lambda x: _cost_parts(problem, x[:K * n].reshape(K, n), x[K * n:], targets, focal, prior)  # noqa: E731
    sol = least_squares(fun, x0, method="trf", x_scale="jac", max_nfev=200)
    P, s = sol.x[:K * n].reshape(K, n), sol.x[K * n:]
    r = fun(sol.x)
    return _result(problem, P, s, float(r @ r), targets, focal, prior)


__all__ = ["JointFit", "fit_identity_reference", "fit_joint_identity", "targets_from_points"]
