"""The face mesh's left/right pairing and the mirror-averaged face mesh (`face.landmarks`):
the pairing is an involution that fixes exactly the midline and maps the head's symmetric
geometry onto itself; the averaged mesh of a mirrored image is the mirrored mesh."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.face import models
from avatarkit.face.landmarks import (MESH_MIDLINE, N_LANDMARKS, face_landmarks, mirror_pairs,
                                      mirror_points, roi_from_face, roi_from_mesh)
from avatarkit.face.roi import Roi

needs_models = pytest.mark.skipif(not models.models_available(), reason="face models not installed")
SAMPLE = "samples/portrait.jpg"


def test_pairing_is_an_involution_fixing_the_midline():
    p = mirror_pairs()
    assert p.shape == (N_LANDMARKS,) and sorted(p.tolist()) == list(range(N_LANDMARKS))
    np.testing.assert_array_equal(p[p], np.arange(N_LANDMARKS))
    np.testing.assert_array_equal(np.flatnonzero(p == np.arange(N_LANDMARKS)), sorted(MESH_MIDLINE))
    # MediaPipe's named points (eye corners, mouth corners, the outline's widest points)
    for a, b in ((33, 263), (133, 362), (61, 291), (234, 454), (78, 308), (127, 356)):
        assert p[a] == b and p[b] == a


def test_pairing_maps_the_symmetric_template_head_onto_itself():
    """The template head is left/right symmetric; its embedded face-mesh points (made from the
    mesh model's answers, independently of the pairing) sit where their partners' mirror
    images are: about a millimetre, against 40 mm for a pairing that ignores the sides."""
    from avatarkit.face.correspondence import template_embedding
    from avatarkit.head.model import HeadModel, HeadParams

    model = HeadModel.template()
    emb = template_embedding()
    rest = model.forward(HeadParams(shape=np.zeros(model.num_shape, np.float32),
                                    expr=np.zeros((1, model.num_expr), np.float32)))[0][0]
    points = emb.points(np.asarray(rest, np.float64), model.faces)          # (K, 3) metres
    row = {int(m): k for k, m in enumerate(emb.mesh_index)}
    p = mirror_pairs()
    both = [(k, row[int(p[m])]) for k, m in enumerate(emb.mesh_index) if int(p[m]) in row]
    assert len(both) > 300
    a = points[[k for k, _ in both]]
    b = points[[j for _, j in both]] * np.array([-1.0, 1.0, 1.0])
    d = np.linalg.norm(a - b, axis=1)
    eye = np.linalg.norm(points[row[33]] - points[row[263]])
    assert np.median(d) < 0.03 * eye and d.max() < 0.12 * eye


@needs_models
def test_the_mesh_of_a_symmetric_face_is_symmetric_under_the_pairing():
    """On an exactly symmetric image (a frontal template render averaged with its mirror) the
    mesh model's points land near their partners' mirror images, and pairing every point with
    the nearest mirrored point (one-to-one) gives exactly `mirror_pairs`
    (`scripts/check_mesh_mirror.py`)."""
    from scipy.optimize import linear_sum_assignment

    from avatarkit.face import detect_faces
    from avatarkit.recon.fit import synthetic_head_view

    image = synthetic_head_view(size=512, n_gaussians=40000, seed=3).image.astype(np.float32)
    image = np.round((image + image[:, ::-1]) / 2).astype(np.uint8)
    W = image.shape[1]
    # the plain mesh: the averaged one is symmetric under any involution it is averaged with
    mesh = face_landmarks(image, max(detect_faces(image), key=lambda f: f.score), mirror=False)
    p = mesh.points[:, :2].astype(np.float64)
    eye = np.linalg.norm(p[33] - p[263])
    d = np.linalg.norm(mirror_points(p, W) - p, axis=1)
    assert np.median(d) < 0.05 * eye and d.max() < 0.1 * eye
    m = p.copy()
    m[:, 0] = W - m[:, 0]
    rows, cols = linear_sum_assignment(np.linalg.norm(m[:, None] - p[None], axis=2))
    np.testing.assert_array_equal(cols[np.argsort(rows)], mirror_pairs())


def _mirrored_roi(roi: Roi, width: int) -> Roi:
    """The region of the mirror image that sees the mirror of what `roi` sees."""
    return Roi((width - roi.center[0], roi.center[1]), roi.side, -roi.angle)


@needs_models
def test_mirror_averaging_gives_the_mirrored_landmarks_of_a_mirrored_image():
    from avatarkit.face import detect_faces
    from avatarkit.recon.image_io import read_image

    image = read_image(SAMPLE)
    flipped = np.ascontiguousarray(image[:, ::-1])
    W = image.shape[1]
    roi = roi_from_face(max(detect_faces(image), key=lambda f: f.score))
    gaps = {}
    for refine in (False, True):
        for mirror in (False, True):
            a = face_landmarks(image, roi, refine=refine, mirror=mirror)
            b = face_landmarks(flipped, _mirrored_roi(roi, W), refine=refine, mirror=mirror)
            eye = float(np.linalg.norm(a.points[33, :2] - a.points[263, :2]))
            expected = mirror_points(a.points, W)
            d = np.linalg.norm(expected[:, :2] - b.points[:, :2], axis=1) / eye
            gaps[refine, mirror] = (float(np.median(d)), float(d.max()))
            if mirror and not refine:
                # the depth too, and the irises: the subject's right eye of the mirror image
                # is the left eye of the image
                np.testing.assert_allclose(b.points[:, 2], expected[:, 2], atol=1e-3 * eye)
                iris = a.iris_centers[::-1].copy()
                iris[:, 0] = W - iris[:, 0]
                np.testing.assert_allclose(b.iris_centers, iris, atol=1e-3 * eye)
                assert abs(a.presence - b.presence) < 1e-4
    # the plain model is not mirror-consistent (what the average removes): measured 2.4% of
    # the eye distance median, 5-6% at most
    assert gaps[False, False][0] > 0.01 and gaps[True, False][0] > 0.01
    # one averaged pass is, to the resampling's rounding
    assert gaps[False, True][1] < 1e-3
    # with the second pass, to what its region (placed by the plain first pass) shifts:
    # measured 0.4% median, 1.3% at most
    assert gaps[True, True][0] < 0.3 * gaps[True, False][0] and gaps[True, True][1] < 0.03, gaps


@needs_models
def test_the_tracker_switch_reaches_the_face_mesh():
    """`TrackOptions(mirror_landmarks=...)` decides the tracker's face mesh, whatever
    `face_landmarks`' default (`MIRROR_AVERAGE`); off by default (docs/face.md)."""
    from avatarkit.face import detect_faces
    from avatarkit.head.model import HeadModel
    from avatarkit.recon.image_io import read_image
    from avatarkit.face import landmarks
    from avatarkit.track.tracker import FrameTracker, TrackOptions

    assert TrackOptions().mirror_landmarks is False and landmarks.MIRROR_AVERAGE is False
    image = read_image(SAMPLE)
    face = max(detect_faces(image), key=lambda f: f.score)
    model = HeadModel.template()
    for mirror in (False, True):
        ft = FrameTracker(model, np.zeros(model.num_shape), image.shape[:2][::-1],
                          TrackOptions(mirror_landmarks=mirror))
        first = ft.landmarks(image)                                   # detection
        np.testing.assert_allclose(first.points, face_landmarks(image, face, mirror=mirror).points, atol=1e-4)
        again = ft.landmarks(image)                                   # the previous mesh's region
        expected = face_landmarks(image, roi_from_mesh(first.points), mirror=mirror)
        np.testing.assert_allclose(again.points, expected.points, atol=1e-4)
        other = face_landmarks(image, roi_from_mesh(first.points), mirror=not mirror)
        assert np.abs(again.points[:, :2] - other.points[:, :2]).max() > 0.5
