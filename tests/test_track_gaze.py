"""Eye rotations from iris pixels: the inverse of projecting a turned eyeball's iris."""
import numpy as np
import pytest

from avatarkit.track.gaze import MAX_ANGLE, eye_rotation, eyes_pose, project_gaze

EYES = np.array([[0.032, 0.05, 0.067], [-0.032, 0.05, 0.067]])   # left (+X), right
F, PP = 600.0, (256.0, 256.0)


@pytest.mark.parametrize("seed", range(6))
def test_round_trip_through_the_projection(seed):
    rng = np.random.default_rng(seed)
    rot = rng.normal(0, 0.25, 3)
    trans = np.array([0.0, -0.05, -0.6]) + rng.normal(0, 0.03, 3)
    eyes = np.concatenate([rng.normal(0, 0.2, 2).tolist() + [0.0], rng.normal(0, 0.2, 2).tolist() + [0.0]])
    px = project_gaze(eyes, EYES, rot, trans, F, PP)
    got = eyes_pose(px, EYES, rot, trans, F, PP)
    # the shortest rotation from +Z has no twist about the gaze: compare gaze directions
    from avatarkit.rotations import axis_angle_to_matrix
    for s in range(2):
        g_true = axis_angle_to_matrix(eyes[3 * s:3 * s + 3]) @ np.array([0, 0, 1.0])
        g_got = axis_angle_to_matrix(got[3 * s:3 * s + 3]) @ np.array([0, 0, 1.0])
        assert np.degrees(np.arccos(np.clip(g_true @ g_got, -1, 1))) < 0.01


def test_iris_straight_ahead_is_no_rotation():
    px = project_gaze(np.zeros(6), EYES, np.zeros(3), np.array([0, -0.05, -0.6]), F, PP)
    np.testing.assert_allclose(eyes_pose(px, EYES, np.zeros(3), np.array([0, -0.05, -0.6]), F, PP),
                               0.0, atol=1e-9)


def test_slots_follow_flame_order():
    """Slot 0 is the left eye (+X), seen at the image's right; turning it alone moves the
    mesh's second iris only."""
    eyes = np.array([0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    px0 = project_gaze(np.zeros(6), EYES, np.zeros(3), np.array([0, 0, -0.6]), F, PP)
    px1 = project_gaze(eyes, EYES, np.zeros(3), np.array([0, 0, -0.6]), F, PP)
    assert px0[1, 0] > px0[0, 0]                 # the left eye is on the image's right
    assert np.allclose(px0[0], px1[0]) and not np.allclose(px0[1], px1[1])


def test_angle_is_clamped():
    aa = eye_rotation(np.array([1.0, 0.0, 0.2]))
    assert np.linalg.norm(aa) == pytest.approx(MAX_ANGLE)


def test_relative_eyes_compose_with_the_inverse_of_the_reference():
    """Against scipy's rotations: R_t R_ref^T per eye; the reference frame becomes zero."""
    from scipy.spatial.transform import Rotation

    from avatarkit.track.gaze import relative_eyes

    rng = np.random.default_rng(3)
    eyes = rng.normal(0, 0.4, (7, 6))
    got = relative_eyes(eyes, eyes[4])
    np.testing.assert_allclose(got[4], 0.0, atol=1e-12)
    for s in range(2):
        want = (Rotation.from_rotvec(eyes[:, 3 * s:3 * s + 3])
                * Rotation.from_rotvec(eyes[4, 3 * s:3 * s + 3]).inv()).as_rotvec()
        np.testing.assert_allclose(got[:, 3 * s:3 * s + 3], want, atol=1e-10)
    # a constant bias on every frame cancels: the changes of gaze are what is left
    bias = np.array([-0.45, 0.1, 0.0, -0.5, -0.1, 0.0])
    turns = np.zeros((3, 6))
    turns[:, 1] = [0.0, 0.2, -0.1]
    turns[:, 4] = [0.0, 0.2, -0.1]
    biased = np.concatenate([(Rotation.from_rotvec(turns[:, 3 * s:3 * s + 3])
                              * Rotation.from_rotvec(np.tile(bias[3 * s:3 * s + 3], (3, 1)))).as_rotvec()
                             for s in range(2)], axis=1)
    np.testing.assert_allclose(relative_eyes(biased, biased[0]), turns, atol=1e-10)


def test_relative_eyes_gain_scales_the_turn_from_the_reference(monkeypatch):
    """A gain scales each eye's turn from the reference (its axis kept): gain 0 holds the eyes
    at the reference's gaze; `eyes_from_build_frame` drives with `gaze.RELATIVE_GAIN`."""
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    from avatarkit.track import gaze
    from avatarkit.track.build_pose import eyes_from_build_frame

    rng = np.random.default_rng(5)
    eyes = rng.normal(0, 0.3, (6, 6))
    full = gaze.relative_eyes(eyes, eyes[2])
    np.testing.assert_allclose(gaze.relative_eyes(eyes, eyes[2], 0.0), 0.0, atol=1e-12)
    half = gaze.relative_eyes(eyes, eyes[2], 0.5)
    for s in range(2):
        a, b = full[:, 3 * s:3 * s + 3], half[:, 3 * s:3 * s + 3]
        # a half turn about the same axis, applied twice, is the whole turn
        twice = (Rotation.from_rotvec(b) * Rotation.from_rotvec(b)).as_rotvec()
        np.testing.assert_allclose(twice, a, atol=1e-10)
    monkeypatch.setattr(gaze, "RELATIVE_GAIN", 0.25)
    result = SimpleNamespace(frame_index=np.arange(10, 16), clip=SimpleNamespace(eyes=eyes.astype(np.float32)))
    assert eyes_from_build_frame(result, 12)
    np.testing.assert_allclose(result.clip.eyes, 0.25 * full, atol=1e-6)


def test_clip_relative_to_the_build_pose():
    """The build frame's view transform becomes the build's exactly; the motion between frames
    (R_s R_t^T, and where a head point goes relative to the build frame) is kept."""
    from avatarkit.rotations import axis_angle_to_matrix
    from avatarkit.track.build_pose import relative_to_build, view_transforms

    rng = np.random.default_rng(5)
    T, b = 9, 4
    rot = rng.normal(0, 0.15, (T, 3))
    tau = rng.normal(0, 0.01, (T, 3))
    C = np.diag([1.0, -1.0, -1.0])
    cam = np.eye(4)
    cam[:3, :3] = C
    cam[:3, 3] = C @ np.array([0.01, -0.05, -0.5])
    J0 = np.array([0.0, -0.12, -0.02])
    Rf = axis_angle_to_matrix(np.array([0.1, -0.05, 0.03])).astype(np.float64)
    tf = np.array([0.004, -0.053, -0.466])
    build = np.eye(4)
    build[:3, :3], build[:3, 3] = C @ Rf, C @ tf
    new_rot, new_tau = relative_to_build(rot, tau, b, cam, build, J0)
    R0, t0 = view_transforms(rot, tau, cam, J0)
    R1, t1 = view_transforms(new_rot, new_tau, cam, J0)
    np.testing.assert_allclose(R1[b], Rf, atol=1e-12)
    np.testing.assert_allclose(t1[b], tf, atol=1e-12)
    for s in range(T):
        np.testing.assert_allclose(R1[s] @ R1[b].T, R0[s] @ R0[b].T, atol=1e-12)
    # with no offset (the build saw what the tracker saw) nothing moves
    same = np.eye(4)
    same[:3, :3], same[:3, 3] = C @ R0[b], C @ t0[b]
    r2, t2 = relative_to_build(rot, tau, b, cam, same, J0)
    np.testing.assert_allclose(r2, rot, atol=1e-10)
    np.testing.assert_allclose(t2, tau, atol=1e-12)
