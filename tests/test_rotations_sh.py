"""rotations.py against scipy's Rotation; sh.py against the spherical harmonics themselves."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.special import sph_harm_y

from avatarkit.gaussians.sh import (SH_C0, SH_COUNTS, degree_from_count, dc_to_rgb, eval_sh,
                                    rgb_to_dc, rotate_sh, sh_basis, sh_rotation)
from avatarkit.rotations import (axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_quat,
                                 quat_multiply, quat_normalize, quat_to_matrix)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_quats(n, seed=0):
    return unit(np.random.default_rng(seed).normal(size=(n, 4)))


def same_rotation_quats(a, b, atol=1e-9):
    """q and -q are the same rotation."""
    dots = np.abs(np.sum(a * b, axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=atol)


def half_turns() -> np.ndarray:
    """180-degree rotations about the axes, diagonals and random axes (w = 0: the hard case)."""
    axes = np.concatenate([np.eye(3), unit([[1, 1, 0], [1, -1, 0], [0, 1, 1], [1, 1, 1], [-1, 2, 3]]),
                           unit(np.random.default_rng(5).normal(size=(20, 3)))])
    return axes * np.pi


# --- rotations --------------------------------------------------------------------------
def test_quat_to_matrix_matches_scipy():
    q = random_quats(500)
    want = Rotation.from_quat(q, scalar_first=True).as_matrix()
    np.testing.assert_allclose(quat_to_matrix(q), want, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(3.0 * q), want, atol=1e-12)  # normalised inside


def test_matrix_to_quat_matches_scipy_and_is_canonical():
    m = Rotation.random(500, random_state=1).as_matrix()
    q = matrix_to_quat(m)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    same_rotation_quats(q, Rotation.from_matrix(m).as_quat(scalar_first=True))
    np.testing.assert_allclose(quat_to_matrix(q), m, atol=1e-12)


@pytest.mark.parametrize("eps", [0.0, 1e-7, 1e-4])
def test_half_turn_round_trips(eps):
    rv = half_turns() * (1 - eps)
    m = Rotation.from_rotvec(rv).as_matrix()
    q = matrix_to_quat(m)
    np.testing.assert_allclose(quat_to_matrix(q), m, atol=1e-9)
    same_rotation_quats(q, Rotation.from_rotvec(rv).as_quat(scalar_first=True))
    aa = matrix_to_axis_angle(m)
    np.testing.assert_allclose(axis_angle_to_matrix(aa), m, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(aa, axis=1), np.pi * (1 - eps), atol=1e-9)


def test_identity_and_tiny_rotations():
    np.testing.assert_allclose(matrix_to_quat(np.eye(3)), [1, 0, 0, 0], atol=1e-15)
    np.testing.assert_array_equal(axis_angle_to_matrix(np.zeros(3)), np.eye(3))
    tiny = np.array([[1e-10, -2e-10, 3e-10], [1e-6, 0, 0], [0, 0, 1e-9]])
    np.testing.assert_allclose(axis_angle_to_matrix(tiny), Rotation.from_rotvec(tiny).as_matrix(),
                               atol=1e-15)
    np.testing.assert_allclose(matrix_to_axis_angle(axis_angle_to_matrix(tiny)), tiny, atol=1e-14)


def test_rodrigues_matches_scipy():
    rng = np.random.default_rng(2)
    aa = unit(rng.normal(size=(300, 3))) * rng.uniform(0, np.pi, (300, 1))
    np.testing.assert_allclose(axis_angle_to_matrix(aa), Rotation.from_rotvec(aa).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(matrix_to_axis_angle(axis_angle_to_matrix(aa)), aa, atol=1e-9)
    big = aa * 3  # angles beyond pi come back as the equivalent angle in [0, pi]
    back = matrix_to_axis_angle(axis_angle_to_matrix(big))
    assert (np.linalg.norm(back, axis=1) <= np.pi + 1e-12).all()
    np.testing.assert_allclose(axis_angle_to_matrix(back), axis_angle_to_matrix(big), atol=1e-9)


def test_batched_shapes():
    aa = np.random.default_rng(3).normal(size=(2, 5, 3))
    m = axis_angle_to_matrix(aa)
    assert m.shape == (2, 5, 3, 3)
    assert matrix_to_quat(m).shape == (2, 5, 4)
    assert quat_to_matrix(matrix_to_quat(m)).shape == (2, 5, 3, 3)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(m)), m, atol=1e-12)
    assert matrix_to_axis_angle(m).shape == (2, 5, 3)


def test_quat_multiply_composes_rotations():
    a, b = random_quats(200, 1), random_quats(200, 2)
    np.testing.assert_allclose(quat_to_matrix(quat_multiply(a, b)),
                               quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-12)
    sa = Rotation.from_quat(a, scalar_first=True)
    sb = Rotation.from_quat(b, scalar_first=True)
    same_rotation_quats(quat_multiply(a, b), (sa * sb).as_quat(scalar_first=True))
    np.testing.assert_allclose(quat_multiply(a[:1], b), quat_multiply(np.repeat(a[:1], 200, 0), b))


def test_quat_normalize():
    q = np.array([[-2.0, 0, 0, 0], [0, 0, 0, 0], [1, 1, 1, 1]])
    out = quat_normalize(q)
    np.testing.assert_allclose(out, [[1, 0, 0, 0], [0, 0, 0, 0], [0.5, 0.5, 0.5, 0.5]])


# --- spherical harmonics ------------------------------------------------------------------
def real_sh(l: int, m: int, d: np.ndarray) -> np.ndarray:
    """Orthonormal real SH from scipy's complex ones (Condon-Shortley phase included)."""
    theta = np.arccos(np.clip(d[:, 2], -1, 1))
    phi = np.arctan2(d[:, 1], d[:, 0])
    y = sph_harm_y(l, abs(m), theta, phi)
    if m > 0:
        return np.sqrt(2) * (-1) ** m * y.real
    if m < 0:
        return np.sqrt(2) * (-1) ** m * y.imag
    return y.real


def fibonacci(n):
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def test_sh_basis_is_the_real_spherical_harmonics():
    d = unit(np.random.default_rng(0).normal(size=(400, 3)))
    basis = sh_basis(d, 3)
    assert basis.shape == (400, 16)
    col = 0
    signs = []
    for l in range(4):
        for m in range(-l, l + 1):
            ref = real_sh(l, m, d)
            sign = np.sign(np.dot(basis[:, col], ref))
            np.testing.assert_allclose(basis[:, col], sign * ref, atol=1e-12)
            signs.append(int(sign))
            col += 1
    # 3DGS's basis is the real SH with a sign flip on the odd-m members of each band (its
    # constants come without the Condon-Shortley phase): e.g. band 1 is (-C1 y, C1 z, -C1 x).
    assert signs == [1 if m % 2 == 0 else -1 for l in range(4) for m in range(-l, l + 1)]


def test_sh_basis_orthonormal_on_the_sphere():
    d = fibonacci(40_000)
    b = sh_basis(d, 3)
    gram = b.T @ b * (4 * np.pi / len(d))
    np.testing.assert_allclose(gram, np.eye(16), atol=2e-3)


def test_sh_basis_prefix_and_band1_values():
    d = unit([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(sh_basis(d, 1), sh_basis(d, 3)[:, :4])
    x, y, z = d[0]
    np.testing.assert_allclose(sh_basis(d, 1)[0], [SH_C0, -0.4886025119029199 * y,
                                                   0.4886025119029199 * z, -0.4886025119029199 * x])


def test_eval_sh_is_the_weighted_sum_plus_half_clamped():
    rng = np.random.default_rng(1)
    sh = rng.normal(size=(50, 9, 3))
    d = unit(rng.normal(size=(50, 3)))
    b = sh_basis(d, 2)
    direct = np.stack([sum(b[i, k] * sh[i, k] for k in range(9)) for i in range(50)]) + 0.5
    np.testing.assert_allclose(eval_sh(sh, d), np.maximum(direct, 0), atol=1e-12)
    assert (eval_sh(sh, d) >= 0).all() and (direct < 0).any()


def test_dc_conversions():
    rgb = np.random.default_rng(2).uniform(size=(10, 3))
    np.testing.assert_allclose(dc_to_rgb(rgb_to_dc(rgb)), rgb, atol=1e-12)
    np.testing.assert_allclose(rgb_to_dc(np.full(3, 0.5)), 0)
    np.testing.assert_allclose(dc_to_rgb(np.ones(3)), 0.5 + SH_C0)
    assert [degree_from_count(k) for k in SH_COUNTS] == [0, 1, 2, 3]
    with pytest.raises(ValueError):
        degree_from_count(5)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rotate_sh_invariance(degree):
    """f'(d) = f(R^T d) for every direction; band energy kept; rotations compose."""
    rng = np.random.default_rng(degree)
    k = SH_COUNTS[degree]
    sh = rng.normal(size=(20, k, 3))
    r1 = Rotation.random(random_state=degree).as_matrix()
    r2 = Rotation.random(random_state=degree + 10).as_matrix()
    d = unit(rng.normal(size=(20, 3)))
    rotated = rotate_sh(sh, r1)
    raw = lambda c, dirs: np.einsum("mk,mkc->mc", sh_basis(dirs, degree), c)  # no clamp
    np.testing.assert_allclose(raw(rotated, d), raw(sh, d @ r1), atol=1e-10)
    for l in range(degree + 1):
        band = slice(l * l, (l + 1) ** 2)
        np.testing.assert_allclose(np.linalg.norm(rotated[:, band], axis=1),
                                   np.linalg.norm(sh[:, band], axis=1), atol=1e-10)
    np.testing.assert_allclose(rotate_sh(rotate_sh(sh, r1), r2), rotate_sh(sh, r2 @ r1), atol=1e-10)
    np.testing.assert_allclose(rotate_sh(sh, np.eye(3)), sh, atol=1e-12)
    np.testing.assert_array_equal(rotated[:, 0], sh[:, 0])  # DC is rotation invariant
    for m in sh_rotation(r1, degree):
        np.testing.assert_allclose(m @ m.T, np.eye(len(m)), atol=1e-10)
    assert rotate_sh(sh.astype(np.float32), r1).dtype == np.float32


def test_rotate_sh_degree0_and_half_turn():
    sh0 = np.random.default_rng(0).normal(size=(5, 1, 3))
    np.testing.assert_array_equal(rotate_sh(sh0, Rotation.random(random_state=0).as_matrix()), sh0)
    r = Rotation.from_rotvec([0, np.pi, 0]).as_matrix()
    sh = np.random.default_rng(1).normal(size=(5, 16, 3))
    d = unit(np.random.default_rng(2).normal(size=(5, 3)))
    np.testing.assert_allclose(eval_sh(rotate_sh(sh, r), d), eval_sh(sh, d @ r), atol=1e-10)


def test_dtypes_follow_the_module_contract():
    # quaternion helpers keep the input's dtype; the conversions return float64
    q = np.array([[1, 0.1, 0.2, 0.3]], np.float32)
    for fn in (quat_normalize, quat_to_matrix, lambda x: quat_multiply(x, x)):
        assert fn(q).dtype == np.float32
    m = quat_to_matrix(q)
    for out in (matrix_to_quat(m), axis_angle_to_matrix(np.float32([[0.1, 0.2, 0.3]])),
                matrix_to_axis_angle(m)):
        assert out.dtype == np.float64
