"""Procedural hair: deterministic, real-sized, on the scalp, outside the head, strand-aligned."""
import numpy as np
import pytest

from avatarkit.errors import InputError
from avatarkit.rotations import quat_to_matrix
from avatarkit.synthetic import HAIR_STYLES, HeadEllipsoid, hair_strands, make_hair

HEAD = HeadEllipsoid()


@pytest.fixture(scope="module", params=HAIR_STYLES)
def styled(request):
    return request.param, make_hair(request.param, n=3000, seed=3)


def test_exact_count_and_valid_set(styled):
    style, g = styled
    assert len(g) == 3000
    assert g.sh_degree == 0
    assert g.extras["strand"].shape == (3000,)
    assert (np.diff(g.extras["strand"]) >= 0).all()  # strands are contiguous runs


def test_deterministic_per_seed():
    a = make_hair("bob", n=500, seed=7)
    b = make_hair("bob", n=500, seed=7)
    c = make_hair("bob", n=500, seed=8)
    for name in ("means", "quats", "scales", "opacities", "sh"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.allclose(a.means, c.means)


def test_everything_outside_the_head(styled):
    _, g = styled
    assert HEAD.level(g.means).min() > 1.0
    axes = quat_to_matrix(g.quats) * g.scales[:, None, :]
    for i in range(3):
        for sign in (1, -1):
            assert HEAD.level(g.means + sign * axes[:, :, i]).min() > 1.0


def test_no_hair_on_the_face(styled):
    _, g = styled
    c, r = np.array(HEAD.center), np.array(HEAD.radii)
    m = g.means - c
    face = (m[:, 2] > 0.5 * r[2]) & (np.abs(m[:, 0]) < 0.6 * r[0]) & (m[:, 1] < 0.3 * r[1])
    assert not face.any()


def test_roots_start_on_the_scalp():
    lines = hair_strands("long_straight", strands=400, seed=1)
    roots = lines[:, 0]
    level = HEAD.level(roots)
    assert (level > 1.0).all() and (level < 1.25).all()
    d = roots - np.array(HEAD.center)
    # nothing rooted low on the front of the head (the face)
    assert not ((d[:, 2] > 0.6 * HEAD.radii[2]) & (d[:, 1] < 0.2 * HEAD.radii[1])).any()


@pytest.mark.parametrize("style,lo,hi", [("long_straight", 0.24, 0.36), ("ponytail", 0.24, 0.36),
                                         ("bob", 0.13, 0.21), ("short", 0.05, 0.2)])
def test_lengths_below_the_crown(style, lo, hi):
    g = make_hair(style, n=4000, seed=0)
    drop = HEAD.crown_y - g.means[:, 1].min()
    assert lo <= drop <= hi


def test_thin_gaussians_along_the_strand(styled):
    style, g = styled
    assert (np.argmax(g.scales, axis=1) == 0).all()          # longest axis is local x
    assert g.scales[:, 1:].max() < 0.001                      # sub-millimetre thickness
    assert (g.scales[:, 0] > 2 * g.scales[:, 1]).all()
    axis = quat_to_matrix(g.quats)[:, :, 0]
    same = g.extras["strand"][1:] == g.extras["strand"][:-1]
    step = np.diff(g.means, axis=0)[same]
    step /= np.linalg.norm(step, axis=1, keepdims=True)
    cos = np.abs(np.einsum("ij,ij->i", step, axis[:-1][same]))
    assert np.median(cos) > (0.9 if style == "curly" else 0.97)  # curls turn ~45 deg a segment


def test_colours_and_opacities_vary_in_range(styled):
    _, g = styled
    assert ((g.opacities >= 0.6) & (g.opacities <= 1.0)).all()
    assert g.colors.std(axis=0).min() > 0.005
    assert (g.colors >= 0).all() and (g.colors <= 1).all()


def test_hair_follows_the_given_head():
    big = HeadEllipsoid(center=(0.0, 1.6, 0.02), radii=(0.1, 0.12, 0.11))
    g = make_hair("curly", n=2000, seed=0, head=big)
    assert big.level(g.means).min() > 1.0
    assert abs(g.means[:, 1].mean() - 1.6) < 0.15
    s = make_hair("short", n=500, head_radius=0.09)
    assert HeadEllipsoid.sphere(0.09).level(s.means).min() > 1.0


def test_bad_arguments():
    with pytest.raises(InputError, match="unknown hair style"):
        make_hair("mohawk")
    with pytest.raises(InputError):
        make_hair("bob", n=0)
    with pytest.raises(InputError):
        make_hair("bob", head=HEAD, head_radius=0.1)
    with pytest.raises(InputError):
        HeadEllipsoid(radii=(0.1, -1.0, 0.1))
    with pytest.raises(InputError):
        make_hair("bob", n=10, color=(2.0, 0.0, 0.0))
