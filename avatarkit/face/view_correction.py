"""View-dependent landmark correspondence: where the face mesh puts each point, as a smooth
function of the view, relative to the head model's fixed embedding point.

Why: MediaPipe's face mesh answers with a view-dependent bias no fixed correspondence follows
(docs/face.md, Figures): on shaded template renders it reads the head's pitch ~16% short, and
under-reads how far the chin drops as the jaw opens, which the pose fit then absorbs as a tilt.
FLAME fitting code handles the contour half of this with pose-dependent ("dynamic") contour
landmarks; here every landmark gets a small offset o_k(view, jaw) (metres, in the head's rest
frame after the jaw's turn) added to its model point, calibrated by
`scripts/make_view_correction.py` from renders of the template with known pose (seeds disjoint
from the benchmarks').

The view is the camera's direction seen from the head: v = R^T (-(R p + t)) for a head posed by
(R, t) in the view frame (camera at the origin), p the landmarks' mean; yaw = atan2(v_x, v_z),
pitch = atan2(v_y, |v_xz|) (radians; 0, 0 = seen from straight ahead, pitch > 0 = seen from
above). jaw = the jaw's rotation about x (radians, > 0 open). The offset is
    o_k = sum_b phi_b(yaw, pitch, jaw) c_kb,
phi = the monomials of `BASIS` (cubic in the view, with jaw terms). `dynamic=True` drops the
constant term: the offsets vanish at the frontal view with the jaw closed, and only how the
face mesh's answer moves with the view and jaw is kept, not the template's static misfit
(measured worse than the full correction on the template, and no help elsewhere).

What it is worth (docs/face.md, docs/tracking.md): calibrated on the template, it removes the
template's bias and puts it on other faces, so neither fit uses it by default.

Use: o is a function of the parameters being fitted (the pose and jaw), evaluated inside the
objective: `face.fit.fit_landmarks(..., view_correction="full")` (torch, differentiated through)
and `track.solve` (`FrameProblem.with_view`; `TrackOptions(view_correction=True)`). A fixed-point
alternative (fit, correct at the fitted pose, refit) was tried first: it diverged in tracking
(the jaw's correction feeds back into the jaw).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

TEMPLATE_FILE = Path(__file__).with_name("data") / "template_view_correction.npz"
#: exponents (yaw, pitch, jaw) of the basis monomials
BASIS = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (2, 0, 0), (1, 1, 0), (0, 2, 0),
         (3, 0, 0), (2, 1, 0), (1, 2, 0), (0, 3, 0),
         (0, 0, 1), (1, 0, 1), (0, 1, 1), (0, 0, 2))
RIDGE = 3e-3
#: `solve_rigid`'s ridge (relative to each parameter's own normal diagonal): 84 parameters
#: shared by every landmark are well determined by a calibration grid, and a turn that moves the
#: points mostly in depth (a nod, seen from the front) is exactly what the pose fit reads
#: weakly, so only a trace of a ridge (at 3e-3 a made-up pitch gain of 0.15 came back 0.105)
RIGID_RIDGE = 1e-6


def features(yaw, pitch, jaw) -> np.ndarray:
    """(N, B) basis values for arrays (N,) of yaw, pitch, jaw (radians)."""
    a, b, j = (np.atleast_1d(np.asarray(x, np.float64)) for x in (yaw, pitch, jaw))
    return np.stack([a ** p * b ** q * j ** r for p, q, r in BASIS], axis=1)


def _angles(rot_T_t: "np.ndarray", centre, lib=np):
    """(yaw, pitch) (N,) each from the camera's direction seen from the head, v = -centre -
    R^T t (rest frame; R^T t given as (N, 3))."""
    v = -rot_T_t - centre
    return lib.arctan2(v[:, 0], v[:, 2]), lib.arctan2(v[:, 1], lib.sqrt(v[:, 0] ** 2 + v[:, 2] ** 2))


def view_angles(head_to_camera: np.ndarray, centre_camera: np.ndarray) -> tuple[float, float]:
    """(yaw, pitch) radians of the camera seen from the head. head_to_camera (3, 3): turns
    rest-frame directions into the camera's frame (OpenCV or view axes alike); centre_camera
    (3,): the head's landmark mean in that frame (the camera at its origin)."""
    v = np.asarray(head_to_camera, np.float64).T @ -np.asarray(centre_camera, np.float64)
    if np.linalg.det(head_to_camera) < 0:      # never: both frames are right-handed
        raise ValueError("head_to_camera is not a rotation")
    return float(np.arctan2(v[0], v[2])), float(np.arctan2(v[1], np.hypot(v[0], v[2])))


def fit_view(rotation: np.ndarray, translation: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """(yaw, pitch) of a `face.fit` pose: rotation (3,) axis-angle and translation (3,) in the
    view frame, points (K, 3) the rest-frame landmarks (their mean is the head's centre)."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.asarray(rotation, np.float64)).as_matrix()
    centre = R @ np.asarray(points, np.float64).mean(0) + np.asarray(translation, np.float64)
    # view frame (x right, y up, camera looking down -Z): the head faces +Z at rest, so the
    # camera's direction from the head is R^T (0 - centre) in the rest frame as it is
    return view_angles(R, centre)


@dataclass(eq=False)
class ViewCorrection:
    """coef (K, B, 3) metres: per landmark (row k = `mesh_index[k]` of the face mesh), the
    basis coefficients of its offset; static (K, 3): the best fixed offset over all views (the
    calibration's first step, kept for inspection); dynamic: drop the constant term."""

    mesh_index: np.ndarray
    coef: np.ndarray
    static: np.ndarray
    dynamic: bool = False

    def offsets(self, yaw: float, pitch: float, jaw: float = 0.0) -> np.ndarray:
        """(K, 3) rest-frame offsets at one view and jaw opening."""
        return np.einsum("b,kbd->kd", features(yaw, pitch, jaw)[0], self.effective())

    def effective(self) -> np.ndarray:
        """(K, B, 3) the coefficients used: with `dynamic`, the constant term's are zero, so the
        offsets vanish at the frontal view with the jaw closed (phi's constant is 1 at every view,
        the other monomials 0 there)."""
        if not self.dynamic:
            return self.coef
        c = self.coef.copy()
        c[:, 0] = 0.0
        return c

    def posed_offsets(self, rotation: np.ndarray, translation: np.ndarray, jaw: np.ndarray,
                      centre: np.ndarray) -> np.ndarray:
        """(N, K, 3) offsets for N poses of a `face.fit` head (numpy): rotation (N, 3, 3)
        matrices, translation (N, 3) view frame, jaw (N,) opening, centre (3,) the rest
        landmarks' mean."""
        yaw, pitch = _angles(np.einsum("nji,nj->ni", rotation, translation), centre)
        K, B, _ = self.coef.shape
        # (N, B) @ (B, 3K): one small matrix product (an einsum over k, b, d is ~10x slower)
        return (features(yaw, pitch, jaw) @ self._matrix()).reshape(len(yaw), K, 3)

    def _matrix(self) -> np.ndarray:
        """(B, 3K) the effective coefficients as one matrix (cached)."""
        key = (id(self.coef), self.dynamic)
        if getattr(self, "_cache", (None,))[0] != key:
            K, B, _ = self.coef.shape
            self._cache = (key, np.ascontiguousarray(self.effective().transpose(1, 0, 2).reshape(B, 3 * K)))
        return self._cache[1]

    def posed_offsets_torch(self, rotation, translation, jaw, centre):
        """(K, 3) the same for one pose, differentiable (torch float64: rotation (3, 3),
        translation (3,), jaw scalar, centre (3,) numpy)."""
        import torch

        yaw, pitch = _angles((rotation.T @ translation)[None], torch.from_numpy(np.asarray(centre, np.float64)),
                             torch)
        phi = torch.stack([yaw[0] ** p * pitch[0] ** q * jaw ** r for p, q, r in BASIS])
        return torch.einsum("b,kbd->kd", phi, torch.from_numpy(self.effective()))

    def matches(self, embedding) -> bool:
        """Whether this correction's rows are `embedding`'s (same face-mesh points, in order)."""
        return len(embedding.mesh_index) == len(self.mesh_index) and \
            bool(np.all(np.asarray(embedding.mesh_index) == self.mesh_index))

    def with_dynamic(self, dynamic: bool) -> "ViewCorrection":
        return ViewCorrection(self.mesh_index, self.coef, self.static, bool(dynamic))

    def save(self, path) -> None:
        np.savez_compressed(path, mesh_index=self.mesh_index.astype(np.int64), coef=self.coef.astype(np.float32),
                            static=self.static.astype(np.float32), basis=np.asarray(BASIS, np.int64))


def read_view_correction(path) -> ViewCorrection:
    d = np.load(path)
    if not np.array_equal(d["basis"], np.asarray(BASIS)):
        raise ValueError(f"{path}: made for another basis; re-run scripts/make_view_correction.py")
    return ViewCorrection(d["mesh_index"].astype(np.int64), d["coef"].astype(np.float64),
                          d["static"].astype(np.float64))


_TEMPLATE: ViewCorrection | None = None


def template_view_correction() -> ViewCorrection | None:
    """The built-in template's correction (cached), or None when its file is missing."""
    global _TEMPLATE
    if _TEMPLATE is None and TEMPLATE_FILE.exists():
        _TEMPLATE = read_view_correction(TEMPLATE_FILE)
    return _TEMPLATE


def correction_for(embedding) -> ViewCorrection | None:
    """The built-in correction when `embedding` is the template's (same rows), else None: a
    correction is calibrated for one head model and embedding."""
    c = template_view_correction()
    return c if c is not None and c.matches(embedding) else None


def resolve(spec, embedding) -> ViewCorrection | None:
    """A correction from a setting: None / False / "off": none; "full" / True: the built-in one
    (for the template's embedding; None for any other); "dynamic": its dynamic part; a
    `ViewCorrection`: itself."""
    if spec is None or spec is False or (isinstance(spec, str) and spec == "off"):
        return None
    if isinstance(spec, ViewCorrection):
        return spec
    if spec is True or spec in ("full", "dynamic"):
        c = correction_for(embedding)
        return None if c is None else c.with_dynamic(spec == "dynamic")
    raise ValueError(f"view correction: {spec!r} (off, full, dynamic or a ViewCorrection)")


# --- calibration ------------------------------------------------------------------------------

@dataclass(eq=False)
class Samples:
    """Calibration data: per case n and landmark k, the face mesh's pixel residual r (N, K, 2)
    against the true projected point, the linear map A (N, K, 2, 3) from a rest-frame offset
    (metres) to its pixel motion, the features phi (N, B) of the case's view and jaw, and a
    mask ok (N, K)."""

    r: np.ndarray
    A: np.ndarray
    phi: np.ndarray
    ok: np.ndarray


def samples_from_renders(data: dict, embedding) -> Samples:
    """`data`: what scripts/make_view_correction.py renders: mesh (N, 468, 3) pixels, truth_cam
    (N, K, 3) true landmarks in the OpenCV camera frame, head_to_cam (N, 3, 3), jaw (N,), focal,
    size, found (N,), and optionally principal (2,) px (default: size / 2 on both axes)."""
    f, size = float(data["focal"]), float(data["size"])
    # the principal point: the image's centre unless given (a crop's, `track.subject_calibration`)
    c = np.asarray(data["principal"], np.float64) if "principal" in data else np.array([size / 2, size / 2])
    X = np.asarray(data["truth_cam"], np.float64)                                    # (N, K, 3)
    z = X[..., 2]
    px = f * X[..., :2] / z[..., None] + c
    det = np.asarray(data["mesh"], np.float64)[:, np.asarray(embedding.mesh_index), :2]
    r = det - px
    # d pixel / d camera point, times head -> camera: (N, K, 2, 3)
    J = np.zeros(X.shape[:2] + (2, 3))
    J[..., 0, 0] = J[..., 1, 1] = f / z
    J[..., 0, 2] = -f * X[..., 0] / z ** 2
    J[..., 1, 2] = -f * X[..., 1] / z ** 2
    A = np.einsum("nkij,njl->nkil", J, np.asarray(data["head_to_cam"], np.float64))
    views = np.array([view_angles(h, x.mean(0)) for h, x in zip(data["head_to_cam"], X)])
    phi = features(views[:, 0], views[:, 1], np.asarray(data["jaw"], np.float64))
    ok = np.asarray(data["found"], bool)[:, None] & np.isfinite(r).all(-1)
    return Samples(np.nan_to_num(r), A, phi, ok)


def _solve(s: Samples, phi: np.ndarray, r: np.ndarray, ridge: float) -> np.ndarray:
    """(K, B, 3) least squares A_nk (sum_b phi_nb c_kb) ~ r_nk with a ridge of `ridge` x the
    normal matrix's mean diagonal (a case says nothing along its own rays; the ridge keeps the
    combinations no case sees small)."""
    N, K = s.ok.shape
    B = phi.shape[1]
    coef = np.zeros((K, B, 3))
    for k in range(K):
        use = s.ok[:, k]
        if use.sum() < 2 * B:
            continue
        M = np.einsum("nij,nb->nibj", s.A[use, k], phi[use]).reshape(-1, B * 3)     # (2n, 3B)
        H = M.T @ M
        lam = ridge * np.trace(H) / (B * 3)
        coef[k] = np.linalg.solve(H + lam * np.eye(B * 3), M.T @ r[use, k].reshape(-1)).reshape(B, 3)
    return coef


def solve_coefficients(s: Samples, ridge: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(coef (K, B, 3), static (K, 3)): the best fixed offset per landmark over all views
    first (the static misfit), then all the basis terms on what it leaves; coef's constant
    column holds both constants. Solved in one go, a depth offset and a yaw-linear sideways one
    trade against each other (both move the point with sin(yaw)) and the ridge alone would
    decide the split; this way the constant term holds the best fixed offset first."""
    ridge = RIDGE if ridge is None else ridge
    assert BASIS[0] == (0, 0, 0)
    static = _solve(s, s.phi[:, :1], s.r, ridge)[:, 0]
    left = s.r - np.einsum("nkij,kj->nki", s.A, static)
    coef = _solve(s, s.phi, left, ridge)
    coef[:, 0] += static
    return coef, static


def predict(s: Samples, coef: np.ndarray, static: np.ndarray | None = None) -> np.ndarray:
    """(N, K, 2) predicted pixel residuals (with `static` (K, 3) subtracted)."""
    o = np.einsum("nb,kbd->nkd", s.phi, coef)
    if static is not None:
        o = o - static[None]
    return np.einsum("nkij,nkj->nki", s.A, o)


def subset(s: Samples, rows: np.ndarray) -> Samples:
    return Samples(s.r[rows], s.A[rows], s.phi[rows], s.ok[rows])


def rigid_basis(points: np.ndarray) -> np.ndarray:
    """(K, 3, 6) L_k: how a small turn w (3, radians about the points' mean)
    and a shift t (3, metres) of the whole face move landmark k: L_k [w; t] = w x q_k + t, q_k
    the point less the mean. points: (K, 3) rest-frame landmarks."""
    q = np.asarray(points, np.float64) - np.asarray(points, np.float64).mean(0)
    L = np.zeros((len(q), 3, 6))
    # w x q = -[q]_x w
    L[:, 0, 1], L[:, 0, 2] = q[:, 2], -q[:, 1]
    L[:, 1, 0], L[:, 1, 2] = -q[:, 2], q[:, 0]
    L[:, 2, 0], L[:, 2, 1] = q[:, 1], -q[:, 0]
    L[:, :, 3:] = np.eye(3)
    return L


def _solve_rigid(s: Samples, phi: np.ndarray, r: np.ndarray, L: np.ndarray, weight: np.ndarray,
                 ridge: float) -> np.ndarray:
    """(B, 6) one turn and shift per basis term, shared by every landmark: least squares
    sqrt(w_k) A_nk L_k (sum_b phi_nb theta_b) ~ sqrt(w_k) r_nk over every case and landmark, with
    a ridge of `ridge` x each parameter's own normal diagonal."""
    B = phi.shape[1]
    n, k = np.nonzero(s.ok & (weight[None] > 0))
    AL = np.einsum("mij,mjl->mil", s.A[n, k], L[k]) * np.sqrt(weight[k])[:, None, None]   # (M, 2, 6)
    M = np.einsum("mil,mb->mibl", AL, phi[n]).reshape(-1, B * 6)                          # (2M, 6B)
    H = M.T @ M
    rhs = M.T @ (r[n, k] * np.sqrt(weight[k])[:, None]).reshape(-1)
    # the ridge scaled per parameter (its own diagonal): a turn moves a point ~q (5 cm) per
    # radian, a shift 1 m per metre, so one ridge for all (`_solve`'s) would hold the turns back;
    # a term no case sees (the jaw's, on a jaw-closed grid) stays zero
    d = np.diag(H)
    seen = d > 1e-12 * d.max()
    theta = np.zeros(B * 6)
    theta[seen] = np.linalg.solve(H[np.ix_(seen, seen)] + ridge * np.diag(d[seen]), rhs[seen])
    return theta.reshape(B, 6)


def solve_rigid(s: Samples, points: np.ndarray, weight: np.ndarray | None = None,
                ridge: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`solve_coefficients` restricted to a rigid motion of the whole face: per basis term one
    small turn and shift (`rigid_basis`) that every landmark follows, fitted to the samples'
    residuals of all landmarks together (weight (K,): each landmark's, default 1), the constant
    term first as `solve_coefficients` does. What the per-landmark fit would also model - one
    landmark read off its neighbours, a mouth corner read wide - is left out: only the part of
    the bias that moves the face as a whole, the part that moves the fitted pose (a constant
    nod, a yaw read short). -> (coef (K, B, 3), static (K, 3)) in `solve_coefficients`' form."""
    ridge = RIGID_RIDGE if ridge is None else ridge
    assert BASIS[0] == (0, 0, 0)
    L = rigid_basis(points)
    w = np.ones(len(L)) if weight is None else np.asarray(weight, np.float64)
    first = _solve_rigid(s, s.phi[:, :1], s.r, L, w, ridge)[0]                           # (6,)
    static = L @ first
    left = s.r - np.einsum("nkij,kj->nki", s.A, static)
    theta = _solve_rigid(s, s.phi, left, L, w, ridge)
    theta[0] += first
    return np.einsum("kdj,bj->kbd", L, theta), static


def fit_correction(s: Samples, mesh_index: np.ndarray, ridge: float | None = None,
                   rigid: np.ndarray | None = None, weight: np.ndarray | None = None) -> tuple[ViewCorrection, str]:
    """The correction from all samples, and a report: the residuals' median before and after
    on a held-out half (fitted on the other half), full and dynamic. rigid: the rest-frame
    landmarks (K, 3): fit only the rigid part (`solve_rigid`, landmark weights `weight`).
    ridge: None, RIDGE (RIGID_RIDGE for the rigid part)."""
    if ridge is None:
        ridge = RIDGE if rigid is None else RIGID_RIDGE

    def solve(part):
        return solve_coefficients(part, ridge) if rigid is None else solve_rigid(part, rigid, weight, ridge)

    N = len(s.phi)
    half = np.arange(N) % 2 == 0
    lines = []
    coef, static = solve(subset(s, np.where(half)[0]))
    test = subset(s, np.where(~half)[0])
    base = np.linalg.norm(test.r, axis=-1)[test.ok]
    for dyn in (False, True):
        left = np.linalg.norm(test.r - predict(test, coef, static if dyn else None), axis=-1)[test.ok]
        lines.append(f"held-out half ({(~half).sum()} cases), {'static subtracted' if dyn else 'full'}: residual median "
                     f"{np.median(base):.2f} -> {np.median(left):.2f} px, mean {base.mean():.2f} -> {left.mean():.2f} px")
    coef, static = solve(s)
    return ViewCorrection(np.asarray(mesh_index, np.int64), coef, static), "\n".join(lines)
