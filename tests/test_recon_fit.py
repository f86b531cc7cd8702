"""Head fit (issue 8 item 4): named vertices, the camera convention, pose recovery on rendered
template heads with a known answer, the sample portrait, tracker parameters and bad files."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.errors import FormatError, InputError
from avatarkit.head.model import HeadModel
from avatarkit.recon.fit import (FOCAL_35MM, face_width_targets, fit_head, fit_with_params,
                                 landmark_vertices, load_flame_params, portrait_focal, project_mask,
                                 scalp_hint, synthetic_head_view, view_camera)
from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle


@pytest.fixture(scope="module")
def template():
    return HeadModel.template()


def _angle_deg(a, b) -> float:
    r = axis_angle_to_matrix(np.asarray(a)) @ axis_angle_to_matrix(np.asarray(b)).T
    return float(np.degrees(np.linalg.norm(matrix_to_axis_angle(r))))


def test_landmark_vertices_are_where_a_face_has_them(template):
    lm = landmark_vertices(template)
    v = template.v_template
    joints = template.rest_joints()[0]
    # pupils: in front of their eye joints, mirror images of each other
    assert v[lm["left_eye"], 0] > 0 > v[lm["right_eye"], 0]
    np.testing.assert_allclose(v[lm["left_eye"]] * [-1, 1, 1], v[lm["right_eye"]], atol=1e-4)
    assert v[lm["left_eye"], 2] > joints[3, 2]
    # the nose tip is the foremost point of the face, on the midline, below the eyes
    assert abs(v[lm["nose_tip"], 0]) < 0.005
    assert v[lm["nose_tip"], 2] >= v[template.regions["face"], 2].max() - 1e-6
    assert v[lm["nose_tip"], 1] < v[lm["left_eye"], 1]
    # the mouth: below the nose, corners on either side, the chin lowest
    assert v[lm["mouth_center"], 1] < v[lm["nose_tip"], 1]
    assert v[lm["mouth_right"], 0] < v[lm["mouth_center"], 0] < v[lm["mouth_left"], 0]
    assert v[lm["chin"], 1] < v[lm["mouth_center"], 1] - 0.02


def test_view_camera_convention():
    cam = view_camera(np.zeros(3), np.array([0.0, 0.0, -0.7]), 400, 300)
    assert cam.fx == pytest.approx(FOCAL_35MM / 36.0 * 400) == portrait_focal(400, 300)
    np.testing.assert_allclose(cam.camera_center, [0, 0, 0.7], atol=1e-12)
    px, z = cam.project(np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.1]]))
    np.testing.assert_allclose(px[0], [200, 150])
    assert px[1, 0] > 200 and px[2, 1] < 150       # +X to the image's right, +Y up
    assert z[3] < z[0]                               # the face (+Z) is nearer the camera


@pytest.mark.parametrize("rotation", [(0.0, 0.0, 0.0), (0.1, 0.25, 0.05), (-0.08, -0.15, -0.1)])
def test_fit_recovers_a_known_pose(rotation):
    view = synthetic_head_view(rotation, distance=0.6, offset=(0.01, -0.005))
    fit = fit_head(view.analysis, view.segmentation)
    assert _angle_deg(fit.rotation, view.truth.rotation) < 3.0
    assert fit.translation[2] == pytest.approx(view.truth.translation[2], rel=0.03)
    assert fit.residuals["landmark_rms_px"] < 1.5
    # the fitted head covers what the rendered one covered
    mask = project_mask(fit)
    truth = view.alpha > 0.5
    assert (mask & truth).sum() / (mask | truth).sum() > 0.93


def test_fit_on_the_sample_portrait(template):
    from avatarkit.recon.image_io import read_image
    from avatarkit.recon.portrait import analyze_portrait
    from avatarkit.recon.segment import segment_portrait
    from pathlib import Path

    image = read_image(Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg")
    # the six cascade landmarks (the face mesh's 468 give a larger RMS by construction)
    analysis = analyze_portrait(image, detector="cascade")
    seg = segment_portrait(image, analysis)
    fit = fit_head(analysis, seg, template)
    assert fit.residuals["landmark_rms_px"] < 3.0
    assert fit.residuals["outside_fraction"] < 0.02
    assert _angle_deg(fit.rotation, np.zeros(3)) < 15.0
    # a head ~0.7 m from a 50 mm-equivalent lens fills the sample's face box
    assert 0.5 < -fit.translation[2] < 1.0
    hint = scalp_hint(fit)
    assert hint[int(analysis.eye_mid[1]), int(analysis.eye_mid[0])]
    np.testing.assert_allclose(fit.rest_vertices,
                               template.forward(fit.params)[0][0], atol=1e-6)


def test_face_width_targets_of_a_known_ellipse():
    from avatarkit.recon.portrait import analysis_from_box

    a = analysis_from_box((200, 200), (60, 40, 80, 80))
    x, y = np.meshgrid(np.arange(200) + 0.5, np.arange(200) + 0.5)
    mid = a.eye_mid
    half = 1.1 * a.eye_distance
    skin = ((x - mid[0]) / half) ** 2 + ((y - mid[1] - 0.5 * a.eye_distance) / (2 * a.eye_distance)) ** 2 <= 1
    rows = face_width_targets(skin, a, rows=(0.5,))
    np.testing.assert_allclose(rows[0, 1:], [-1.1, 1.1], atol=0.03)
    assert np.isnan(face_width_targets(np.zeros_like(skin), a, rows=(0.5,))[0, 1])


def test_tracker_parameters_fix_the_shape(tmp_path, template):
    view = synthetic_head_view((0.0, 0.1, 0.0))
    shape = np.zeros(template.num_shape, np.float32)
    shape[0] = 0.7
    path = tmp_path / "track.npz"
    np.savez(path, shape=shape[None], rotation=np.zeros((3, 3)), expr=np.zeros((3, 10)))
    params = load_flame_params(path)
    fit = fit_with_params(view.analysis, view.segmentation, template, params)
    np.testing.assert_allclose(fit.shape, shape, atol=1e-6)
    assert fit.source == "imported"
    assert fit.residuals["landmark_rms_px"] < 2.5


def test_bad_tracker_files_name_the_file(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_flame_params(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file at all")
    with pytest.raises(FormatError) as e:
        load_flame_params(junk)
    assert str(junk) in str(e.value)
    no_shape = tmp_path / "noshape.npz"
    np.savez(no_shape, expr=np.zeros((2, 10)))
    with pytest.raises(FormatError, match="no 'shape'"):
        load_flame_params(no_shape)


def test_fit_refuses_a_mismatched_segmentation():
    view = synthetic_head_view()
    from avatarkit.recon.segment import Segmentation

    small = Segmentation(view.segmentation.labels[:100, :100], view.segmentation.skin_model, None, "none")
    with pytest.raises(InputError, match="segmentation is"):
        fit_head(view.analysis, small)
