"""The view-dependent landmark correction (`face.view_correction`): its fast evaluation against
the per-pose reference, the calibration's least squares, and both fits (`face.fit` and the
tracker's `track.solve`) reading the pose right from landmarks that move with the view as the
correction says (exact projections; no rendering, no face mesh)."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avatarkit.face.correspondence import template_embedding
from avatarkit.face.fit import LandmarkModel, LandmarkTargets, fit_landmarks
from avatarkit.face.view_correction import (BASIS, Samples, ViewCorrection, correction_for, features, fit_view,
                                            predict, solve_coefficients)
from avatarkit.head.model import HeadModel
from avatarkit.recon.fit import portrait_focal
from avatarkit.track.solve import FrameProblem, fit_frame, project

SIZE = 512


@pytest.fixture(scope="module")
def template():
    return HeadModel.template(), template_embedding()


def _correction(emb, scale=0.004, seed=0):
    """A made-up correction of the size the shipped one has (millimetres; strongest in pitch
    and jaw, as the face mesh's own bias on the template)."""
    rng = np.random.default_rng(seed)
    coef = rng.normal(0, scale, (len(emb), len(BASIS), 3))
    return ViewCorrection(np.asarray(emb.mesh_index), coef, rng.normal(0, scale, (len(emb), 3)))


def _deg(a, b):
    return math.degrees((Rotation.from_rotvec(a) * Rotation.from_rotvec(b).inv()).magnitude())


def test_posed_offsets_match_the_per_pose_reference(template):
    """The batched numpy path and the differentiable torch path against `offsets` at the view
    `fit_view` computes, pose by pose (the obvious reference)."""
    import torch

    model, emb = template
    c = _correction(emb)
    centre = LandmarkModel(model, emb).points_numpy().mean(0)
    rng = np.random.default_rng(1)
    rots = rng.normal(0, 0.3, (5, 3))
    trans = np.array([0.02, -0.04, -0.55]) + rng.normal(0, 0.02, (5, 3))
    jaw = rng.uniform(0, 0.3, 5)
    R = Rotation.from_rotvec(rots).as_matrix()
    for dynamic in (False, True):
        c = c.with_dynamic(dynamic)
        fast = c.posed_offsets(R, trans, jaw, centre)
        for n in range(5):
            yaw, pitch = fit_view(rots[n], trans[n], centre[None])
            ref = c.offsets(yaw, pitch, jaw[n])
            np.testing.assert_allclose(fast[n], ref, atol=1e-12)
            t = c.posed_offsets_torch(torch.tensor(R[n]), torch.tensor(trans[n]),
                                      torch.tensor(jaw[n], dtype=torch.float64), centre).numpy()
            np.testing.assert_allclose(t, ref, atol=1e-12)
    # dynamic: the frontal, jaw-closed offset taken out, at every view
    d = c.with_dynamic(False).offsets(0.3, -0.1, 0.2) - c.with_dynamic(True).offsets(0.3, -0.1, 0.2)
    np.testing.assert_allclose(d, c.with_dynamic(False).offsets(0.0, 0.0, 0.0), atol=1e-12)
    assert np.abs(c.with_dynamic(True).offsets(0.0, 0.0, 0.0)).max() == 0.0


def test_view_angles_follow_the_head():
    """A head turned to its left (+yaw about +Y) sees the camera on its right (negative yaw);
    one below the camera sees it from above (positive pitch)."""
    pts = np.zeros((1, 3))
    yaw, pitch = fit_view(np.array([0.0, 0.3, 0.0]), np.array([0.0, 0.0, -0.5]), pts)
    assert yaw == pytest.approx(-0.3) and abs(pitch) < 1e-12
    yaw, pitch = fit_view(np.zeros(3), np.array([0.0, -0.1, -0.5]), pts)
    assert abs(yaw) < 1e-12 and pitch == pytest.approx(math.atan2(0.1, 0.5))


def test_calibration_recovers_a_known_correction():
    """Residuals made from a known correction through random view maps: the least squares of
    the calibration predicts them back (on cases it was not fitted on)."""
    rng = np.random.default_rng(2)
    K, N = 6, 400
    coef = rng.normal(0, 0.003, (K, len(BASIS), 3))
    views = np.stack([rng.uniform(-0.7, 0.7, N), rng.uniform(-0.35, 0.35, N), rng.uniform(0, 0.3, N)], 1)
    phi = features(*views.T)
    R = Rotation.from_euler("YXZ", np.stack([-views[:, 0], -views[:, 1], rng.uniform(-0.2, 0.2, N)], 1)).as_matrix()
    A = 1000.0 * np.einsum("ij,njk->nik", np.eye(3)[:2], R)[:, None].repeat(K, 1)     # (N, K, 2, 3)
    o = np.einsum("nb,kbd->nkd", phi, coef)
    r = np.einsum("nkij,nkj->nki", A, o)
    train, test = np.arange(N) < 300, np.arange(N) >= 300
    s = Samples(r[train], A[train], phi[train], np.ones((300, K), bool))
    got, static = solve_coefficients(s, ridge=1e-8)
    t = Samples(r[test], A[test], phi[test], np.ones((100, K), bool))
    err = np.abs(predict(t, got) - r[test])
    assert np.median(np.abs(r[test])) > 1.0
    assert err.max() < 1e-3 * np.abs(r[test]).max(), err.max()


def _targets(points_px, n):
    return LandmarkTargets(points_px, np.zeros(n), np.ones(n), np.zeros((n, 2)), 60.0, (SIZE, SIZE))


@pytest.mark.parametrize("solver", ["torch", "levenberg-marquardt"])
def test_fits_read_the_pose_through_a_view_correction(template, solver):
    """Landmarks placed where a view correction says the face mesh reads them (exact
    projections of model point + offset at the true pose and jaw): with the correction the
    fit finds the true pose; without it the pose is off by about a degree or more."""
    model, emb = template
    c = _correction(emb, seed=3)
    lm = LandmarkModel(model, emb)
    shape = np.zeros(model.num_shape)
    E = model.num_expr
    f = portrait_focal(SIZE, SIZE)
    plain = FrameProblem.from_landmark_model(lm, shape, E)
    truth = plain.with_view(c)
    centre = lm.points_numpy(shape).mean(0)
    errs = {True: [], False: []}
    for rot, jaw in ((np.array([0.1, 0.4, 0.05]), 0.0), (np.array([-0.15, -0.2, 0.0]), 0.2)):
        trans = np.array([0.01, -0.03, -0.55])
        jaw3 = np.array([jaw, 0.0, 0.0])
        # the targets from the vertex-level model and the per-pose reference of the offsets
        X = lm.points_numpy(shape, None, jaw3) + c.offsets(*fit_view(rot, trans, centre[None]), jaw)
        cam = (X @ Rotation.from_rotvec(rot).as_matrix().T + trans) * np.array([1.0, -1.0, -1.0])
        px = f * cam[:, :2] / cam[:, 2:] + SIZE / 2
        np.testing.assert_allclose(project(truth, rot, trans, jaw3, np.zeros(E), f, (SIZE, SIZE)), px, atol=1e-6)
        tg = _targets(px, len(emb))
        for on in (True, False):
            if solver == "torch":
                fit = fit_landmarks(model, emb, tg, f, shape=shape, fit_shape=False, fit_jaw=jaw > 0,
                                    outline_weight=1.0, view_correction=c if on else None, iterations=100,
                                    jaw_prior=1e-8, landmark_model=lm)
            else:
                fit = fit_frame(truth if on else plain, tg, f, initial=(rot + 0.05, trans + 0.01), iterations=60,
                                depth_weight=0.0, expr_prior=1e-8, jaw_prior=1e-8, shape=shape)
            errs[on].append(_deg(fit.rotation, rot))
            if on:
                assert fit.median_error < 0.05, fit.median_error
    # measured: with 0.00-0.01 deg, without 1.5-4 deg
    assert max(errs[True]) < 0.05, errs
    assert min(errs[False]) > 0.5, errs


def test_the_switch_and_the_shipped_correction(template):
    """`correction_for` finds the shipped correction for the template's embedding only; the
    tracker's switch turns it on (off by default); its offsets over the calibrated views are
    millimetres."""
    from avatarkit.track.tracker import FrameTracker, TrackOptions

    model, emb = template
    c = correction_for(emb)
    assert c is not None and c.dynamic is False
    assert correction_for(emb.__class__(emb.face_idx[:10], emb.bary[:10], emb.mesh_index[:10])) is None
    sizes = [np.linalg.norm(c.offsets(y, p, j), axis=1) for y in (-0.7, 0, 0.7) for p in (-0.35, 0, 0.35)
             for j in (0, 0.3)]
    # measured (the shipped one): median 1 cm (mostly along the rays, where the renders see
    # little and the ridge holds it), 6.5 cm at the corners of the range (yaw 40, pitch 20 deg, jaw 0.3)
    assert np.median(sizes) < 0.02 and np.max(sizes) < 0.1
    on = FrameTracker(model, np.zeros(model.num_shape), (SIZE, SIZE), TrackOptions(view_correction=True))
    off = FrameTracker(model, np.zeros(model.num_shape), (SIZE, SIZE), TrackOptions())
    assert on.problem.view is not None and not on.problem.view.dynamic and off.problem.view is None
    np.testing.assert_array_equal(on.problem.view.coef, c.coef)
