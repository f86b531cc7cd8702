"""Eye rotations (FLAME `eyes_pose`) from the iris centres the face mesh found.

Each eye is a sphere of radius `EYE_RADIUS` about its eye joint (the template's eyeballs are
12 mm spheres centred on joints 3 and 4; FLAME's eyeballs are the same size). With the head's
pose known (rotation R, translation t: X_view = R X_head + t, OpenCV camera = C X_view with
C = diag(1, -1, -1), as `face.fit`), the ray through the iris centre's pixel meets the eyeball's
front surface at the iris; the gaze is the direction from the eye's centre to that point.
Expressed in the head's frame, the eye's rotation is the shortest rotation taking the rest gaze
(+Z, where the face looks) to it. A ray that misses the sphere (a noisy iris at the eye's edge)
uses the point of the ray nearest the centre, pushed onto the sphere. Angles are clamped to
`MAX_ANGLE` (eyes do not turn further).

FLAME order: eyes_pose = (left eye (joint 3, +X, the subject's left; the face mesh's second
iris), right eye (joint 4; the first iris)).
"""
from __future__ import annotations

import numpy as np

from avatarkit.rotations import axis_angle_to_matrix

EYE_RADIUS = 0.012
MAX_ANGLE = np.radians(40.0)
#: the share of the tracked change of gaze that turns an avatar's eyes (`relative_eyes`' gain,
#: as `track.build_pose.eyes_from_build_frame` drives a built avatar): 1 turns them by the whole
#: tracked change. Read at the call, so setting it takes effect
RELATIVE_GAIN = 1.0
_C = np.diag([1.0, -1.0, -1.0])
LEFT_EYE_JOINT, RIGHT_EYE_JOINT = 3, 4


def _gaze_point(centre: np.ndarray, ray: np.ndarray, radius: float) -> np.ndarray:
    """Front intersection of the ray from the camera origin along unit `ray` with the sphere
    (centre (3,), camera coordinates); the nearest point pushed onto it when the ray misses."""
    b = float(ray @ centre)
    closest = b * ray
    d2 = float(np.sum((centre - closest) ** 2))
    if d2 >= radius ** 2:
        off = closest - centre
        return centre + radius * off / max(np.linalg.norm(off), 1e-12)
    return (b - np.sqrt(radius ** 2 - d2)) * ray


def eye_rotation(gaze_head: np.ndarray, max_angle: float | None = None) -> np.ndarray:
    """(3,) axis-angle of the shortest rotation taking +Z to unit `gaze_head` (head frame),
    its angle clamped to max_angle."""
    max_angle = MAX_ANGLE if max_angle is None else max_angle
    z = np.array([0.0, 0.0, 1.0])
    g = gaze_head / max(np.linalg.norm(gaze_head), 1e-12)
    axis = np.cross(z, g)
    s = np.linalg.norm(axis)
    angle = np.arctan2(s, float(z @ g))
    if s < 1e-12:
        return np.zeros(3)
    return axis / s * min(angle, max_angle)


def eyes_pose(iris_px: np.ndarray, eye_centres_head: np.ndarray, rotation: np.ndarray,
              translation: np.ndarray, focal: float, principal: tuple[float, float],
              radius: float | None = None) -> np.ndarray:
    """FLAME eyes_pose (6,) float64.

    iris_px: (2, 2) pixel centres of the irises (face mesh order: subject's right, then left);
    eye_centres_head: (2, 3) eye joint positions in the head's rest frame (joint 3 left, joint 4
    right: FLAME order); rotation (3,) axis-angle, translation (3,): the head's view-frame pose.
    """
    radius = EYE_RADIUS if radius is None else radius
    R = axis_angle_to_matrix(np.asarray(rotation, np.float64)).astype(np.float64)
    t = np.asarray(translation, np.float64)
    out = np.zeros(6)
    # FLAME slot 0 = left eye = the mesh's second iris; slot 1 = right eye = the first
    for slot, iris in ((0, iris_px[1]), (1, iris_px[0])):
        centre_cam = _C @ (R @ eye_centres_head[slot] + t)
        ray = np.array([(iris[0] - principal[0]) / focal, (iris[1] - principal[1]) / focal, 1.0])
        ray /= np.linalg.norm(ray)
        p = _gaze_point(centre_cam, ray, radius)
        gaze_head = R.T @ (_C @ (p - centre_cam))
        out[3 * slot:3 * slot + 3] = eye_rotation(gaze_head)
    return out


def project_gaze(eyes: np.ndarray, eye_centres_head: np.ndarray, rotation: np.ndarray,
                 translation: np.ndarray, focal: float, principal: tuple[float, float],
                 radius: float | None = None) -> np.ndarray:
    """Inverse of `eyes_pose` for tests and overlays: (2, 2) pixels of the iris centres
    (mesh order: subject's right, then left) of eyes turned by `eyes` (6,)."""
    radius = EYE_RADIUS if radius is None else radius
    R = axis_angle_to_matrix(np.asarray(rotation, np.float64)).astype(np.float64)
    t = np.asarray(translation, np.float64)
    out = np.zeros((2, 2))
    for slot, row in ((0, 1), (1, 0)):
        g = axis_angle_to_matrix(np.asarray(eyes[3 * slot:3 * slot + 3], np.float64)) @ np.array([0, 0, 1.0])
        p_cam = _C @ (R @ (eye_centres_head[slot] + radius * g) + t)
        out[row] = (focal * p_cam[0] / p_cam[2] + principal[0], focal * p_cam[1] / p_cam[2] + principal[1])
    return out


def relative_eyes(eyes: np.ndarray, reference: np.ndarray, gain: float = 1.0) -> np.ndarray:
    """(T, 6) eye rotations relative to the `reference` (6,): per eye R_t R_ref^T, so the
    reference itself becomes no rotation; `gain` scales each relative rotation's angle (its axis
    kept: 0 holds the eyes at the reference's gaze). An avatar built from a frame carries that frame's
    eyes painted on its eyeballs (iris where the photo showed it): driving it with the tracked
    gaze as it is turns the painted iris by the whole tracked angle, including the estimate's
    constant bias (measured on talking_man_glasses.mp4: ~25-30 degrees downward at every
    frame, the iris ray meets the model's eyeball far from its front), and the eyeballs show
    their unpainted white. Relative to the build frame, the avatar's eyes look as the video's
    did there, and the gaze's changes drive them."""
    from avatarkit.rotations import matrix_to_axis_angle

    e = np.asarray(eyes, np.float64).reshape(-1, 2, 3)
    R = axis_angle_to_matrix(e.reshape(-1, 3)).astype(np.float64).reshape(-1, 2, 3, 3)   # (T, 2, 3, 3)
    ref = axis_angle_to_matrix(np.asarray(reference, np.float64).reshape(2, 3)).astype(np.float64)
    rel = R @ np.swapaxes(ref, -1, -2)[None]
    return float(gain) * matrix_to_axis_angle(rel.reshape(-1, 3, 3)).astype(np.float64).reshape(-1, 6)
