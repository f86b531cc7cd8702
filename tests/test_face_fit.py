"""Face mesh <-> head model correspondence and the landmark fit (avatarkit.face.correspondence,
avatarkit.face.fit): file reading (FLAME's embedding format), the landmark model against the
head model's own forward pass, exact recovery from exact landmarks, and the fit on renders of
the template with known pose (MediaPipe's models on the render)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avatarkit.errors import FormatError, InputError
from avatarkit.face import models
from avatarkit.face.correspondence import (FACE_OVAL, LandmarkEmbedding, read_embedding,
                                           template_embedding)
from avatarkit.face.fit import LandmarkModel, LandmarkTargets, fit_landmarks
from avatarkit.head.model import HeadModel, HeadParams
from avatarkit.recon.fit import portrait_focal, view_camera


@pytest.fixture(scope="module")
def model():
    return HeadModel.template()


def _flame_style_file(path, model, n=105, seed=0):
    rng = np.random.default_rng(seed)
    b = rng.dirichlet(np.ones(3), n)
    np.savez(path, lmk_face_idx=rng.integers(0, model.num_faces, n).astype(np.int64),
             lmk_b_coords=b, landmark_indices=rng.choice(468, n, replace=False).astype(np.int64))
    return b


def test_reads_flame_style_embedding(tmp_path, model):
    p = tmp_path / "mediapipe_landmark_embedding.npz"
    b = _flame_style_file(p, model)
    emb = read_embedding(p, model.num_faces)
    assert len(emb) == 105
    np.testing.assert_allclose(emb.bary, b)
    pts = emb.points(model.v_template, model.faces)
    tri = model.v_template[model.faces[emb.face_idx]]
    # a barycentric point lies in its triangle's plane, within its bounding box
    assert (pts >= tri.min(1) - 1e-6).all() and (pts <= tri.max(1) + 1e-6).all()
    emb.save(tmp_path / "again.npz")
    again = read_embedding(tmp_path / "again.npz")
    np.testing.assert_array_equal(again.face_idx, emb.face_idx)


@pytest.mark.parametrize("bad", ["missing_key", "lengths", "bary_sum", "face_range", "not_npz"])
def test_bad_embedding_files(tmp_path, model, bad):
    p = tmp_path / "emb.npz"
    n = 10
    data = {"lmk_face_idx": np.arange(n), "lmk_b_coords": np.full((n, 3), 1 / 3),
            "landmark_indices": np.arange(n)}
    if bad == "missing_key":
        del data["lmk_b_coords"]
    elif bad == "lengths":
        data["landmark_indices"] = np.arange(n + 1)
    elif bad == "bary_sum":
        data["lmk_b_coords"] = np.full((n, 3), 0.5)
    elif bad == "face_range":
        data["lmk_face_idx"] = np.arange(n) + model.num_faces
    if bad == "not_npz":
        p.write_bytes(b"not a zip")
    else:
        np.savez(p, **data)
    with pytest.raises(FormatError) as e:
        read_embedding(p, model.num_faces)
    assert str(p) in str(e.value)
    with pytest.raises(InputError, match="not found"):
        read_embedding(tmp_path / "absent.npz")


@pytest.mark.parametrize("mirror", [False, True])
def test_shipped_template_embedding(model, mirror):
    """Both shipped embeddings: the plain face mesh's and the mirror-averaged one's."""
    emb = template_embedding(mirror).check(model.num_faces)
    assert len(emb) > 300 and len(np.unique(emb.mesh_index)) == len(emb)
    assert np.abs(emb.bary.sum(1) - 1).max() < 1e-6 and (emb.bary > -1e-9).all()
    pts = emb.points(model.v_template, model.faces)
    by_index = dict(zip(emb.mesh_index.tolist(), pts))
    # the nose tip stands out in front of the eye corners; the chin is below the mouth
    if {1, 33, 263}.issubset(by_index):
        assert by_index[1][2] > max(by_index[33][2], by_index[263][2])
    if {152, 13}.issubset(by_index):
        assert by_index[152][1] < by_index[13][1]
    # the outline points are on the face's front half
    oval = [by_index[m] for m in FACE_OVAL if m in by_index]
    assert len(oval) > 20


def test_landmark_model_matches_the_head_models_forward(model):
    """Shape + expression + jaw through LandmarkModel equal the full model's LBS (the template
    has no pose correctives, so this is exact)."""
    emb = template_embedding()
    lm = LandmarkModel(model, emb)
    rng = np.random.default_rng(3)
    shape = rng.normal(size=model.num_shape)
    expr = rng.normal(size=model.num_expr) * 0.5
    jaw = np.array([0.25, 0.02, -0.01])
    verts = model.forward(HeadParams(shape=shape.astype(np.float32), expr=expr[None].astype(np.float32),
                                     jaw=jaw[None].astype(np.float32)))[0][0]
    want = emb.points(verts, model.faces)
    got = lm.points_numpy(shape, expr, jaw)
    np.testing.assert_allclose(got, want, atol=2e-5)


def _exact_targets(model, emb, rotation, translation, size, shape=None, expr=None, jaw=None):
    lm = LandmarkModel(model, emb)
    pts = lm.points_numpy(shape, expr, jaw)
    cam = view_camera(rotation, translation, size, size)
    px, z = cam.project(pts)
    # a mesh-like z: camera depth in pixels at the face's distance
    zpx = (z - z.mean()) * cam.fx / z.mean()
    fake = type("Mesh", (), {})()
    fake.points = np.zeros((468, 3))
    fake.points[emb.mesh_index, :2] = px
    fake.points[emb.mesh_index, 2] = zpx
    fake.iris_centers = np.array([[size * 0.4, size * 0.4], [size * 0.6, size * 0.4]])
    return LandmarkTargets.from_mesh(fake, emb, (size, size))


def test_fit_recovers_pose_shape_expression_and_jaw_from_exact_landmarks(model):
    emb = template_embedding()
    size = 512
    rot = Rotation.from_euler("YXZ", [30, -10, 8], degrees=True).as_rotvec()
    trans = np.array([0.01, -0.02, -0.6])
    rng = np.random.default_rng(5)
    shape = rng.normal(size=model.num_shape) * 0.8
    expr = rng.normal(size=model.num_expr) * 0.5
    jaw = np.array([0.15, 0.0, 0.0])
    targets = _exact_targets(model, emb, rot, trans, size, shape, expr, jaw)
    # exact projections carry no face-mesh bias: the view correction is off. With every
    # expression free and near-zero priors the problem is ill-conditioned and converges slowly:
    # at 100 iterations it stopped short by a CPU's rounding (AMD EPYC passed, Intel Xeon read
    # 0.65 px and a jaw 0.044 rad off); run it to convergence (300: 0.10 px, jaw 0.002 rad)
    fit = fit_landmarks(model, emb, targets, portrait_focal(size, size), expr_components=model.num_expr,
                        fit_jaw=True, shape_prior=1e-6, expr_prior=1e-6, jaw_prior=1e-6, iterations=300,
                        view_correction=None)
    err = math.degrees((Rotation.from_rotvec(fit.rotation) * Rotation.from_rotvec(rot).inv()).magnitude())
    # all of shape, expression and jaw are free: a few tenths of a degree trade against them
    assert err < 1.0, err
    assert fit.median_error < 0.5
    # the outline (which holds the chin) counts at OUTLINE_WEIGHT: the jaw is read mostly from
    # the lips, measured 0.024 rad off (it was under 0.02 with the outline at full weight)
    assert np.abs(fit.jaw - jaw).max() < 0.035
    # size and distance trade against the identity (the template's shape includes head size)
    assert np.abs(fit.translation[:2] - trans[:2]).max() < 0.005
    assert abs(fit.translation[2] - trans[2]) < 0.05 * abs(trans[2])


@pytest.mark.skipif(not models.models_available(), reason="face models not installed")
@pytest.mark.parametrize("yaw", [0, 25])
def test_fit_on_template_renders_with_known_pose(model, yaw):
    from avatarkit.face import detect_faces, face_landmarks
    from avatarkit.recon.fit import synthetic_head_view

    emb = template_embedding()
    rot = Rotation.from_euler("YXZ", [yaw, -5, 4], degrees=True).as_rotvec()
    s = synthetic_head_view(rotation=rot, size=512, distance=0.55, n_gaussians=30000, seed=yaw)
    faces = detect_faces(s.image)
    mesh = face_landmarks(s.image, max(faces, key=lambda f: f.score))
    targets = LandmarkTargets.from_mesh(mesh, emb, (512, 512))
    fit = fit_landmarks(model, emb, targets, portrait_focal(512, 512))
    err = math.degrees((Rotation.from_rotvec(fit.rotation) * Rotation.from_rotvec(rot).inv()).magnitude())
    # measured on such renders (benchmarks/face.py): 2-6.5 degrees, 1-2.5 px median at yaw <= 25
    # (the target of 2 degrees is NOT met): the face mesh's answers on the template head
    # drift with the view by ~5% of the eye distance (median), which no fixed correspondence removes
    assert err < 8.0, err
    assert fit.median_error < 4.0, fit.median_error


@pytest.mark.skipif(not models.models_available(), reason="face models not installed")
@pytest.mark.parametrize("yaw, max_deg, max_px", [(0, 3.0, 2.0), (25, 5.5, 3.5)])
def test_fit_on_shaded_template_renders(model, yaw, max_deg, max_px):
    """Lambert-shaded renders (`synthetic.shading`, the benchmark's target renders): the fit's
    defaults (no depth term, outline at OUTLINE_WEIGHT) read the pose better than the previous
    settings (depth term 0.05, outline at full weight) on the same targets."""
    from avatarkit.face import detect_faces, face_landmarks
    from avatarkit.face.fit import DEPTH_WEIGHT
    from avatarkit.recon.fit import synthetic_head_view
    from avatarkit.synthetic.shading import LIGHT

    emb = template_embedding()
    rot = Rotation.from_euler("YXZ", [yaw, -5, 4], degrees=True).as_rotvec()
    s = synthetic_head_view(rotation=rot, size=512, distance=0.55, n_gaussians=30000, seed=yaw, light=LIGHT)
    mesh = face_landmarks(s.image, max(detect_faces(s.image), key=lambda f: f.score))
    targets = LandmarkTargets.from_mesh(mesh, emb, (512, 512))
    f = portrait_focal(512, 512)
    err = lambda r: math.degrees((Rotation.from_rotvec(r) * Rotation.from_rotvec(rot).inv()).magnitude())
    fit = fit_landmarks(model, emb, targets, f)
    before = fit_landmarks(model, emb, targets, f, depth_weight=DEPTH_WEIGHT, outline_weight=1.0)
    # measured: yaw 0 2.02 deg / 1.24 px (previous 2.52 / 1.30); yaw 25 4.14 / 2.51 (4.79 / 2.69);
    # the benchmark's median over 12 cases: 1.77 deg (previous 2.69)
    assert err(fit.rotation) < max_deg, err(fit.rotation)
    assert fit.median_error < max_px, fit.median_error
    assert err(fit.rotation) < err(before.rotation) - 0.2


def test_outline_weight_scales_only_the_outline_points():
    from avatarkit.face.fit import with_outline_weight

    k = 5
    normal = np.zeros((k, 2))
    normal[[1, 3]] = [[1.0, 0.0], [0.0, 1.0]]
    t = LandmarkTargets(np.zeros((k, 2)), np.zeros(k), np.array([1.0, 2.0, 0.5, 1.0, 3.0]), normal, 10.0, (64, 64))
    out = with_outline_weight(t, 0.25)
    assert np.allclose(out.weight, [1.0, 0.5, 0.5, 0.25, 3.0])
    assert out.xy is t.xy and out.normal is t.normal and out.iod == t.iod


@pytest.mark.slow
@pytest.mark.skipif(not models.models_available(), reason="face models not installed")
def test_mirror_embedding_is_what_the_script_makes(model):
    """The shipped embedding for the mirror-averaged face mesh is `make_template_embedding` with
    that mesh at `MIRROR_TEMPLATE_VIEWS` (scripts/make_face_correspondence.py --mirror): the
    same points on the same triangles (the renders and the mesh model are deterministic)."""
    from avatarkit.face.correspondence import MIRROR_TEMPLATE_VIEWS, make_template_embedding

    made, _ = make_template_embedding(MIRROR_TEMPLATE_VIEWS, mirror=True)
    shipped = template_embedding(mirror=True)
    assert np.array_equal(made.mesh_index, shipped.mesh_index)
    assert np.array_equal(made.face_idx, shipped.face_idx)
    assert np.abs(made.bary - shipped.bary).max() < 1e-6


def test_mirror_embedding_views_cover_the_pitch():
    """The views the mirror-averaged mesh's embedding is made from: frontal first (the points
    are cast along its rays), yaw to +-45 and pitch to +-20 degrees, every pair once."""
    from avatarkit.face.correspondence import MIRROR_TEMPLATE_VIEWS

    v = np.array(MIRROR_TEMPLATE_VIEWS)
    assert tuple(v[0]) == (0.0, 0.0) and len(set(map(tuple, v))) == len(v) == 35
    assert v[:, 0].min() == -45 and v[:, 0].max() == 45 and v[:, 1].min() == -20 and v[:, 1].max() == 20
