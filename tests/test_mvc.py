"""Mean value coordinates: invariants on non-convex cages, robust cases, fast vs reference."""
import numpy as np
import pytest
import trimesh

from avatarkit.cage import (mvc_weights, mvc_weights_reference, sparse_apply, sparse_error, sparsify,
                            winding_numbers, winding_numbers_reference)
from avatarkit.errors import InputError


def bumpy_sphere(seed: int, subdivisions: int = 2, amplitude: float = 0.35):
    """A star-shaped, non-convex closed mesh: an icosphere with smooth random radial bumps."""
    rng = np.random.default_rng(seed)
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = m.vertices
    k = rng.normal(size=(3, 3)) * 2.5
    phase = rng.uniform(0, 2 * np.pi, 3)
    bump = sum(np.sin(d @ k[i] + phase[i]) for i in range(3)) / 3
    v = d * (1 + amplitude * bump)[:, None] * np.array([1.0, 0.8, 1.2])
    return v, np.asarray(m.faces)


def l_prism():
    """An L-shaped prism (not convex, not star-shaped about its centroid), 12 vertices."""
    outline = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)
    v = np.concatenate([np.c_[outline, np.zeros(6)], np.c_[outline, np.ones(6)]])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]       # fan from the reflex corner
    bottom = [(a, c, b) for a, b, c in fan]                    # facing -z
    top = [(a + 6, b + 6, c + 6) for a, b, c in fan]           # facing +z
    sides = []
    for i in range(6):
        j = (i + 1) % 6
        sides += [(i, j, j + 6), (i, j + 6, i + 6)]
    f = np.array(bottom + top + sides)
    assert trimesh.Trimesh(v, f).is_volume
    return v, f


def inside_points(v, f, n, seed):
    rng = np.random.default_rng(seed)
    lo, hi = v.min(0), v.max(0)
    cand = rng.uniform(lo, hi, (n * 6, 3))
    keep = winding_numbers_reference(cand, v, f) > 0.5
    pts = cand[keep][:n]
    assert len(pts) == n
    return pts


CAGES = {"bumpy0": bumpy_sphere(0), "bumpy1": bumpy_sphere(1, amplitude=0.45), "L": l_prism()}


@pytest.mark.parametrize("name", sorted(CAGES))
def test_invariants_inside_non_convex_cages(name):
    v, f = CAGES[name]
    pts = inside_points(v, f, 300, seed=5)
    w = mvc_weights(pts, v, f)
    assert w.dtype == np.float32 and w.shape == (300, len(v))
    assert np.isfinite(w).all()
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(w.astype(np.float64) @ v, pts, atol=1e-5)  # linear precision


@pytest.mark.parametrize("name", sorted(CAGES))
def test_fast_matches_reference(name):
    v, f = CAGES[name]
    pts = inside_points(v, f, 120, seed=11)
    ref = mvc_weights_reference(pts, v, f)
    np.testing.assert_allclose(ref.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(ref @ v, pts, atol=1e-10)
    np.testing.assert_allclose(mvc_weights(pts, v, f), ref, atol=2e-6)


def test_non_convex_cage_has_negative_weights_somewhere():
    v, f = CAGES["bumpy1"]
    w = mvc_weights(inside_points(v, f, 400, seed=2), v, f)
    assert (w < -1e-4).any()  # MVC are not positive on non-convex cages, yet still exact above


@pytest.mark.parametrize("fn", [mvc_weights, mvc_weights_reference])
def test_points_on_vertices_edges_and_faces(fn):
    v, f = CAGES["bumpy0"]
    rng = np.random.default_rng(4)
    tri = f[rng.choice(len(f), 20, replace=False)]
    bary = rng.dirichlet(np.ones(3), 20)
    on_face = np.einsum("pk,pkc->pc", bary, v[tri])
    t = rng.uniform(0.05, 0.95, 20)
    on_edge = (1 - t)[:, None] * v[tri[:, 0]] + t[:, None] * v[tri[:, 1]]
    on_vertex = v[tri[:, 2]]
    for pts in (on_face, on_edge, on_vertex):
        w = np.asarray(fn(pts, v, f), np.float64)
        assert np.isfinite(w).all()
        np.testing.assert_allclose(w @ v, pts, atol=1e-6)
    w_face = np.asarray(fn(on_face, v, f), np.float64)
    expect = np.zeros_like(w_face)
    np.put_along_axis(expect, tri, bary, axis=1)
    np.testing.assert_allclose(w_face, expect, atol=1e-6)     # planar barycentric case
    w_edge = np.asarray(fn(on_edge, v, f), np.float64)
    expect = np.zeros_like(w_edge)
    np.put_along_axis(expect, tri[:, :2], np.stack([1 - t, t], 1), axis=1)
    np.testing.assert_allclose(w_edge, expect, atol=1e-6)     # linear along the edge
    w_vertex = np.asarray(fn(on_vertex, v, f), np.float64)
    np.testing.assert_allclose(w_vertex, np.eye(len(v))[tri[:, 2]], atol=1e-7)


def test_points_very_near_a_face_stay_exact():
    v, f = CAGES["bumpy0"]
    tri = v[f[17]]
    centre = tri.mean(0)
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    n /= np.linalg.norm(n)
    pts = centre - np.outer([1e-13, 1e-10, 1e-7, 1e-4, 1e-2], n)  # from just inside
    w = mvc_weights(pts, v, f).astype(np.float64)
    assert np.isfinite(w).all()
    np.testing.assert_allclose(w @ v, pts, atol=1e-6)


def test_outside_points_keep_linear_precision():
    v, f = CAGES["L"]
    pts = np.random.default_rng(0).uniform(-1.5, 3.5, (200, 3))
    outside = winding_numbers_reference(pts, v, f) < 0.5
    w = mvc_weights(pts[outside], v, f).astype(np.float64)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(w @ v, pts[outside], atol=1e-5)


def test_transposed_layout_and_progress():
    v, f = CAGES["bumpy0"]
    pts = inside_points(v, f, 50, seed=1)
    calls = []
    wt = mvc_weights(pts, v, f, transposed=True, progress=lambda done, total: calls.append((done, total)))
    assert wt.flags.c_contiguous and wt.shape == (len(v), 50)
    np.testing.assert_array_equal(wt.T, mvc_weights(pts, v, f))
    assert calls[-1] == (50, 50)


def test_affine_cage_motion_moves_points_affinely():
    v, f = CAGES["bumpy1"]
    pts = inside_points(v, f, 200, seed=9)
    w = mvc_weights(pts, v, f).astype(np.float64)
    a = np.array([[1.3, 0.2, 0.0], [-0.1, 0.7, 0.3], [0.0, 0.4, 1.1]])
    t = np.array([0.5, -2.0, 1.0])
    np.testing.assert_allclose(w @ (v @ a.T + t), pts @ a.T + t, atol=2e-5)


def test_sparse_top_k():
    v, f = CAGES["bumpy0"]
    pts = inside_points(v, f, 200, seed=3)
    w = mvc_weights(pts, v, f)
    idx, sw = sparsify(w, len(v))
    np.testing.assert_allclose(sparse_apply(idx, sw, v), pts, atol=1e-5)
    errors = []
    for k in (4, 16, 64):
        idx, sw = sparsify(w, k)
        assert idx.shape == (200, k) and sw.dtype == np.float32
        np.testing.assert_allclose(sw.sum(axis=1), 1.0, atol=1e-5)
        e = sparse_error(idx, sw, v, pts)
        assert e.k == k and e.max_error >= e.mean_error > 0
        errors.append(e.mean_error)
    assert errors[0] > errors[1] > errors[2]
    with pytest.raises(InputError):
        sparsify(w, 0)


def test_sparse_top_k_with_linear_precision():
    v, f = CAGES["bumpy1"]
    pts = inside_points(v, f, 200, seed=8)
    w = mvc_weights(pts, v, f)
    idx, sw = sparsify(w, 16, points=pts, cage_vertices=v)
    np.testing.assert_allclose(sw.sum(axis=1), 1.0, atol=1e-5)
    assert sparse_error(idx, sw, v, pts).max_error < 1e-5          # exact on the rest cage
    a = np.array([[1.1, 0.3, 0.0], [0.0, 0.9, -0.2], [0.1, 0.0, 1.2]])
    np.testing.assert_allclose(sparse_apply(idx, sw, v @ a.T), pts @ a.T, atol=2e-5)  # and affine
    bend = v + 0.2 * np.sin(2 * v[:, [2, 0, 1]])
    plain = sparsify(w, 16)
    dense = w.astype(np.float64) @ bend
    assert sparse_error(idx, sw, bend, dense).mean_error < sparse_error(*plain, bend, dense).mean_error
    with pytest.raises(InputError):
        sparsify(w, 16, points=pts)


def test_winding_numbers_fast_vs_reference():
    v, f = CAGES["L"]
    pts = np.random.default_rng(0).uniform(-0.5, 2.5, (300, 3))
    ref = winding_numbers_reference(pts, v, f)
    np.testing.assert_allclose(winding_numbers(pts, v, f), ref, atol=1e-9)
    inside = (pts[:, 2] > 0) & (pts[:, 2] < 1) & (pts[:, 0] > 0) & (pts[:, 1] > 0) & (
        ((pts[:, 0] < 2) & (pts[:, 1] < 1)) | ((pts[:, 0] < 1) & (pts[:, 1] < 2)))
    np.testing.assert_allclose(ref, inside.astype(float), atol=1e-6)


def test_bad_inputs():
    v, f = CAGES["L"]
    with pytest.raises(InputError, match="points"):
        mvc_weights(np.zeros((3, 2)), v, f)
    with pytest.raises(InputError, match="index"):
        mvc_weights(np.zeros((3, 3)), v, f + 100)
    with pytest.raises(InputError, match="finite"):
        mvc_weights(np.full((1, 3), np.nan), v, f)
    with pytest.raises(InputError):
        mvc_weights(np.zeros((1, 3)), v, f.astype(float))
    assert mvc_weights(np.zeros((0, 3)), v, f).shape == (0, len(v))


def test_kernel_atan2_matches_numpy():
    from avatarkit.cage import _kernels

    rng = np.random.default_rng(0)
    ang = np.concatenate([rng.uniform(0, np.pi / 2, 20000),
                          [0.0, np.pi / 2, 3 * np.pi / 8, np.arctan(0.66), 1e-12, np.pi / 2 - 1e-12]])
    r = rng.uniform(0.1, 3.0, len(ang))
    y, x = r * np.sin(ang), r * np.cos(ang)
    y, x = np.append(y, [2.0, 0.0]), np.append(x, [0.0, 2.0])    # the exact axes
    out = np.empty_like(x)
    _kernels.atan2_pos(y, x, out)
    np.testing.assert_allclose(out, np.arctan2(y, x), rtol=1e-15, atol=1e-16)
