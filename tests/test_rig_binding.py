"""TriangleBinding: exact round trips, rigid/similarity motion, nearest-face binding, errors."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from avatarkit.errors import InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.sh import rotate_sh
from avatarkit.rig import (PosedGaussians, TriangleBinding, local_to_world, nearest_faces,
                           point_triangle_distance, triangle_frames, world_to_local)
from avatarkit.rig.sh_rotation import rotate_sh_indexed


# --- fixtures ----------------------------------------------------------------------------------
def bumpy_sphere(subdivisions=3, seed=0):
    """An irregular closed mesh of head size: icosphere radius 0.1 m with jittered vertices."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.1)
    rng = np.random.default_rng(seed)
    v = m.vertices * (1 + 0.05 * rng.uniform(-1, 1, (len(m.vertices), 1)))
    return v, np.asarray(m.faces)


def gaussians_near(vertices, n=400, sh_degree=3, seed=1, spread=0.004, extras=None):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    means = d * 0.1 + rng.normal(scale=spread, size=(n, 3))
    q = rng.normal(size=(n, 4))
    sh = rng.normal(scale=0.3, size=(n, (sh_degree + 1) ** 2, 3))
    return GaussianSet(means, q / np.linalg.norm(q, axis=1, keepdims=True),
                       np.exp(rng.normal(-6, 0.5, (n, 3))), rng.uniform(0, 1, n), sh, extras or {})


def assert_same_orientation(qa, qb, atol=1e-6):
    """Quaternions equal up to sign."""
    d = np.abs(np.sum(np.asarray(qa, np.float64) * np.asarray(qb, np.float64), axis=-1))
    np.testing.assert_allclose(d, 1.0, atol=atol)


def assert_same_gaussians(a: GaussianSet, b: GaussianSet, atol=1e-6, sh_atol=1e-5):
    np.testing.assert_allclose(a.means, b.means, atol=atol)
    assert_same_orientation(a.quats, b.quats, atol)
    np.testing.assert_allclose(a.scales, b.scales, rtol=atol)
    np.testing.assert_array_equal(a.opacities, b.opacities)
    np.testing.assert_allclose(a.sh, b.sh, atol=sh_atol)


def reference_to_world(binding: TriangleBinding, vertices):
    """Slow and obvious: one Gaussian at a time, frames and quaternion maths via scipy."""
    means, quats, scales = [], [], []
    for i in range(len(binding)):
        a, b, c = vertices[binding.faces[binding.face_ids[i]]]
        e0 = (b - a) / np.linalg.norm(b - a)
        n = np.cross(e0, c - a)
        n /= np.linalg.norm(n)
        r = np.stack([e0, n, np.cross(e0, n)], axis=1)
        k = (np.linalg.norm(b - a) + abs(np.dot(np.cross(e0, n), c - a))) / 2
        means.append(k * r @ binding.local_means[i] + (a + b + c) / 3)
        w, x, y, z = binding.local_quats[i]
        xyzw = (Rotation.from_matrix(r) * Rotation.from_quat([x, y, z, w])).as_quat()
        quats.append(np.roll(xyzw, 1))
        scales.append(k * binding.local_scales[i])
    return np.array(means), np.array(quats), np.array(scales)


# --- round trips -------------------------------------------------------------------------------
def test_bind_then_to_world_gives_back_the_gaussians():
    v, f = bumpy_sphere()
    g = gaussians_near(v, extras={"part": np.arange(400) % 3})
    b = TriangleBinding.bind(g, v, f)
    w = b.to_world(v)
    assert_same_gaussians(w, g)
    np.testing.assert_array_equal(w.extras["part"], g.extras["part"])
    assert w.extras["binding"].dtype == np.int32
    np.testing.assert_array_equal(w.extras["binding"], b.face_ids)


def test_to_local_of_to_world_is_the_binding():
    v, f = bumpy_sphere()
    b = TriangleBinding.bind(gaussians_near(v), v, f)
    v2 = v + np.random.default_rng(3).normal(scale=0.002, size=v.shape)  # a non-rigid pose
    b2 = b.to_local(b.to_world(v2), v2)
    np.testing.assert_allclose(b2.local_means, b.local_means, atol=1e-5)  # local units (~k)
    assert_same_orientation(b2.local_quats, b.local_quats)
    np.testing.assert_allclose(b2.local_scales, b.local_scales, rtol=1e-6)
    np.testing.assert_allclose(b2.local.sh, b.local.sh, atol=1e-5)


def test_array_functions_are_inverses():
    v, f = bumpy_sphere(2)
    rng = np.random.default_rng(4)
    ids = rng.integers(0, len(f), 100)
    q = rng.normal(size=(100, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    lm, lq, ls = rng.normal(size=(100, 3)), q, rng.uniform(0.1, 2, (100, 3))
    t, r, k = triangle_frames(v, f)
    m, wq, s = local_to_world(t, r, k, ids, lm, lq, ls)
    lm2, lq2, ls2 = world_to_local(t, r, k, ids, m, wq, s)
    np.testing.assert_allclose(lm2, lm, atol=1e-12)
    np.testing.assert_allclose(lq2, lq, atol=1e-12)
    np.testing.assert_allclose(ls2, ls, rtol=1e-12)


# --- against the slow reference ----------------------------------------------------------------
def test_fast_to_world_matches_per_gaussian_reference_on_a_deformed_mesh():
    v, f = bumpy_sphere(2)
    b = TriangleBinding.bind(gaussians_near(v, 150, sh_degree=0), v, f)
    rng = np.random.default_rng(6)
    posed = v * [1.1, 0.9, 1.0] + rng.normal(scale=0.003, size=v.shape)
    w = b.to_world(posed)
    m, q, s = reference_to_world(b, posed.astype(np.float64))
    np.testing.assert_allclose(w.means, m, atol=1e-6)
    assert_same_orientation(w.quats, q)
    np.testing.assert_allclose(w.scales, s, rtol=1e-6)


# --- motion of the mesh ------------------------------------------------------------------------
def test_rigidly_moved_mesh_moves_gaussians_rigidly():
    v, f = bumpy_sphere()
    g = gaussians_near(v)
    b = TriangleBinding.bind(g, v, f)
    rot = Rotation.random(random_state=7).as_matrix()
    t = np.array([0.05, -0.3, 1.2])
    w = b.to_world(v @ rot.T + t)
    assert_same_gaussians(w, g.transform(rot, t), atol=2e-6)  # SH bands turned with the head


def test_uniformly_scaled_mesh_scales_gaussians():
    v, f = bumpy_sphere()
    g = gaussians_near(v)
    b = TriangleBinding.bind(g, v, f)
    w = b.to_world(1.7 * v + [0.0, 0.1, 0.0])
    np.testing.assert_allclose(w.means, 1.7 * g.means + [0.0, 0.1, 0.0], atol=1e-6)
    np.testing.assert_allclose(w.scales, 1.7 * g.scales, rtol=1e-6)
    assert_same_orientation(w.quats, g.quats)


def test_world_sh_frame_leaves_colour_fixed():
    v, f = bumpy_sphere(2)
    g = gaussians_near(v, 100)
    b = TriangleBinding.bind(g, v, f, rotate_sh=False)
    assert b.sh_frame == "world"
    rot = Rotation.from_euler("y", 70, degrees=True).as_matrix()
    np.testing.assert_array_equal(b.to_world(v @ rot.T).sh, g.sh)


def test_batched_to_world_equals_per_frame():
    v, f = bumpy_sphere(2)
    b = TriangleBinding.bind(gaussians_near(v, 200, sh_degree=1), v, f)
    rng = np.random.default_rng(8)
    frames = v[None] + rng.normal(scale=0.002, size=(4,) + v.shape)
    posed = b.to_world(frames)
    assert isinstance(posed, PosedGaussians) and len(posed) == 4
    assert posed.means.shape == (4, 200, 3) and posed.quats.shape == (4, 200, 4)
    for t in range(4):
        single = b.to_world(frames[t])
        np.testing.assert_allclose(posed.means[t], single.means, atol=1e-7)
        np.testing.assert_allclose(posed.quats[t], single.quats, atol=1e-7)
        np.testing.assert_allclose(posed.scales[t], single.scales, rtol=1e-6)
        assert_same_gaussians(posed.frame(t), single, atol=1e-7, sh_atol=1e-7)


# --- nearest-face binding ----------------------------------------------------------------------
def brute_force_distances(points, vertices, faces):
    """(N, F) exact point-triangle distances, every pair."""
    n, nf = len(points), len(faces)
    d = point_triangle_distance(np.repeat(points, nf, axis=0), np.tile(vertices[faces], (n, 1, 1)))
    return d.reshape(n, nf)


@pytest.mark.parametrize("spread", [0.002, 0.05])  # near the surface; far (exhaustive fallback)
def test_nearest_faces_match_brute_force(spread):
    v, f = bumpy_sphere(3)
    pts = gaussians_near(v, 300, sh_degree=0, seed=9, spread=spread).means
    ids, dist = nearest_faces(pts, v, f, candidates=4)
    ref = brute_force_distances(pts.astype(np.float64), v, f)
    np.testing.assert_allclose(dist, ref.min(axis=1), atol=1e-12)
    np.testing.assert_allclose(ref[np.arange(len(pts)), ids], ref.min(axis=1), atol=1e-12)


def test_nearest_faces_with_very_uneven_triangles():
    # a big triangle beside a fan of small ones: centroid distance alone would pick wrongly
    rng = np.random.default_rng(10)
    small = rng.uniform(0, 0.01, (60, 3, 3)) + [0.5, 0, 0]
    big = np.array([[[-1.0, -1, 0], [1, -1, 0], [0, 1, 0]]])
    tris = np.concatenate([big, small])
    v, f = tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3)
    pts = rng.uniform(-1, 1, (200, 3)) * [1, 1, 0.2]
    ids, dist = nearest_faces(pts, v, f, candidates=2)
    ref = brute_force_distances(pts, v, f)
    np.testing.assert_allclose(dist, ref.min(axis=1), atol=1e-12)


def _pruning_cases():
    rng = np.random.default_rng(11)
    v, f = bumpy_sphere(3)
    # a few big triangles among small ones: the size classes each get their own search radius
    coarse, cf = bumpy_sphere(1, seed=3)
    v2 = np.concatenate([v, coarse * 1.02])
    f2 = np.concatenate([f, cf + len(v)])
    near = gaussians_near(v, 400, sh_degree=0, seed=12, spread=0.003).means
    far = gaussians_near(v, 300, sh_degree=0, seed=13, spread=0.04).means   # hair over a scalp
    on_vertices = v[rng.integers(0, len(v), 200)]                            # exact ties
    degenerate = np.zeros(len(f), bool)
    degenerate[::7] = True
    return [(near, v, f, {}, 4), (far, v, f, {}, 8), (on_vertices, v, f, {}, 8),
            (near, v, f, {"exclude": degenerate}, 32), (np.concatenate([near, far]), v2, f2, {}, 8)]


@pytest.mark.parametrize("case", range(5))
def test_nearest_faces_pruned_search_is_the_reference_bit_for_bit(case):
    points, v, f, kw, k = _pruning_cases()[case]
    ids, dist = nearest_faces(points, v, f, candidates=k, **kw)
    ref_ids, ref_dist = nearest_faces(points, v, f, candidates=k, prune=False, **kw)
    np.testing.assert_array_equal(ids, ref_ids)
    np.testing.assert_array_equal(dist, ref_dist)
    brute = brute_force_distances(points.astype(np.float64), v, f)
    if "exclude" in kw:
        brute[:, kw["exclude"]] = np.inf
    np.testing.assert_allclose(dist, brute.min(axis=1), atol=1e-12)


def test_bind_uses_given_face_ids_and_skips_degenerate_faces():
    v, f = bumpy_sphere(2)
    g = gaussians_near(v, 50, sh_degree=0)
    ids = np.arange(50) * 3
    b = TriangleBinding.bind(g, v, f, face_ids=ids)
    np.testing.assert_array_equal(b.face_ids, ids)
    assert_same_gaussians(b.to_world(v), g)
    # collapse triangle 0 onto a point: nearest binding must avoid it
    v2 = v.copy()
    v2[f[0]] = v2[f[0]].mean(axis=0)
    b2 = TriangleBinding.bind(g, v2, f)
    assert 0 not in b2.face_ids


def test_from_local_reads_the_binding_extra():
    v, f = bumpy_sphere(2)
    b = TriangleBinding.bind(gaussians_near(v, 60, sh_degree=0), v, f)
    ga = TriangleBinding.from_local(b.local_gaussians(), f)  # GaussianAvatars' PLY layout
    np.testing.assert_array_equal(ga.face_ids, b.face_ids)
    assert "binding" not in ga.local.extras
    assert_same_gaussians(ga.to_world(v), b.to_world(v))


def test_subset_keeps_matching_face_ids():
    v, f = bumpy_sphere(2)
    b = TriangleBinding.bind(gaussians_near(v, 60, sh_degree=0), v, f)
    s = b.subset(np.arange(60) % 2 == 0)
    assert len(s) == 30
    assert_same_gaussians(s.to_world(v), b.to_world(v).subset(np.arange(0, 60, 2)))


def test_per_face_sh_rotation_matches_single_rotation_reference():
    rng = np.random.default_rng(11)
    rots = Rotation.random(20, random_state=12).as_matrix()
    sh = rng.normal(size=(100, 16, 3)).astype(np.float32)
    idx = rng.integers(0, 20, 100)
    out = rotate_sh_indexed(sh, rots, idx)
    for i in range(0, 100, 7):
        np.testing.assert_allclose(out[i], rotate_sh(sh[i:i + 1], rots[idx[i]])[0], atol=1e-5)


# --- errors ------------------------------------------------------------------------------------
def test_errors_are_clear():
    v, f = bumpy_sphere(1)
    g = gaussians_near(v, 10, sh_degree=0)
    with pytest.raises(InputError, match="face_ids must lie"):
        TriangleBinding.bind(g, v, f, face_ids=np.full(10, len(f)))
    with pytest.raises(InputError, match=r"shape \(10,\)"):
        TriangleBinding.bind(g, v, f, face_ids=np.zeros(3, int))
    with pytest.raises(InputError, match="one mesh pose"):
        TriangleBinding.bind(g, v[None], f)
    v_nan = v.copy()
    v_nan[0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        TriangleBinding.bind(g, v_nan, f)
    flat = v.copy()
    flat[f[0]] = 0.0
    with pytest.raises(InputError, match="triangle 0 is degenerate"):
        TriangleBinding.bind(g, flat, f, face_ids=np.zeros(10, int))

    b = TriangleBinding.bind(g, v, f, face_ids=np.zeros(10, int))
    frames = np.stack([v, v, flat])
    with pytest.raises(InputError, match="triangle 0 collapsed in frame 2"):
        b.to_world(frames)
    with pytest.raises(InputError, match=r"\(V, 3\) or \(T, V, 3\)"):
        b.to_world(v[None, None])
    with pytest.raises(InputError, match="only"):
        b.to_world(v[:5])
    with pytest.raises(InputError, match="5 Gaussians given"):
        b.to_local(g.subset(np.arange(5)), v)


def test_empty_set_binds_and_poses():
    v, f = bumpy_sphere(1)
    b = TriangleBinding.bind(GaussianSet.empty(1), v, f)
    assert len(b) == 0 and len(b.to_world(v)) == 0
    assert b.to_world(np.stack([v, v])).means.shape == (2, 0, 3)
