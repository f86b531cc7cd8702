"""Deforming Gaussians through a cage: identity, affine, rigid, stretch; fast vs reference; files."""
import numpy as np
import pytest
import trimesh

from avatarkit.cage import Cage, CageDeformer, build_cage, deformation_points, load_weights, save_weights
from avatarkit.cage.deform import principal_rebuild_reference
from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.rotations import axis_angle_to_matrix, quat_to_matrix
from avatarkit.synthetic import make_hair

METHODS = ["principal_axis", "seven_point"]


@pytest.fixture(scope="module")
def hair():
    return make_hair("ponytail", n=1500, seed=4)


@pytest.fixture(scope="module")
def ball_cage(hair):
    """A coarse icosphere around the hair: any closed cage holding the points will do."""
    lo, hi = hair.bounds()
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.6 * np.linalg.norm(hi - lo))
    return Cage(m.vertices + (lo + hi) / 2, m.faces)


@pytest.fixture(scope="module")
def deformers(hair, ball_cage):
    return {m: CageDeformer.build(hair, ball_cage, m) for m in METHODS}


def covariances(quats: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """R diag(s^2) R^T (N, 3, 3) in float64."""
    rot = quat_to_matrix(quats.astype(np.float64))
    return np.einsum("nij,nj,nkj->nik", rot, scales.astype(np.float64) ** 2, rot)


def principal_axes(g: GaussianSet) -> np.ndarray:
    k = np.argmax(g.scales, axis=1)
    return quat_to_matrix(g.quats)[np.arange(len(g)), :, k]


@pytest.mark.parametrize("method", METHODS)
def test_identity_cage_leaves_gaussians_unchanged(deformers, hair, ball_cage, method):
    out = deformers[method].deform(ball_cage.vertices)
    np.testing.assert_allclose(out.means, hair.means, atol=1e-6)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", out.quats, hair.quats)), 1.0, atol=1e-5)
    np.testing.assert_allclose(out.scales, hair.scales, rtol=1e-3)
    np.testing.assert_array_equal(out.opacities, hair.opacities)
    np.testing.assert_array_equal(out.sh, hair.sh)
    np.testing.assert_array_equal(out.extras["strand"], hair.extras["strand"])


@pytest.mark.parametrize("method", METHODS)
def test_affine_cage_gives_affine_centres(deformers, hair, ball_cage, method):
    a = np.array([[1.2, 0.15, 0.0], [-0.1, 0.85, 0.2], [0.05, 0.0, 1.1]])
    t = np.array([0.3, -0.1, 0.2])
    means, quats, scales = deformers[method].deform_arrays(ball_cage.vertices @ a.T + t)
    np.testing.assert_allclose(means, hair.means @ a.T + t, atol=1e-5)
    # the principal axis follows the affine map in both methods
    axis = principal_axes(hair) @ a.T
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    got = principal_axes(hair.replace(means=means, quats=quats, scales=scales))
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", got, axis)), 1.0, atol=1e-4)


def test_seven_point_affine_gives_exact_covariance(deformers, hair, ball_cage):
    a = np.array([[1.2, 0.15, 0.0], [-0.1, 0.85, 0.2], [0.05, 0.0, 1.1]])
    out = deformers["seven_point"].deform(ball_cage.vertices @ a.T)
    expect = a @ hair.covariances() @ a.T
    size = (hair.scales.max(axis=1) ** 2)[:, None, None]
    # float32 weights carry the sub-millimetre minor axes to ~1e-3 of the longest one
    assert (np.abs(out.covariances() - expect) / size).max() < 2e-3


@pytest.mark.parametrize("method", METHODS)
def test_rigid_rotation_rotates_and_keeps_scales(deformers, hair, ball_cage, method):
    r = axis_angle_to_matrix(np.array([0.4, -0.7, 0.25]))
    t = np.array([0.05, 0.1, -0.2])
    out = deformers[method].deform(ball_cage.vertices @ r.T + t)
    np.testing.assert_allclose(out.means, hair.means @ r.T + t, atol=1e-5)
    got, expect = principal_axes(out), principal_axes(hair) @ r.T
    np.testing.assert_allclose(np.einsum("ij,ij->i", got, expect), 1.0, atol=1e-5)  # sign kept too
    k = np.argmax(hair.scales, axis=1)
    np.testing.assert_allclose(out.scales[np.arange(len(hair)), k], hair.scales[np.arange(len(hair)), k],
                               rtol=1e-3)
    size = hair.scales.max(axis=1) ** 2
    error = np.abs(out.covariances() - r @ hair.covariances() @ r.T).max(axis=(1, 2))
    if method == "principal_axis":
        # only the axis is carried: the two thin scales stay as they were, and the roll about the
        # axis is the minimal rotation's, so the thin cross-section may turn (by at most the
        # difference of the two thin variances)
        minor = np.ones_like(hair.scales, bool)
        minor[np.arange(len(hair)), k] = False
        np.testing.assert_array_equal(out.scales[minor], hair.scales[minor])
        spread = np.sort(hair.scales, axis=1)
        assert (error <= 2 * (spread[:, 1] ** 2 - spread[:, 0] ** 2) + 2e-3 * size).all()
    else:
        assert (error / size).max() < 2e-3


def test_stretch_along_the_principal_axis_scales_that_axis(ball_cage):
    # Gaussians whose longest axis is +Y (random roll about it), inside the ball cage
    rng = np.random.default_rng(0)
    n = 300
    centre = ball_cage.vertices.mean(axis=0)
    means = centre + rng.uniform(-0.1, 0.1, (n, 3))
    to_y = axis_angle_to_matrix(np.array([0.0, 0.0, np.pi / 2]))          # local x -> world y
    roll = axis_angle_to_matrix(np.c_[np.zeros(n), rng.uniform(0, 2 * np.pi, n), np.zeros(n)])
    from avatarkit.rotations import matrix_to_quat
    quats = matrix_to_quat(roll @ to_y)
    scales = np.c_[rng.uniform(0.004, 0.008, n), rng.uniform(0.0005, 0.001, (n, 2))]
    g = GaussianSet.from_colors(means, quats, scales, np.ones(n), np.full((n, 3), 0.5))
    stretch = np.diag([1.0, 1.6, 1.0])
    for method in METHODS:
        d = CageDeformer.build(g, ball_cage, method)
        out = d.deform((ball_cage.vertices - centre) @ stretch + centre)
        np.testing.assert_allclose(out.means, (means - centre) @ stretch + centre, atol=1e-5)
        np.testing.assert_allclose(out.scales[:, 0], 1.6 * scales[:, 0], rtol=2e-3)
        np.testing.assert_allclose(out.scales[:, 1:], scales[:, 1:], rtol=5e-3)
        np.testing.assert_allclose(np.abs(principal_axes(out)[:, 1]), 1.0, atol=1e-5)


def test_principal_rebuild_fast_matches_reference(deformers, hair, ball_cage):
    d = deformers["principal_axis"]
    rng = np.random.default_rng(1)
    v = ball_cage.vertices
    bent = v + 0.05 * np.sin(7 * v[:, [1, 2, 0]]) + rng.normal(0, 0.01, v.shape)  # non-affine
    xt = d.deformed_points(bent)
    n = len(hair)
    xt[:, :20], xt[:, n:n + 20] = xt[:, n:n + 20].copy(), xt[:, :20].copy()       # reversed axes
    fast = d._rebuild(xt)
    ref = principal_rebuild_reference(xt, hair, d._pre)
    for a, b in zip(fast, ref):
        np.testing.assert_allclose(a, b, atol=2e-6)
    # swapping the ends of an axis reverses it and keeps its length and centre
    plain = d._rebuild(d.deformed_points(bent))
    axes = [principal_axes(hair.replace(means=m, quats=q, scales=sc))[:20] for m, q, sc in (fast, plain)]
    np.testing.assert_allclose(np.einsum("ij,ij->i", *axes), -1, atol=1e-5)
    np.testing.assert_allclose(fast[2], plain[2], rtol=1e-5)
    np.testing.assert_allclose(fast[0], plain[0], atol=1e-7)


@pytest.mark.parametrize("method", METHODS)
def test_batch_matches_single_frames(deformers, ball_cage, method):
    d = deformers[method]
    rng = np.random.default_rng(2)
    frames = ball_cage.vertices + rng.normal(0, 0.01, (3,) + ball_cage.vertices.shape)
    batch = list(d.deform_batch(frames, chunk=2))  # a full chunk and a partial one
    assert len(batch) == 3
    # The batched product (3t, C) x (C, P) may sum in another order than the single one (it does
    # with one-thread OpenBLAS), so the carried points agree to float32 rounding (~2e-7 m on this
    # 0.5 m cage), not bit for bit. Rebuilt from them: centres and scales to the same 1e-6 m;
    # what the Gaussian *is*, its covariance, to 1e-4 of its largest eigenvalue. A quaternion is
    # compared only where it is well defined: principal_axis turns one axis whose length (>= ~2e-3 m)
    # divides the points' rounding (5e-5). seven_point's eigenvectors of two near-equal scales (this
    # hair has scale pairs 1.0001 apart) are free to turn in their plane, so its quaternions are not.
    stacked = np.ascontiguousarray(frames[:2].astype(np.float32).transpose(0, 2, 1).reshape(6, -1))
    np.testing.assert_allclose(stacked @ d.weights_t, np.concatenate(
        [d.deformed_points(f) for f in frames[:2]]), atol=1e-6)
    for frame, got in zip(frames, batch):
        single = d.deform_arrays(frame)
        np.testing.assert_allclose(got[0], single[0], atol=1e-6)
        np.testing.assert_allclose(got[2], single[2], atol=1e-6)
        cov_got, cov_single = (covariances(q, sc) for _, q, sc in (got, single))
        largest = single[2].astype(np.float64).max(axis=1) ** 2
        assert (np.abs(cov_got - cov_single).max(axis=(1, 2)) <= 1e-4 * largest).all()
        if method == "principal_axis":
            np.testing.assert_allclose(got[1], single[1], atol=5e-5)


def test_weights_layout_matches_deformation_points(deformers, hair, ball_cage):
    d = deformers["principal_axis"]
    pts = deformation_points(hair, "principal_axis")
    assert d.weights.shape == (2 * len(hair), ball_cage.n_vertices)
    np.testing.assert_allclose(d.weights.astype(np.float64) @ ball_cage.vertices, pts, atol=1e-5)
    assert deformers["seven_point"].weights.shape == (7 * len(hair), ball_cage.n_vertices)


def test_real_built_cage_round_trip(tmp_path):
    hair = make_hair("long_straight", n=1200, seed=1)
    cage = build_cage(hair, target_vertices=200)
    d = CageDeformer.build(hair, cage)
    path = tmp_path / "weights.npz"
    save_weights(path, d)
    loaded = load_weights(path)
    assert loaded.method == "principal_axis" and loaded.n_gaussians == 1200
    d2 = loaded.deformer(hair)
    moved = cage.vertices + np.array([0.0, -0.02, 0.01]) * (cage.vertices[:, 1:2] < 0)
    for a, b in zip(d.deform_arrays(moved), d2.deform_arrays(moved)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(InputError, match="different Gaussians"):
        loaded.deformer(hair.replace(means=hair.means + 0.001))
    with pytest.raises(InputError, match="1200 Gaussians"):
        loaded.deformer(hair.subset(np.arange(10)))


def test_weight_file_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_weights(tmp_path / "none.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(FormatError, match="junk.npz"):
        load_weights(junk)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    with pytest.raises(FormatError, match="not a cage weights file"):
        load_weights(other)


def test_bad_deformation_inputs(deformers, hair, ball_cage):
    d = deformers["principal_axis"]
    with pytest.raises(InputError, match="shape"):
        d.deform(ball_cage.vertices[:-1])
    with pytest.raises(InputError, match="non-finite"):
        d.deform(np.full_like(ball_cage.vertices, np.nan))
    with pytest.raises(InputError, match="unknown deformation method"):
        CageDeformer.build(hair, ball_cage, "affine")
    with pytest.raises(InputError, match="weights have shape"):
        CageDeformer(hair, ball_cage, d.weights_t[:, :10])


@pytest.mark.parametrize("method", METHODS)
def test_deferred_weights_are_computed_on_first_use(deformers, hair, ball_cage, method):
    built = deformers[method]
    lazy = CageDeformer.deferred(hair, ball_cage, method)
    assert not lazy.weights_ready and "deferred" in repr(lazy)
    rng = np.random.default_rng(5)
    v = ball_cage.vertices + rng.normal(0, 0.01, ball_cage.vertices.shape)
    for a, b in zip(lazy.deform_arrays(v), built.deform_arrays(v)):  # the first use computes them
        assert np.array_equal(a, b)
    assert lazy.weights_ready and "ready" in repr(lazy)
    assert np.array_equal(lazy.weights_t, built.weights_t)
    with pytest.raises(AttributeError):
        lazy.no_such_thing  # noqa: B018
    calls = []
    again = CageDeformer.deferred(hair, ball_cage, method).ensure_weights(lambda d, t: calls.append((d, t)))
    assert again.weights_ready and calls[-1][0] == calls[-1][1] == again.weights_t.shape[1]
    assert np.array_equal(again.weights_t, built.weights_t)
    assert again.ensure_weights() is again  # nothing left to do
    with pytest.raises(InputError, match="unknown deformation method"):
        CageDeformer.deferred(hair, ball_cage, "affine")
    with pytest.raises(InputError, match="axis_sigma"):
        CageDeformer.deferred(hair, ball_cage, method, axis_sigma=0.0)
