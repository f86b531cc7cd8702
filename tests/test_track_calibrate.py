"""The tracker's per-landmark calibration (`FrameTracker.calibrate`, `solve.landmark_offsets`):
landmark offsets in the two landmark models, and calibration recovering a face whose landmarks
sit off the template's, from exact projections (no rendering, no face mesh)."""
import numpy as np
import pytest

from avatarkit.face.correspondence import template_embedding
from avatarkit.face.fit import LandmarkModel, LandmarkTargets
from avatarkit.head.model import HeadModel
from avatarkit.recon.fit import portrait_focal
from avatarkit.rotations import axis_angle_to_matrix
from avatarkit.track.solve import FrameProblem, fit_frame, landmark_offsets, project, rest_points, rigid_part

SIZE = 256


@pytest.fixture(scope="module")
def template():
    model = HeadModel.template()
    return model, template_embedding()


def _angle_deg(a, b):
    R = axis_angle_to_matrix(a).T @ axis_angle_to_matrix(b)
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def test_offsets_ride_on_the_landmarks_alike_in_both_models(template):
    """FrameProblem (landmark-level) against LandmarkModel (vertex-level) with offsets, the
    jaw turned and expressions on: the offset follows its landmark's jaw weight in both."""
    model, emb = template
    rng = np.random.default_rng(1)
    emb = emb.with_offset(rng.normal(0, 0.004, (len(emb), 3)))
    lm = LandmarkModel(model, emb)
    shape = rng.normal(0, 0.5, model.num_shape)
    problem = FrameProblem.from_landmark_model(lm, shape, model.num_expr)
    for _ in range(3):
        expr, jaw = rng.normal(0, 0.5, model.num_expr), rng.normal(0, 0.15, 3)
        np.testing.assert_allclose(problem.points(expr[None], jaw[None])[0], lm.points_numpy(shape, expr, jaw),
                                   atol=1e-9)
    # at rest the offset is simply added
    plain = LandmarkModel(model, emb.with_offset(None)).points_numpy(shape)
    np.testing.assert_allclose(lm.points_numpy(shape) - plain, emb.offset, atol=1e-12)


def test_rigid_part_is_what_a_pose_change_would_do(template):
    model, emb = template
    p = emb.points(model.v_template, model.faces)
    use = np.ones(len(p), bool)
    use[:10] = False
    w, t = np.array([0.01, -0.02, 0.005]), np.array([0.001, 0.002, -0.003])
    rigid = np.cross(w, p - p[use].mean(0)) + t
    np.testing.assert_allclose(rigid_part(rigid, p, use)[use], rigid[use], atol=1e-12)
    assert (rigid_part(rigid, p, use)[~use] == 0).all()
    field = np.random.default_rng(2).normal(0, 0.003, p.shape)
    rest = field - rigid_part(field, p, use)
    assert np.abs(rigid_part(rest, p, use)).max() < 1e-12


def test_calibration_recovers_landmarks_that_sit_off_the_template(template):
    """A 'person' whose face-mesh points sit a few millimetres off the template's (across the
    view: what frontal frames can see), seen turned and nodded in 8 frames. Fitting the plain
    template leaves pixels of error and a biased pose; two calibration rounds (as
    `FrameTracker.calibrate` runs them) find the offsets and remove both."""
    model, emb = template
    rng = np.random.default_rng(3)
    lm0 = LandmarkModel(model, emb)
    shape = np.zeros(model.num_shape)
    E = model.num_expr
    points = lm0.points_numpy(shape)
    use = np.ones(len(emb), bool)
    truth = np.zeros((len(emb), 3))
    truth[:, :2] = rng.normal(0, 0.003, (len(emb), 2))
    truth -= rigid_part(truth, points, use)            # a calibration cannot see (nor needs) this part
    person = FrameProblem.from_landmark_model(LandmarkModel(model, emb.with_offset(truth)), shape, E)
    focal = portrait_focal(SIZE, SIZE)
    poses = [np.array([p, y, 0.0]) for y in (-0.3, -0.1, 0.1, 0.3) for p in (-0.1, 0.1)]
    trans = np.array([0.0, -0.03, -0.45])
    targets = []
    for rot in poses:
        px = project(person, rot, trans, np.zeros(3), np.zeros(E), focal, (SIZE, SIZE))
        targets.append(LandmarkTargets(px, np.zeros(len(emb)), np.ones(len(emb)), np.zeros((len(emb), 2)),
                                       60.0, (SIZE, SIZE)))

    def fit_all(problem):
        out = []
        for tg, rot in zip(targets, poses):
            out.append(fit_frame(problem, tg, focal, initial=(rot + 0.05, trans + 0.01), iterations=40,
                                 depth_weight=0.0, expr_prior=1e-2, jaw_prior=1e-3, shape=shape))
        return out

    problem = FrameProblem.from_landmark_model(lm0, shape, E)
    before = fit_all(problem)
    offset = np.zeros_like(truth)
    for _ in range(2):
        offset = offset + landmark_offsets(problem, fit_all(problem), targets, focal)
        problem = FrameProblem.from_landmark_model(LandmarkModel(model, emb.with_offset(offset)), shape, E)
    after = fit_all(problem)
    err_before = np.median([f.median_error for f in before])
    err_after = np.median([f.median_error for f in after])
    rot_before = max(_angle_deg(f.rotation, r) for f, r in zip(before, poses))
    rot_after = max(_angle_deg(f.rotation, r) for f, r in zip(after, poses))
    off_err = np.median(np.linalg.norm(offset - truth, axis=1))
    off_size = np.median(np.linalg.norm(truth, axis=1))
    # measured: 3.4 px -> 0.03 px, offsets within 4% of their size, worst rotation error
    # 0.44 -> 0.34 deg (random offsets bias the pose little; what is left is the part of the
    # offsets two rounds of fixed-point updates have not reached)
    assert err_before > 1.5 and err_after < 0.15, (err_before, err_after)
    assert off_err < 0.12 * off_size, (off_err, off_size)
    assert rot_after < 0.5 and rot_after < rot_before, (rot_before, rot_after)
    # the rest landmarks moved by the offsets alone
    np.testing.assert_allclose(rest_points(problem) - points, offset, atol=1e-9)


def test_a_tracked_result_carries_its_calibrated_embedding():
    """What `track_frames` hands back names the offsets it fitted with (the preview and any
    later projection of the fitted head need them); the result's landmark error uses them."""
    from avatarkit.synthetic.head_video import HeadVideo, head_video_camera
    from avatarkit.motion.clip import MotionClip
    from avatarkit.track import TrackOptions, track_frames

    T = 6
    clip = MotionClip(fps=24.0, rotation=np.stack([np.zeros(T), np.linspace(-0.2, 0.2, T), np.zeros(T)], 1),
                      translation=np.zeros((T, 3)), neck=np.zeros((T, 3)), jaw=np.zeros((T, 3)),
                      eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))
    frames = list(HeadVideo(clip, head_video_camera(192, distance=0.45), n_gaussians=8000).frames())
    model = HeadModel.template()
    r = track_frames(frames, model, np.zeros(model.num_shape), (192, 192), 24.0, TrackOptions(smoothing=1.0))
    assert r.found.all()
    off = r.embedding.offset
    assert off is not None and off.shape == (len(r.embedding), 3)
    # millimetres, not centimetres: a calibration, not a new face (measured: median 0.7 mm)
    assert 1e-4 < np.median(np.linalg.norm(off, axis=1)) < 6e-3
    plain = track_frames(frames, model, np.zeros(model.num_shape), (192, 192), 24.0,
                         TrackOptions(smoothing=1.0, calibration_frames=0))
    # uncalibrated: only the offsets the template's embedding comes with (its lower inner lip
    # re-hosted on the jaw, `correspondence.carried_by_jaw`)
    from avatarkit.face.correspondence import embedding_for

    np.testing.assert_array_equal(plain.embedding.offset, embedding_for(model).offset)
