"""HeadModel / HeadParams / LBS: the FLAME maths against a plain reference and its torch twin."""
from __future__ import annotations

import types
import warnings

import numpy as np
import pytest
import scipy.sparse

from avatarkit.errors import InputError
from avatarkit.head import FLAME_PARENTS, HeadModel, HeadParams
from avatarkit.head.lbs import lbs_reference
from avatarkit.head.model import CoefficientCountWarning
from avatarkit.rotations import axis_angle_to_matrix


def tiny_model(seed=0, V=60, S=4, E=3, posedirs=True, sparse=True) -> HeadModel:
    """A random but valid 5-joint model: blob vertices, random convex skinning weights,
    blendshapes and pose correctives, a J_regressor averaging vertex groups."""
    rng = np.random.default_rng(seed)
    v = rng.normal(scale=0.05, size=(V, 3))
    faces = np.stack([np.arange(V - 2), np.arange(1, V - 1), np.arange(2, V)], 1)
    w = rng.random((V, 5)) ** 3
    w /= w.sum(1, keepdims=True)
    groups = rng.integers(0, 5, V)
    groups[:5] = np.arange(5)
    jr = np.zeros((5, V))
    for j in range(5):
        jr[j, groups == j] = 1.0 / np.sum(groups == j)
    return HeadModel(faces=faces, v_template=v, shapedirs=rng.normal(scale=0.01, size=(V, 3, S)),
                     exprdirs=rng.normal(scale=0.01, size=(V, 3, E)),
                     posedirs=rng.normal(scale=0.01, size=(36, V * 3)) if posedirs else None,
                     J_regressor=scipy.sparse.csr_matrix(jr) if sparse else jr,
                     kintree_parents=FLAME_PARENTS, weights=w, name="tiny")


def random_params(model, T=3, seed=1, scale=0.4) -> HeadParams:
    rng = np.random.default_rng(seed)
    return HeadParams(expr=rng.normal(size=(T, model.num_expr)), rotation=rng.normal(scale=scale, size=(T, 3)),
                      neck=rng.normal(scale=scale, size=(T, 3)), jaw=rng.normal(scale=scale, size=(T, 3)),
                      eyes=rng.normal(scale=scale, size=(T, 6)), translation=rng.normal(scale=0.1, size=(T, 3)),
                      shape=rng.normal(size=model.num_shape))


@pytest.mark.parametrize("posedirs,sparse", [(True, True), (False, False)])
def test_numpy_matches_plain_reference(posedirs, sparse):
    m = tiny_model(posedirs=posedirs, sparse=sparse)
    p = random_params(m, T=4)
    v, A = m.forward(p)
    vr, Ar = lbs_reference(m.shaped_vertices(p), m.J_regressor, m.kintree_parents, m.weights,
                           p.full_pose, p.translation, m.posedirs)
    assert v.shape == (4, m.num_vertices, 3) and A.shape == (4, 5, 4, 4)
    np.testing.assert_allclose(v, vr, atol=2e-6)
    np.testing.assert_allclose(A, Ar, atol=2e-6)


def test_blendshapes_are_linear_and_joints_follow_them():
    m = tiny_model()
    p = random_params(m, T=2)
    vs = m.shaped_vertices(p)
    expect = m.v_template + np.einsum("vcs,s->vc", m.shapedirs, p.shape)[None] \
        + np.einsum("vce,te->tvc", m.exprdirs, p.expr)
    np.testing.assert_allclose(vs, expect, atol=1e-6)
    np.testing.assert_allclose(m.rest_joints(p), np.einsum("jv,tvc->tjc", m.J_regressor.toarray(), vs), atol=1e-6)


def test_per_frame_shape():
    m = tiny_model()
    rng = np.random.default_rng(3)
    shapes = rng.normal(size=(3, m.num_shape))
    p = HeadParams(shape=shapes, expr=np.zeros((3, m.num_expr)))
    v, _ = m.forward(p)
    for t in range(3):
        vt, _ = m.forward(HeadParams(shape=shapes[t]))
        np.testing.assert_allclose(v[t], vt[0], atol=1e-6)


def test_zero_pose_gives_template():
    m = tiny_model()
    v, A = m.forward(HeadParams(num_frames=2))
    np.testing.assert_allclose(v, np.broadcast_to(m.v_template, v.shape), atol=1e-7)
    np.testing.assert_allclose(A, np.broadcast_to(np.eye(4), A.shape), atol=1e-7)


def test_root_rotation_is_rigid_about_root_joint():
    m = tiny_model(posedirs=True)  # the root is not in the pose-corrective features
    aa = np.array([0.3, -0.5, 0.2])
    t = np.array([0.01, -0.02, 0.3])
    v, A = m.forward(HeadParams(rotation=aa, translation=t))
    R = axis_angle_to_matrix(aa)
    j0 = m.rest_joints()[0, 0]
    expect = (m.v_template - j0) @ R.T + j0 + t
    np.testing.assert_allclose(v[0], expect, atol=1e-6)
    for j in range(5):  # every joint transform is the same rigid motion
        np.testing.assert_allclose(A[0, j, :3, :3], R, atol=1e-6)


def test_joint_transforms_map_rest_joints_to_posed_joints():
    m = tiny_model()
    p = random_params(m, T=2)
    _, A = m.forward(p)
    J = m.rest_joints(p).astype(np.float64)
    # posed joint j = world transform of its chain applied at the joint: A_j J_j (A = G [I | -J])
    R = axis_angle_to_matrix(p.full_pose)
    for t in range(2):
        G = [None] * 5
        for j in range(5):
            local = np.eye(4)
            local[:3, :3] = R[t, j]
            local[:3, 3] = J[t, j] - (J[t, FLAME_PARENTS[j]] if j else 0)
            G[j] = local if j == 0 else G[FLAME_PARENTS[j]] @ local
            posed = A[t, j, :3, :3] @ J[t, j] + A[t, j, :3, 3]
            np.testing.assert_allclose(posed, G[j][:3, 3] + p.translation[t], atol=1e-6)


def test_torch_twin_matches_numpy_and_is_differentiable():
    torch = pytest.importorskip("torch")
    m = tiny_model()
    p = random_params(m, T=3)
    v, A = m.forward(p)
    vt, At = m.forward_torch(p)
    np.testing.assert_allclose(vt.numpy(), v, atol=2e-6)
    np.testing.assert_allclose(At.numpy(), A, atol=2e-6)

    params = {k: torch.tensor(np.asarray(getattr(p, k), np.float64), requires_grad=True)
              for k in ("expr", "rotation", "translation", "neck", "jaw", "eyes", "shape")}
    out, _ = m.forward_torch(params)
    assert out.dtype == torch.float64
    np.testing.assert_allclose(out.detach().numpy(), v, atol=2e-6)

    probe = torch.tensor(np.random.default_rng(5).normal(size=out.shape))

    def f(rotation, jaw, eyes, expr, shape):  # a scalar of the output keeps gradcheck cheap
        q = dict(params, rotation=rotation, jaw=jaw, eyes=eyes, expr=expr, shape=shape)
        return (m.forward_torch(q)[0] * probe).sum()
    assert torch.autograd.gradcheck(f, (params["rotation"], params["jaw"], params["eyes"], params["expr"],
                                        params["shape"]), eps=1e-6, atol=1e-5, fast_mode=True)


def test_torch_gradient_is_finite_at_zero_pose():
    torch = pytest.importorskip("torch")
    m = tiny_model()
    pose = {k: torch.zeros(1, w, dtype=torch.float64, requires_grad=True)
            for k, w in (("rotation", 3), ("neck", 3), ("jaw", 3), ("eyes", 6))}
    v, _ = m.forward_torch(pose)
    v.square().sum().backward()
    for t in pose.values():
        assert torch.isfinite(t.grad).all()
        # d(sum v^2)/d(rotation) at 0 is 2 sum v x ... non-zero in general: rotation does act
    assert pose["rotation"].grad.abs().sum() > 0


def test_expression_count_mismatch_truncates_or_pads_with_warning():
    m = tiny_model(E=3)
    base = np.array([[0.5, -1.0, 2.0]])
    ref, _ = m.forward(HeadParams(expr=base))
    with pytest.warns(CoefficientCountWarning, match="ignoring"):
        longer, _ = m.forward(HeadParams(expr=np.array([[0.5, -1.0, 2.0, 7.0, 1.0]])))
    np.testing.assert_allclose(longer, ref, atol=1e-7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # dropping zeros loses nothing: no warning
        same, _ = m.forward(HeadParams(expr=np.array([[0.5, -1.0, 2.0, 0.0, 0.0]])))
    np.testing.assert_allclose(same, ref, atol=1e-7)
    with pytest.warns(CoefficientCountWarning, match="padding"):
        shorter, _ = m.forward(HeadParams(expr=np.array([[0.5, -1.0]])))
    padded, _ = m.forward(HeadParams(expr=np.array([[0.5, -1.0, 0.0]])))
    np.testing.assert_allclose(shorter, padded, atol=1e-7)


def test_params_from_flame_names_and_clip():
    d = {"rotation": np.zeros((2, 3)), "translation": np.ones((2, 3)), "neck_pose": np.full((2, 3), 0.1),
         "jaw_pose": np.full((2, 3), 0.2), "eyes_pose": np.full((2, 6), 0.3), "expr": np.ones((2, 5)),
         "shape": np.ones((1, 7)), "static_offset": np.zeros((1, 10, 3))}
    p = HeadParams.from_dict(d)
    assert p.num_frames == 2 and p.shape.shape == (7,)
    np.testing.assert_allclose(p.neck, 0.1)
    np.testing.assert_allclose(p.eyes, 0.3)
    back = p.to_dict()
    assert set(back) >= {"neck_pose", "jaw_pose", "eyes_pose", "rotation", "translation", "expr", "shape"}
    clip = types.SimpleNamespace(fps=25.0, rotation=np.arange(12.0).reshape(4, 3), translation=np.zeros((4, 3)),
                                 neck=np.zeros((4, 3)), jaw=np.zeros((4, 3)), eyes=np.zeros((4, 6)),
                                 expr=np.zeros((4, 2)), shape=np.zeros(3))
    q = HeadParams.from_clip(clip, frames=[1, 3])
    assert q.num_frames == 2
    np.testing.assert_allclose(q.rotation, [[3, 4, 5], [9, 10, 11]])
    np.testing.assert_allclose(HeadParams.from_clip(clip).select(slice(1, 3)).rotation, clip.rotation[1:3])


@pytest.mark.parametrize("kwargs,match", [
    ({"jaw": np.zeros((2, 4))}, "jaw must have shape"),
    ({"jaw": np.zeros((2, 3)), "neck": np.zeros((3, 3))}, "has 2 frames, expected 3"),
    ({"eyes": np.full((1, 6), np.nan)}, "NaN"),
    ({"shape": np.zeros((2, 2, 2))}, "shape must have shape"),
    ({"expr": np.zeros((2, 3, 1))}, "expr must have shape"),
])
def test_bad_params_raise_input_error(kwargs, match):
    with pytest.raises(InputError, match=match):
        HeadParams(**kwargs)


def test_bad_model_arrays_raise_input_error():
    m = tiny_model()
    good = dict(faces=m.faces, v_template=m.v_template, shapedirs=m.shapedirs, exprdirs=m.exprdirs,
                J_regressor=m.J_regressor, kintree_parents=m.kintree_parents, weights=m.weights)
    for key, value, match in [("weights", m.weights[:, :4], "weights must have shape"),
                              ("kintree_parents", [-1, 0, 3, 1, 1], "kintree_parents"),
                              ("faces", m.faces + 1000, "faces index"),
                              ("shapedirs", m.shapedirs[:5], "shapedirs must have shape")]:
        with pytest.raises(InputError, match=match):
            HeadModel(**{**good, key: value})


def test_region_faces_modes():
    m = tiny_model()
    m.regions = {"part": np.arange(10)}
    all_ = set(m.region_faces("part", "all"))
    maj = set(m.region_faces("part", "majority"))
    any_ = set(m.region_faces("part", "any"))
    assert all_ == set(range(8)) and all_ < maj < any_
    with pytest.raises(InputError, match="unknown region"):
        m.region_faces("nope")
