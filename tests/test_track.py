"""The tracker on videos with known motion (the template head rendered by our renderer), its
parts against their references, the tracked-clip file, and what it does without a face."""
import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.head.model import HeadModel
from avatarkit.motion.clip import MotionClip
from avatarkit.rotations import axis_angle_to_matrix
from avatarkit.synthetic.head_video import HeadVideo, SyntheticFrame, head_video_camera
from avatarkit.track import TrackOptions, load_tracking, save_tracking, track_frames

SIZE = 224
FPS = 24.0


def _clip(T=10):
    t = np.linspace(0, 1, T)
    rot = np.stack([0.12 * np.sin(2 * np.pi * t), 0.30 * np.sin(np.pi * t), np.zeros(T)], axis=1)
    jaw = np.stack([0.25 * np.sin(np.pi * t) ** 2, np.zeros(T), np.zeros(T)], axis=1)
    trans = np.stack([0.01 * t, np.zeros(T), np.zeros(T)], axis=1)
    return MotionClip(fps=FPS, rotation=rot, translation=trans, neck=np.zeros((T, 3)), jaw=jaw,
                      eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))


def _angle_deg(a, b):
    R = axis_angle_to_matrix(a).T @ axis_angle_to_matrix(b)
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@pytest.fixture(scope="module")
def video():
    clip = _clip()
    camera = head_video_camera(SIZE, distance=0.45)
    hv = HeadVideo(clip, camera, n_gaussians=15000)
    return clip, camera, list(hv.frames())


@pytest.fixture(scope="module")
def tracked(video):
    clip, camera, frames = video
    model = HeadModel.template()
    return track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), FPS,
                        TrackOptions(smoothing=1.0))


def _eye_midpoint_camera(clip, camera, t):
    """The eye midpoint of frame t's posed head in camera coordinates (metres)."""
    from avatarkit.head.model import HeadParams

    model = HeadModel.template()
    params = HeadParams.from_clip(clip, frames=[t])
    params.shape = np.zeros(model.num_shape, np.float32)
    _, A = model.forward(params)
    joints = model.rest_joints(params)[0]
    eyes = np.array([(A[0, j] @ np.append(joints[j], 1.0))[:3] for j in (3, 4)])
    return camera.to_camera(eyes.mean(0)[None])[0]


def test_tracks_known_motion(video, tracked):
    clip, camera, frames = video
    assert tracked.found.all() and tracked.num_frames == len(frames)
    rot_err = [_angle_deg(a, b) for a, b in zip(tracked.clip.rotation, clip.rotation)]
    pos_err = [np.linalg.norm(_eye_midpoint_camera(tracked.clip, tracked.camera, t)
                              - _eye_midpoint_camera(clip, camera, t)) for t in range(len(frames))]
    # Measured here (template head, 224 px): rotation median 6.1 deg, worst 11.8 deg while the
    # jaw opens (the face mesh reads the template's opening mouth as a pitch), eye-midpoint
    # position <= 7 mm, landmark error 2.5 px. The face mesh's own drift on the procedural head
    # bounds this (docs/tracking.md); a wrong axis, sign or camera convention gives > 15 deg.
    assert np.median(rot_err) < 9.0, rot_err
    assert np.median(pos_err) < 0.012, pos_err
    # the turn itself is followed: yaw rises then falls with the truth
    yaw = tracked.clip.rotation[:, 1]
    assert np.corrcoef(yaw, clip.rotation[:, 1])[0, 1] > 0.95
    assert np.nanmedian(tracked.landmark_error) < 4.0
    assert (tracked.confidence > 0.3).all()


def test_fit_recovers_known_parameters_from_exact_landmarks(video):
    """The fit and the clip's frames without the face mesh's error: landmarks projected from a
    head posed by known parameters (jaw open, turned) give those parameters back."""
    from avatarkit.face.fit import LandmarkTargets
    from avatarkit.head.model import HeadParams
    from avatarkit.track.solve import fit_frame
    from avatarkit.track.tracker import FrameTracker, finish

    clip, camera, frames = video
    model = HeadModel.template()
    ft = FrameTracker(model, np.zeros(model.num_shape), (SIZE, SIZE), TrackOptions())
    mesh = ft.landmarks(frames[0].rgb)
    raw = {k: [] for k in ("rotation", "translation", "jaw", "expr", "eyes")}
    prev = None
    for t in range(clip.n_frames):
        params = HeadParams.from_clip(clip, frames=[t])
        params.shape = np.zeros(model.num_shape, np.float32)
        px, _ = camera.project(ft.embedding.points(model.forward(params)[0][0], model.faces))
        targets = LandmarkTargets.from_mesh(mesh, ft.embedding, (SIZE, SIZE))
        targets.xy = px
        prev = fit_frame(ft.problem, targets, ft.focal, start=prev, iterations=30,
                         initial=None if prev is not None else (np.zeros(3), np.array([0, 0, -0.45])),
                         depth_weight=0.0, expr_prior=1e-2, jaw_prior=1e-3)
        for k in raw:
            raw[k].append(getattr(prev, k) if k != "eyes" else np.zeros(6))
    T = clip.n_frames
    r = finish({k: np.array(v) for k, v in raw.items()}, np.ones(T), np.ones(T, bool), np.arange(T),
               np.zeros((T, 468, 2), np.float32), ft, FPS, TrackOptions(smoothing=0))
    rot_err = [_angle_deg(a, b) for a, b in zip(r.clip.rotation, clip.rotation)]
    assert np.max(rot_err) < 1.0, rot_err
    assert np.abs(r.clip.jaw[:, 0] - clip.jaw[:, 0]).max() < 0.03
    pos = [np.linalg.norm(_eye_midpoint_camera(r.clip, r.camera, t) - _eye_midpoint_camera(clip, camera, t))
           for t in range(T)]
    assert max(pos) < 2e-3, pos


def test_frames_without_a_face_are_interpolated_and_flagged(video):
    clip, camera, frames = video
    blank = np.full_like(frames[0].rgb, 120)
    gapped = [SyntheticFrame(f.index, f.time, blank if f.index in (4, 5) else f.rgb) for f in frames]
    model = HeadModel.template()
    r = track_frames(gapped, model, np.zeros(model.num_shape), (SIZE, SIZE), FPS)
    assert r.found.tolist() == [i not in (4, 5) for i in range(len(frames))]
    assert (r.confidence[[4, 5]] == 0).all() and np.isnan(r.landmarks[4]).all()
    # the interpolated yaw lies between its neighbours' and near the truth
    yaw = r.clip.rotation[:, 1]
    assert min(yaw[3], yaw[6]) - 0.05 < yaw[4] < max(yaw[3], yaw[6]) + 0.05
    assert abs(yaw[4] - clip.rotation[4, 1]) < 0.12


def test_no_face_anywhere_is_an_input_error():
    frames = [SyntheticFrame(i, i / FPS, np.full((96, 96, 3), 90, np.uint8)) for i in range(3)]
    model = HeadModel.template()
    with pytest.raises(InputError, match="no face found in any of the 3 frames"):
        track_frames(frames, model, np.zeros(model.num_shape), (96, 96), FPS)


def test_tracked_clip_round_trip_and_bake_reads_it(tmp_path, tracked):
    from avatarkit.motion.io import load_clip

    path = tmp_path / "t.npz"
    save_tracking(path, tracked)
    back = load_tracking(path)
    for k in ("rotation", "translation", "jaw", "eyes", "expr"):
        np.testing.assert_allclose(getattr(back.clip, k), getattr(tracked.clip, k), atol=1e-6)
    np.testing.assert_allclose(back.camera.world_to_camera, tracked.camera.world_to_camera)
    assert back.camera.fx == pytest.approx(tracked.camera.fx)
    np.testing.assert_array_equal(back.found, tracked.found)
    np.testing.assert_allclose(back.landmarks, tracked.landmarks, atol=1e-4)
    plain = load_clip(path)                     # what `bake` reads: the motion, extras ignored
    assert plain.n_frames == tracked.num_frames and plain.fps == FPS


def test_a_plain_clip_is_not_a_tracked_clip(tmp_path):
    from avatarkit.errors import FormatError
    from avatarkit.motion.io import save_clip

    save_clip(tmp_path / "c.npz", _clip(3))
    with pytest.raises(FormatError, match="not a tracked clip"):
        load_tracking(tmp_path / "c.npz")


def test_reduced_landmark_model_equals_the_vertex_one():
    """solve.FrameProblem (landmark-level precomputation) against face.fit.LandmarkModel."""
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.face.fit import LandmarkModel
    from avatarkit.track.solve import FrameProblem

    model = HeadModel.template()
    lm = LandmarkModel(model, template_embedding())
    rng = np.random.default_rng(0)
    shape = rng.normal(0, 0.5, model.num_shape)
    problem = FrameProblem.from_landmark_model(lm, shape, model.num_expr)
    for _ in range(3):
        expr, jaw = rng.normal(0, 0.5, model.num_expr), rng.normal(0, 0.15, 3)
        fast = problem.points(expr[None], jaw[None])[0]
        np.testing.assert_allclose(fast, lm.points_numpy(shape, expr, jaw), atol=1e-9)


def test_levenberg_marquardt_reaches_the_reference_fit(video):
    """solve.fit_frame against face.fit.fit_landmarks (torch L-BFGS) on one frame."""
    from avatarkit.face.fit import DEPTH_WEIGHT, LandmarkTargets, fit_landmarks
    from avatarkit.track.solve import fit_frame
    from avatarkit.track.tracker import FrameTracker

    clip, camera, frames = video
    model = HeadModel.template()
    ft = FrameTracker(model, np.zeros(model.num_shape), (SIZE, SIZE), TrackOptions())
    mesh = ft.landmarks(frames[6].rgb)
    targets = LandmarkTargets.from_mesh(mesh, ft.embedding, (SIZE, SIZE))
    # the same objective as fit_frame's defaults: the depth term on, the outline at full weight
    # (and the tracker's view correction)
    ref = fit_landmarks(model, ft.embedding, targets, ft.focal, fit_shape=False, depth_weight=DEPTH_WEIGHT,
                        outline_weight=1.0, expr_components=model.num_expr, fit_jaw=True, iterations=200,
                        view_correction=ft.problem.view)
    ours = fit_frame(ft.problem, targets, ft.focal, start=None,
                     initial=(ref.rotation + 0.05, ref.translation + 0.01), iterations=60)
    assert _angle_deg(ours.rotation, ref.rotation) < 0.3
    assert np.linalg.norm(ours.translation - ref.translation) < 2e-3
    assert abs(ours.jaw[0] - ref.jaw[0]) < 0.02
    assert ours.loss["total"] <= sum(ref.loss.values()) * 1.02


def test_identity_is_recovered_from_exact_landmarks():
    """The identity fit (shape coefficients in the same Levenberg-Marquardt problem) gives a
    known shape back from the landmarks of a head with that shape."""
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.face.fit import LandmarkModel, LandmarkTargets
    from avatarkit.head.model import HeadParams
    from avatarkit.track.solve import FrameProblem, fit_frame, rest_points
    from avatarkit.face.fit import initial_pose

    model = HeadModel.template()
    emb = template_embedding()
    lm = LandmarkModel(model, emb)
    camera = head_video_camera(SIZE, distance=0.45)
    truth = np.array([1.6, -1.0, 0.6, 0.0, 1.2, -0.8, 0.0, 0.4])[:model.num_shape]
    params = HeadParams(shape=truth.astype(np.float32), rotation=np.array([[0.05, 0.2, 0.0]]),
                        expr=np.zeros((1, model.num_expr)))
    px, _ = camera.project(emb.points(model.forward(params)[0][0], model.faces))
    idx = emb.mesh_index
    targets = LandmarkTargets(px, np.zeros(len(idx)), np.ones(len(idx)), np.zeros((len(idx), 2)),
                              float(np.linalg.norm(px[idx == 33][0] - px[idx == 263][0])), (SIZE, SIZE))
    problem = FrameProblem.from_landmark_model(lm, np.zeros(model.num_shape), model.num_expr,
                                               shape_components=model.num_shape)
    from avatarkit.recon.fit import portrait_focal
    f = portrait_focal(SIZE, SIZE)
    fit = fit_frame(problem, targets, f, initial=initial_pose(rest_points(problem), targets, f),
                    iterations=60, depth_weight=0.0, shape=np.zeros(model.num_shape), shape_prior=1e-6)
    assert fit.median_error < 0.05
    # not every coefficient is seen by face landmarks (neck width, head depth behind the
    # face; overall size trades against distance), so compare the landmark geometry itself
    from avatarkit.head.model import HeadParams as P
    got = emb.points(model.forward(P(shape=fit.shape.astype(np.float32),
                                     expr=np.zeros((1, model.num_expr))))[0][0], model.faces)
    want = emb.points(model.forward(P(shape=truth.astype(np.float32),
                                      expr=np.zeros((1, model.num_expr))))[0][0], model.faces)
    got, want = got - got.mean(0), want - want.mean(0)
    scale = np.linalg.norm(want) / np.linalg.norm(got)
    fitted_error = np.median(np.linalg.norm(got * scale - want, axis=1))
    zero = emb.points(model.v_template, model.faces)
    zero = zero - zero.mean(0)
    template_error = np.median(np.linalg.norm(zero - want, axis=1))
    assert template_error > 2e-3 and fitted_error < 0.2 * template_error, (fitted_error, template_error)


def test_calibration_partway_through_a_video(video, tracked):
    """Calibrating after the 5th frame (the frames before are fitted again, the rest follow)
    against no calibration and against calibrating at the end (the fixture: 10 frames < 30)."""
    clip, camera, frames = video
    model = HeadModel.template()
    runs = {n: track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), FPS,
                            TrackOptions(smoothing=1.0, calibration_frames=n)) for n in (5, 0)}
    mid, off = runs[5], runs[0]
    assert mid.found.all() and np.isfinite(mid.raw["rotation"]).all()
    err = {k: np.nanmedian(r.landmark_error) for k, r in (("mid", mid), ("off", off), ("end", tracked))}
    # measured: off 2.47 px, after frame 5 1.97 px, at the end 1.85 px
    assert err["mid"] < 0.9 * err["off"] and err["end"] < 0.9 * err["off"], err
    rot_err = [_angle_deg(a, b) for a, b in zip(mid.clip.rotation, clip.rotation)]
    assert np.median(rot_err) < 9.0, rot_err


def test_tracks_a_person_like_render_closer(video, tracked):
    """The template rendered as the targets are measured (`synthetic.shading`: Lambert shading
    from a light fixed to the camera, a dark mouth interior as the jaw opens) is read better
    than the flat one: rotation and jaw both closer to the truth."""
    from avatarkit.synthetic.shading import LIGHT

    clip, camera, _ = video
    frames = list(HeadVideo(clip, camera, n_gaussians=15000, light=LIGHT, mouth=True).frames())
    model = HeadModel.template()
    r = track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), FPS, TrackOptions(smoothing=1.0))
    rot = np.median([_angle_deg(a, b) for a, b in zip(r.clip.rotation, clip.rotation)])
    jaw = np.median(np.abs(r.clip.jaw[:, 0] - clip.jaw[:, 0]))
    flat_rot = np.median([_angle_deg(a, b) for a, b in zip(tracked.clip.rotation, clip.rotation)])
    flat_jaw = np.median(np.abs(tracked.clip.jaw[:, 0] - clip.jaw[:, 0]))
    # measured at 224 px: rotation 2.66 deg, jaw 0.055 rad (flat: 6.09 deg, 0.067 rad)
    assert r.found.all()
    assert rot < 4.0, rot
    assert jaw < 0.07, jaw
    assert rot < 0.7 * flat_rot and jaw < flat_jaw
