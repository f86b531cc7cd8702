"""Triangle frames: GaussianAvatars' definition, orthonormal right-handed, batched."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avatarkit.errors import InputError
from avatarkit.rig import degenerate_faces, triangle_frames


def _unit(x):
    return x / np.linalg.norm(x)


def reference_frame(v0, v1, v2):
    """One triangle, written out as GaussianAvatars' compute_face_orientation does it."""
    a0 = _unit(v1 - v0)
    a1 = _unit(np.cross(a0, v2 - v0))
    a2 = -_unit(np.cross(a1, a0))
    r = np.stack([a0, a1, a2], axis=1)
    s0 = np.linalg.norm(v1 - v0)
    s1 = abs(np.dot(a2, v2 - v0))
    return (v0 + v1 + v2) / 3, r, (s0 + s1) / 2


def random_mesh(n_faces=200, seed=0):
    rng = np.random.default_rng(seed)
    v = rng.normal(scale=0.1, size=(3 * n_faces, 3))
    return v, np.arange(3 * n_faces).reshape(n_faces, 3)


def test_matches_gaussianavatars_reference_triangle_by_triangle():
    v, f = random_mesh()
    t, r, k = triangle_frames(v, f)
    for i, (a, b, c) in enumerate(f):
        t_ref, r_ref, k_ref = reference_frame(v[a], v[b], v[c])
        np.testing.assert_allclose(t[i], t_ref, atol=1e-12)
        np.testing.assert_allclose(r[i], r_ref, atol=1e-12)
        np.testing.assert_allclose(k[i], k_ref, rtol=1e-12)


def test_rotations_are_orthonormal_and_right_handed():
    v, f = random_mesh(500, seed=1)
    _, r, _ = triangle_frames(v, f)
    np.testing.assert_allclose(r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)


def test_analytic_right_triangle():
    # v0 at origin, v1 along +x (length 2), v2 along +y (height 3): e0=+x, n=+z, b = e0 x n = -y
    v = np.array([[0.0, 0, 0], [2, 0, 0], [0, 3, 0]])
    t, r, k = triangle_frames(v, np.array([[0, 1, 2]]))
    np.testing.assert_allclose(t[0], [2 / 3, 1, 0])
    np.testing.assert_allclose(r[0], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)
    assert k[0] == pytest.approx((2 + 3) / 2)  # mean of |v1 - v0| and the height from v2


def test_height_not_edge_for_slanted_triangle():
    # v2 sits above the far end of the v0v1 line: the height is 1, not |v2 - v0| = sqrt(26)
    v = np.array([[0.0, 0, 0], [1, 0, 0], [5, 1, 0]])
    _, _, k = triangle_frames(v, np.array([[0, 1, 2]]))
    assert k[0] == pytest.approx(1.0)


def test_frames_follow_similarity_transforms():
    v, f = random_mesh(50, seed=2)
    rot = Rotation.random(random_state=3).as_matrix()
    t0, r0, k0 = triangle_frames(v, f)
    t1, r1, k1 = triangle_frames(2.5 * v @ rot.T + [0.1, -0.2, 0.3], f)
    np.testing.assert_allclose(t1, 2.5 * t0 @ rot.T + [0.1, -0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(r1, rot @ r0, atol=1e-12)
    np.testing.assert_allclose(k1, 2.5 * k0, rtol=1e-12)


def test_batched_over_leading_axes_equals_per_frame():
    v, f = random_mesh(30, seed=4)
    rng = np.random.default_rng(5)
    batch = v[None, None] + rng.normal(scale=0.01, size=(2, 3) + v.shape)
    t, r, k = triangle_frames(batch, f)
    assert t.shape == (2, 3, 30, 3) and r.shape == (2, 3, 30, 3, 3) and k.shape == (2, 3, 30)
    for i in range(2):
        for j in range(3):
            ti, ri, ki = triangle_frames(batch[i, j], f)
            np.testing.assert_array_equal(t[i, j], ti)
            np.testing.assert_array_equal(r[i, j], ri)
            np.testing.assert_array_equal(k[i, j], ki)


def test_dtype_follows_vertices():
    v, f = random_mesh(5)
    assert triangle_frames(v.astype(np.float32), f)[1].dtype == np.float32
    assert triangle_frames(v, f)[1].dtype == np.float64


def test_degenerate_triangles_are_flagged_and_get_identity():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2], [0, 0, 3], [0, 1, 3]])  # collinear, zero edge, fine
    np.testing.assert_array_equal(degenerate_faces(v, f), [True, True, False])
    _, r, _ = triangle_frames(v, f)
    np.testing.assert_array_equal(r[:2], np.broadcast_to(np.eye(3), (2, 3, 3)))
    assert np.isfinite(r).all()


@pytest.mark.parametrize("vertices, faces, match", [
    (np.zeros((4, 2)), np.array([[0, 1, 2]]), "vertices"),
    (np.zeros((4, 3)), np.array([[0, 1, 4]]), "only 4"),
    (np.zeros((4, 3)), np.array([[0.0, 1, 2]]), "integer"),
    (np.zeros((4, 3)), np.array([0, 1, 2]), r"\(F, 3\)"),
])
def test_bad_input(vertices, faces, match):
    with pytest.raises(InputError, match=match):
        triangle_frames(vertices, faces)


def test_points_on_triangles_lie_inside_and_spread_uniformly():
    from avatarkit.rig.frames import points_on_triangles

    tri = np.repeat(np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]]]), 40000, axis=0)
    p = points_on_triangles(tri, np.random.default_rng(0))
    x, y = p[:, 0], p[:, 1] / 2.0                 # the triangle x, y >= 0, x + y <= 1 after scaling
    assert (x >= 0).all() and (y >= 0).all() and (x + y <= 1 + 1e-12).all() and (p[:, 2] == 0).all()
    np.testing.assert_allclose(p.mean(axis=0), tri[0].mean(axis=0), atol=0.01)   # uniform: the centroid
    # uniform by area: the sub-triangle x + y <= 1/2 holds a quarter of the area
    assert abs((x + y <= 0.5).mean() - 0.25) < 0.01
