"""GaussianSet: validation, derived sets, transforms (covariances, SH appearance), colours."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.sh import SH_C0, eval_sh
from avatarkit.rotations import quat_to_matrix
from helpers import random_gaussians, random_rotation


def fields(n=4, k=4, seed=0) -> dict:
    g = random_gaussians(n, {1: 0, 4: 1, 9: 2, 16: 3}[k], seed=seed)
    return dict(means=g.means, quats=g.quats, scales=g.scales, opacities=g.opacities, sh=g.sh)


def unit_dirs(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# --- validation -------------------------------------------------------------------------
@pytest.mark.parametrize("name,value,match", [
    ("means", np.zeros((4, 2)), r"means must have shape \(N, 3\)"),
    ("means", np.zeros(12), r"means must have shape"),
    ("means", np.array([["a", "b", "c"]] * 4), "not a numeric array"),
    ("quats", np.zeros((4, 3)), r"quats must have shape \(N, 4\)"),
    ("scales", np.ones((4, 3, 1)), r"scales must have shape \(N, 3\)"),
    ("opacities", np.ones((4, 1)), r"opacities must have shape \(N\)"),
    ("sh", np.zeros((4, 5, 3)), "sh must have shape"),
    ("sh", np.zeros((4, 4, 2)), "sh must have shape"),
    ("quats", np.tile([1.0, 0, 0, 0], (3, 1)), "quats has 3 rows but means has 4"),
    ("scales", np.ones((5, 3)), "scales has 5 rows"),
    ("opacities", np.ones(2), "opacities has 2 rows"),
    ("sh", np.zeros((3, 4, 3)), "sh has 3 rows"),
])
def test_shape_errors(name, value, match):
    f = fields()
    f[name] = value
    with pytest.raises(InputError, match=match):
        GaussianSet(**f)


@pytest.mark.parametrize("name", ["means", "quats", "scales", "opacities", "sh"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_name_field_and_row(name, bad):
    f = {k: np.array(v, copy=True) for k, v in fields().items()}
    f[name].reshape(4, -1)[2, 0] = bad
    with pytest.raises(InputError, match=rf"{name} has a non-finite value \(Gaussian 2\)"):
        GaussianSet(**f)


def test_huge_but_finite_values_are_accepted():
    # the validation sums arrays as a fast finiteness test; an overflowing sum must not count
    f = fields()
    f["means"] = np.full((4, 3), 3e38, np.float32)
    assert np.isfinite(GaussianSet(**f).means).all()


def test_value_range_errors():
    f = fields()
    for scales, ok in [(np.zeros((4, 3)), False), (-np.ones((4, 3)), False), (np.full((4, 3), 1e-30), True)]:
        if ok:
            GaussianSet(**{**f, "scales": scales})
        else:
            with pytest.raises(InputError, match="scales must be > 0"):
                GaussianSet(**{**f, "scales": scales})
    for op in (-0.01, 1.01):
        with pytest.raises(InputError, match=r"opacities must lie in \[0, 1\]"):
            GaussianSet(**{**f, "opacities": np.full(4, op)})
    GaussianSet(**{**f, "opacities": np.array([0.0, 1.0, 0.5, 0.0])})


def test_quaternions_normalised_or_rejected():
    f = fields()
    with pytest.raises(InputError, match="unit length"):
        GaussianSet(**{**f, "quats": f["quats"] * 2})
    with pytest.raises(InputError, match="unit length"):
        GaussianSet(**{**f, "quats": np.zeros((4, 4))})
    near = f["quats"] * (1 + 5e-4)
    g = GaussianSet(**{**f, "quats": near})
    np.testing.assert_allclose(np.linalg.norm(g.quats, axis=1), 1, atol=1e-7)
    np.testing.assert_allclose(g.quats, f["quats"], atol=1e-6)


def test_construction_is_idempotent_bit_for_bit():
    g = random_gaussians(5000, 3, seed=1, extras=("binding",))
    again = GaussianSet(g.means, g.quats, g.scales, g.opacities, g.sh, g.extras)
    for name in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(again, name), getattr(g, name))
    assert g.replace().quats.tobytes() == g.quats.tobytes()


def test_inputs_are_not_modified():
    q = np.tile(np.array([2.0, 0, 0, 0], np.float32) / 2 * (1 + 1e-4), (4, 1))
    before = q.copy()
    GaussianSet(**{**fields(), "quats": q})
    np.testing.assert_array_equal(q, before)


def test_extras_validation():
    f = fields()
    for extras, match in [({"1bad": np.zeros(4)}, "identifier"), ({"a-b": np.zeros(4)}, "identifier"),
                          ({"x": np.zeros(3)}, "first axis must be 4"),
                          ({"x": 5}, "first axis must be 4"), ({"x": np.float32(1)}, "first axis")]:
        with pytest.raises(InputError, match=match):
            GaussianSet(**f, extras=extras)
    one = random_gaussians(1)
    with pytest.raises(InputError, match="first axis"):  # a scalar is not an (N,) array, even for N=1
        one.replace(extras={"x": 5})


def test_dtypes_and_dc_only_sh():
    f = fields(k=1)
    g = GaussianSet(**{**f, "sh": f["sh"][:, 0].astype(np.float64)})  # (N, 3) means DC only
    assert g.sh.shape == (4, 1, 3) and g.sh_degree == 0
    for name in ("means", "quats", "scales", "opacities", "sh"):
        assert getattr(g, name).dtype == np.float32 and getattr(g, name).flags.c_contiguous


def test_empty():
    for d in range(4):
        e = GaussianSet.empty(d)
        assert len(e) == 0 and e.sh_degree == d
    with pytest.raises(InputError, match="empty"):
        GaussianSet.empty().bounds()
    assert len(GaussianSet.concat([GaussianSet.empty(1), random_gaussians(3)])) == 3


# --- subset / concat / SH degree ------------------------------------------------------------
def test_subset_mask_and_indices():
    g = random_gaussians(10, 2, extras=("binding", "feat"))
    mask = np.arange(10) % 3 == 0
    s = g.subset(mask)
    assert len(s) == 4
    np.testing.assert_array_equal(s.means, g.means[mask])
    np.testing.assert_array_equal(s.sh, g.sh[mask])
    np.testing.assert_array_equal(s.extras["feat"], g.extras["feat"][mask])
    t = g.subset([9, 0, 0])
    np.testing.assert_array_equal(t.extras["binding"], g.extras["binding"][[9, 0, 0]])
    np.testing.assert_array_equal(t.quats[1], g.quats[0])
    assert len(g.subset([])) == 0 and g.subset([]).sh_degree == 2
    with pytest.raises(InputError, match="mask has shape"):
        g.subset(np.ones(9, bool))


def test_concat_pads_sh_and_keeps_common_extras():
    a = random_gaussians(3, 1, seed=1, extras=("binding", "feat", "part"))
    b = random_gaussians(4, 3, seed=2, extras=("binding", "part"))
    b = b.replace(extras={**b.extras, "feat": np.zeros((4, 2), np.float32)})  # other trailing shape
    c = GaussianSet.concat([a, b])
    assert len(c) == 7 and c.sh_degree == 3
    np.testing.assert_array_equal(c.sh[:3, :4], a.sh)
    assert (c.sh[:3, 4:] == 0).all()
    np.testing.assert_array_equal(c.sh[3:], b.sh)
    np.testing.assert_array_equal(c.means, np.concatenate([a.means, b.means]))
    assert set(c.extras) == {"binding", "part"}  # feat differs in shape: dropped
    np.testing.assert_array_equal(c.extras["binding"],
                                  np.concatenate([a.extras["binding"], b.extras["binding"]]))
    d = GaussianSet.concat([a, random_gaussians(2, 0)])
    assert d.extras == {} and d.sh_degree == 1
    with pytest.raises(InputError):
        GaussianSet.concat([])


def test_with_sh_degree():
    g = random_gaussians(5, 2)
    up, down = g.with_sh_degree(3), g.with_sh_degree(1)
    assert up.sh_degree == 3 and down.sh_degree == 1
    np.testing.assert_array_equal(up.sh[:, :9], g.sh)
    assert (up.sh[:, 9:] == 0).all()
    np.testing.assert_array_equal(down.sh, g.sh[:, :4])
    with pytest.raises(InputError):
        g.with_sh_degree(4)


# --- colours ------------------------------------------------------------------------------------
def test_colours_and_from_colors():
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 1, (6, 3))
    g = GaussianSet.from_colors(rng.normal(size=(6, 3)), rng.normal(size=(6, 4)),
                                np.full((6, 3), 0.01), np.full(6, 0.5), rgb, sh_degree=2)
    assert g.sh_degree == 2 and (g.sh[:, 1:] == 0).all()
    np.testing.assert_allclose(g.colors, rgb, atol=1e-6)
    np.testing.assert_allclose(g.sh[:, 0], (rgb - 0.5) / SH_C0, rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(g.quats, axis=1), 1, atol=1e-6)
    # the DC colour is what a degree-0 evaluation renders from every direction
    np.testing.assert_allclose(eval_sh(g.with_sh_degree(0).sh, unit_dirs(6)), rgb, atol=1e-6)
    h = g.with_colors(1 - rgb)
    np.testing.assert_allclose(h.colors, 1 - rgb, atol=1e-6)
    np.testing.assert_array_equal(h.sh[:, 1:], g.sh[:, 1:])
    over = g.with_colors(np.full((6, 3), 1.7))
    assert (over.colors == 1).all()  # clamped accessor; the coefficients keep 1.7
    np.testing.assert_allclose(over.sh[:, 0] * SH_C0 + 0.5, 1.7, atol=1e-6)


# --- covariances and transforms ----------------------------------------------------------------
def test_covariances_analytic():
    s = np.array([[1.0, 2.0, 3.0]])
    q_id = np.array([[1.0, 0, 0, 0]])
    g = GaussianSet(np.zeros((1, 3)), q_id, s, [1.0], np.zeros((1, 1, 3)))
    np.testing.assert_allclose(g.covariances()[0], np.diag([1, 4, 9]), atol=1e-12)
    half = np.sqrt(0.5)
    g90 = g.replace(quats=[[half, 0, 0, half]])  # 90 degrees about z: x axis -> y axis
    np.testing.assert_allclose(g90.covariances()[0], np.diag([4, 1, 9]), atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rigid_transform_covariances(seed):
    rng = np.random.default_rng(seed)
    g = random_gaussians(50, 1, seed=seed, extras=("binding",))
    r, t = random_rotation(rng), rng.normal(size=3)
    h = g.transform(r, t)
    np.testing.assert_allclose(h.means, g.means @ r.T + t, atol=1e-5)
    np.testing.assert_allclose(h.covariances(), r @ g.covariances() @ r.T, rtol=1e-4, atol=1e-12)
    np.testing.assert_array_equal(h.scales, g.scales)
    np.testing.assert_array_equal(h.extras["binding"], g.extras["binding"])
    np.testing.assert_allclose(np.linalg.norm(h.quats, axis=1), 1, atol=1e-6)
    np.testing.assert_allclose(quat_to_matrix(h.quats.astype(np.float64)),
                               r @ quat_to_matrix(g.quats.astype(np.float64)), atol=1e-5)


def test_similarity_transform_and_quaternion_input():
    rng = np.random.default_rng(3)
    g = random_gaussians(40, 0)
    r = random_rotation(rng)
    from avatarkit.rotations import matrix_to_quat
    a = g.transform(r, [0.1, 0.2, 0.3], scale=2.5)
    b = g.transform(matrix_to_quat(r), [0.1, 0.2, 0.3], scale=2.5)
    np.testing.assert_allclose(a.means, 2.5 * g.means @ r.T + [0.1, 0.2, 0.3], atol=1e-5)
    np.testing.assert_allclose(a.scales, 2.5 * g.scales, rtol=1e-6)
    np.testing.assert_allclose(a.covariances(), 6.25 * r @ g.covariances() @ r.T, rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(a.means, b.means, atol=1e-6)
    np.testing.assert_allclose(a.covariances(), b.covariances(), rtol=1e-4, atol=1e-12)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_transform_rotates_sh_appearance(degree):
    """A splat seen along d after the rotation looks as the original did along R^T d."""
    rng = np.random.default_rng(degree)
    g = random_gaussians(30, degree, seed=degree)
    r = random_rotation(rng)
    h = g.transform(r)
    d = unit_dirs(30, seed=degree)
    np.testing.assert_allclose(eval_sh(h.sh.astype(np.float64), d),
                               eval_sh(g.sh.astype(np.float64), d @ r), atol=2e-5)
    # without the SH rotation the appearance would be wrong (so the test can fail)
    frozen = g.transform(r, rotate_sh_coeffs=False)
    np.testing.assert_array_equal(frozen.sh, g.sh)
    assert np.abs(eval_sh(frozen.sh, d) - eval_sh(g.sh, d @ r)).max() > 1e-2


def test_transform_identity_and_errors():
    g = random_gaussians(10, 2)
    same = g.transform()
    np.testing.assert_allclose(same.means, g.means, atol=1e-7)
    np.testing.assert_allclose(same.sh, g.sh, atol=1e-6)
    for kw, match in [(dict(rotation=np.diag([1.0, 1.0, -1.0])), "proper"),
                      (dict(rotation=np.ones((3, 3))), "proper"),
                      (dict(rotation=np.eye(2)), "proper"),
                      (dict(translation=[1, 2]), "translation"),
                      (dict(translation=[np.nan, 0, 0]), "translation"),
                      (dict(scale=0.0), "scale"), (dict(scale=-1.0), "scale"),
                      (dict(scale=np.inf), "scale")]:
        with pytest.raises(InputError, match=match):
            g.transform(**kw)


def test_repr_and_bounds():
    g = random_gaussians(7, 1, extras=("feat",))
    assert "n=7" in repr(g) and "sh_degree=1" in repr(g) and "feat(4,)" in repr(g)
    lo, hi = g.bounds()
    np.testing.assert_array_equal(lo, g.means.min(0))
    np.testing.assert_array_equal(hi, g.means.max(0))


def test_from_checked_takes_arrays_as_given_but_checks_extras():
    gs = random_gaussians(5, 1, seed=2)
    same = GaussianSet.from_checked(gs.means, gs.quats, gs.scales, gs.opacities, gs.sh,
                                    {"binding": np.arange(5)})
    assert same.means is gs.means and same.sh is gs.sh  # no copy, no second pass
    assert same.extras["binding"].tolist() == [0, 1, 2, 3, 4]
    with pytest.raises(InputError, match="first axis must be 5"):
        GaussianSet.from_checked(gs.means, gs.quats, gs.scales, gs.opacities, gs.sh,
                                 {"binding": np.arange(4)})


def _replace_case(n=64, seed=0):
    import numpy as np

    from avatarkit.gaussians.gaussian_set import GaussianSet

    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return GaussianSet(rng.normal(size=(n, 3)), q / np.linalg.norm(q, axis=1, keepdims=True),
                       rng.uniform(0.01, 0.1, (n, 3)), rng.uniform(0, 1, n), rng.normal(size=(n, 4, 3)),
                       {"binding": np.arange(n)}), rng


def test_replace_checks_what_it_replaces_and_gives_the_constructors_set():
    """`replace` (only the replaced fields checked) gives `replace_reference`'s set (the
    constructor's, every field checked) bit for bit: float64 inputs made float32, quats a
    little off unit renormalised, DC-only sh, other extras; and raises the same errors for
    bad replacements (a row count, a NaN, a scale of 0, an opacity above 1, a long quat)."""
    import numpy as np
    import pytest

    from avatarkit.errors import InputError

    gs, rng = _replace_case()
    n = len(gs)
    q = gs.quats.astype(np.float64) * (1 + 1e-5 * rng.normal(size=(n, 1)))
    cases = [dict(means=rng.normal(size=(n, 3))), dict(quats=q), dict(scales=gs.scales * 2),
             dict(opacities=rng.uniform(0, 1, n).astype(np.float64)), dict(sh=rng.normal(size=(n, 3))),
             dict(extras={}), dict(extras={"w": rng.normal(size=n)}),
             dict(means=gs.means[:10], quats=gs.quats[:10], scales=gs.scales[:10], opacities=gs.opacities[:10],
                  sh=gs.sh[:10], extras={}), {}]
    for change in cases:
        a, b = gs.replace(**change), gs.replace_reference(**change)
        assert type(a) is type(b) and set(a.extras) == set(b.extras)
        for k in ("means", "quats", "scales", "opacities", "sh"):
            x, y = getattr(a, k), getattr(b, k)
            assert x.dtype == y.dtype == np.float32 and x.flags.c_contiguous and np.array_equal(x, y), k
        for k in a.extras:
            assert np.array_equal(a.extras[k], b.extras[k])
    assert not np.array_equal(gs.replace(quats=q).quats, q.astype(np.float32))   # renormalised
    bad_q = gs.quats.copy()
    bad_q[3] *= 1.1
    nan = gs.means.copy()
    nan[5, 1] = np.nan
    for change in (dict(means=gs.means[:10]), dict(means=nan), dict(scales=gs.scales * 0),
                   dict(opacities=gs.opacities + 1.5), dict(quats=bad_q), dict(sh=np.zeros((n, 2, 3))),
                   dict(extras={"w": np.zeros(n + 1)})):
        with pytest.raises(InputError) as e1:
            gs.replace(**change)
        with pytest.raises(InputError) as e2:
            gs.replace_reference(**change)
        assert str(e1.value) == str(e2.value)
    with pytest.raises(TypeError):
        gs.replace(colour=1)
