"""The tracker on a head turning to 46 degrees (the turn docs/video-build.md asks people to
record): the confidence's unit (`tracker.face_scale`) and the tracked yaw against the truth."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avatarkit.head.model import HeadModel, HeadParams
from avatarkit.rotations import axis_angle_to_matrix
from avatarkit.track import TrackOptions, track_frames
from avatarkit.track import gaze
from avatarkit.track.tracker import ERROR_SCALE, confidence, face_scale

SIZE = 160
FPS = 24.0
TURN = np.radians(46.0)


def _eye_centres():
    model = HeadModel.template()
    params = HeadParams(shape=np.zeros(model.num_shape, np.float32), expr=np.zeros((1, model.num_expr), np.float32))
    joints = model.rest_joints(params)[0].astype(np.float64)
    return joints[[gaze.LEFT_EYE_JOINT, gaze.RIGHT_EYE_JOINT]]


def _projected_eye_distance(eyes, rotation, translation, focal):
    """Pixels between the eye centres in the image (the pinhole of `solve.project`)."""
    cam = eyes @ axis_angle_to_matrix(rotation).T + translation
    xy = focal * cam[:, :2] / -cam[:, 2:]
    return float(np.linalg.norm(xy[1] - xy[0]))


def test_face_scale_is_the_eye_distance_facing_the_camera_whatever_the_turn():
    eyes = _eye_centres()
    focal, mid = 500.0, np.array([0.01, 0.02, -0.5])
    t0 = mid - eyes.mean(0)
    front = face_scale(eyes, np.zeros(3), t0, focal)
    # facing the camera it is the eye distance seen in the image
    assert front == pytest.approx(_projected_eye_distance(eyes, np.zeros(3), t0, focal), rel=1e-3)
    for yaw in (0.4, 0.8, -0.8):
        r = np.array([0.0, yaw, 0.0])
        t = mid - axis_angle_to_matrix(r) @ eyes.mean(0)        # the eyes' midpoint stays put
        # the image distance shrinks with the turn; the confidence's unit does not
        assert _projected_eye_distance(eyes, r, t, focal) < np.cos(abs(yaw)) * front * 1.05
        assert face_scale(eyes, r, t, focal) == pytest.approx(front, rel=1e-9)
    # twice as far: half the size
    far = mid * [1.0, 1.0, 2.0] - eyes.mean(0)
    assert face_scale(eyes, np.zeros(3), far, focal) == pytest.approx(front / 2, rel=1e-9)


def test_confidence_is_the_presence_at_no_error_and_half_of_it_at_the_error_scale():
    assert confidence(0.9, 0.0, 40.0) == pytest.approx(0.9)
    assert confidence(0.9, ERROR_SCALE * 40.0, 40.0) == pytest.approx(0.45)
    assert confidence(1.0, 3.0, 40.0) > confidence(1.0, 3.0, 20.0) > confidence(1.0, 6.0, 20.0)


def _turn_clip():
    """0 -> 46 degrees of yaw -> -46 -> 0, eased (a head slows down before it turns back),
    held 3 frames at each side: 31 frames."""
    from avatarkit.motion.clip import MotionClip

    def ease(a, b, n):
        return a + (b - a) * (1 - np.cos(np.pi * np.arange(1, n + 1) / n)) / 2

    y = np.concatenate([[0.0], ease(0, TURN, 6), np.full(3, TURN), ease(TURN, -TURN, 12), np.full(3, -TURN),
                        ease(-TURN, 0, 6)])
    T = len(y)
    rot = Rotation.from_euler("YXZ", np.stack([y, np.zeros(T), np.zeros(T)], axis=1)).as_rotvec()
    z = np.zeros((T, 3))
    return MotionClip(fps=FPS, rotation=rot, translation=z.copy(), neck=z.copy(), jaw=z.copy(),
                      eyes=np.zeros((T, 6)), expr=np.zeros((T, 10)))


def _yaw(rotation):
    return np.degrees(Rotation.from_rotvec(np.asarray(rotation, np.float64)).as_euler("YXZ")[:, 0])


def test_turned_frames_keep_their_confidence_and_the_yaw_follows_the_turn():
    """The mesh subject (`synthetic.mesh_head`: the template mesh rasterised, not our splatting)
    turning to 46 degrees each way. With the iris distance in the image as the confidence's
    unit (before `face_scale`) the frames past 40 degrees had 0.34 of the front frames'
    confidence here (0.13-0.27 absolute on the issue-25 turning video) though they fitted
    about as well, and the smoother pulled a fast turn's ends back toward the front."""
    from avatarkit.export.images import to_uint8
    from avatarkit.synthetic.head_video import SyntheticFrame, head_video_camera
    from avatarkit.synthetic.mesh_head import MeshHead

    clip = _turn_clip()
    camera = head_video_camera(SIZE, distance=0.5)
    subject = MeshHead.make()
    frames = [SyntheticFrame(i, i / FPS, to_uint8(subject.render(camera, subject.posed(clip, i))[0]))
              for i in range(clip.n_frames)]
    model = HeadModel.template()
    truth = _yaw(clip.rotation)
    r = track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), FPS, TrackOptions())
    assert r.found.all()
    far, front = np.abs(truth) > 40, np.abs(truth) < 10
    share = r.confidence[far].min() / np.median(r.confidence[front])
    yaw = _yaw(r.clip.rotation)
    err = np.abs(yaw - truth)
    # measured: share 0.76 (0.34 before face_scale); yaw within 7.0 degrees at every frame,
    # -45.8 .. 43.6 at the turn's ends (the face mesh reads the far turn a little short)
    assert share > 0.55, (share, r.confidence)
    assert err.max() < 10.0, (yaw, truth)
    assert yaw.min() < -40.0 and yaw.max() > 40.0, yaw
