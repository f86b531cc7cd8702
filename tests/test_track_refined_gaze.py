"""With the pose refined after the landmark fit (`track_frames(refiner=)`), the eyes are read
again from the irises at the refined pose: the gaze is relative to the head, so a head turned by
the refinement needs other eye rotations for the same irises."""
from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.head.model import HeadModel
from avatarkit.motion.clip import MotionClip
from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from avatarkit.synthetic.head_video import HeadVideo, head_video_camera
from avatarkit.track import TrackOptions, track_frames
from avatarkit.track import gaze
from avatarkit.track.photometric import Refinement

SIZE = 224
TURN = np.radians(4.0)            # the stub refinement's yaw change


class TurningRefiner:
    """A stand-in for `photometric.PoseRefiner`: every refined frame's head is the landmark
    fit's turned TURN about the camera's vertical axis and moved 5 mm sideways."""

    camera = SimpleNamespace(width=SIZE)

    def shrink(self, rgb):
        return rgb

    def refine(self, rgb, rotation, translation, jaw, expr, eyes):
        dR = axis_angle_to_matrix(np.array([0.0, TURN, 0.0])).astype(np.float64)
        R = dR @ axis_angle_to_matrix(np.asarray(rotation, np.float64)).astype(np.float64)
        rot = np.asarray(matrix_to_axis_angle(R), np.float64).reshape(3)
        tr = np.asarray(translation, np.float64) + np.array([0.005, 0.0, 0.0])
        return Refinement(rot, tr, 1, 1000, 0.1, 0.5, np.asarray(jaw, np.float64))


@pytest.fixture(scope="module")
def frames():
    T = 4
    t = np.linspace(0, 1, T)
    rot = np.stack([np.zeros(T), 0.2 * t, np.zeros(T)], axis=1)
    clip = MotionClip(fps=24.0, rotation=rot, translation=np.zeros((T, 3)), neck=np.zeros((T, 3)),
                      jaw=np.zeros((T, 3)), eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))
    return list(HeadVideo(clip, head_video_camera(SIZE, distance=0.45), n_gaussians=15000).frames())


def test_refined_frames_read_their_gaze_at_the_refined_pose(frames):
    model = HeadModel.template()
    options = TrackOptions(smoothing=0.0, calibration_frames=0)
    plain = track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), 24.0, options)
    refined = track_frames(frames, model, np.zeros(model.num_shape), (SIZE, SIZE), 24.0, options,
                           meshes=plain.meshes, refiner=TurningRefiner())
    joints = model.rest_joints()[0]
    centres = np.asarray(joints[[gaze.LEFT_EYE_JOINT, gaze.RIGHT_EYE_JOINT]], np.float64)
    focal = plain.camera.fx
    moved = 0.0
    for t, mesh in enumerate(plain.meshes):
        assert mesh is not None
        rot, tr = refined.raw["rotation"][t], refined.raw["translation"][t]
        # the refined pose is the stub's, and the eyes are what the irises say at it
        R = axis_angle_to_matrix(rot) @ axis_angle_to_matrix(plain.raw["rotation"][t]).T
        assert np.degrees(np.linalg.norm(matrix_to_axis_angle(R))) == pytest.approx(4.0, abs=1e-3)
        want = gaze.eyes_pose(np.asarray(mesh.iris_centers, np.float64), centres, rot, tr, focal,
                              (SIZE / 2, SIZE / 2))
        np.testing.assert_allclose(refined.raw["eyes"][t], want, atol=1e-9)
        moved = max(moved, float(np.abs(refined.raw["eyes"][t] - plain.raw["eyes"][t]).max()))
    # a 4-degree turn of the head is a few degrees of eye rotation the other way
    assert moved > np.radians(1.0)
