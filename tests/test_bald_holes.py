"""The bald layer's holes (`bald_discs.HOLE_ALPHA`, `fill_holes`): discs drawn at random leave
patches of the surface thin, and what lies behind (the back of the head, dark where the video
build fills the scalp with the hair's colour) shows through them as specks in a large render.
Cases with a known answer: a flat sheet of random discs over a dark plane, seen head-on."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import bald_discs
from avatarkit.render import render
from avatarkit.render.camera import Camera
from avatarkit.rotations import quat_to_matrix


def _sheet(cells: int = 10, size: float = 0.1):
    """A square of triangles in the z = 0 plane, side `size` metres centred on the origin:
    vertices (V, 3), faces (F, 3) wound so the triangles' normal is +Z."""
    t = np.linspace(-size / 2, size / 2, cells + 1)
    X, Y = np.meshgrid(t, t)
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    i = np.arange(cells)[:, None] * (cells + 1) + np.arange(cells)[None, :]
    i = i.ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + cells + 2], 1), np.stack([i, i + cells + 2, i + cells + 1], 1)])
    return v, faces


def _random_discs(v, faces, n: int, seed: int = 3):
    """n discs as `sample_bald` draws them (area-weighted, independent), and the per-face weight
    and share `fill_holes` takes."""
    from avatarkit.rig.frames import triangle_frames

    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    ids = rng.choice(len(faces), size=n, p=area / area.sum()).astype(np.int32)
    share = np.full(len(faces), area.sum() / n)
    points, quats, scales, normals = bald_discs._discs_on(v, faces, ids, share[ids], rng)
    assert np.allclose(triangle_frames(v, faces)[1][:, 2, 1], 1.0)     # the sheet faces +Z
    return (points, quats, scales, ids, normals), area, share


def _leak(discs, width: int = 256) -> np.ndarray:
    """The white sheet of `discs` in front of a black plane, seen head-on from +Z: (pixels,) the
    darkening over the sheet's middle (1 - the pixel's grey), where the black shows through."""
    points, quats, scales, _, _ = discs
    n = len(points)
    front = GaussianSet.from_colors(points, quats, scales, np.full(n, 0.95), np.ones((n, 3)))
    g = np.linspace(-0.06, 0.06, 25)
    X, Y = np.meshgrid(g, g)
    m = X.size
    back = GaussianSet.from_colors(np.stack([X.ravel(), Y.ravel(), np.full(m, -0.02)], 1),
                                   np.tile([1.0, 0, 0, 0], (m, 1)), np.tile([0.008, 0.008, 0.001], (m, 1)),
                                   np.full(m, 0.99), np.zeros((m, 3)))
    cam = Camera.look_at((0.0, 0.0, 0.3), (0.0, 0.0, 0.0), fov_deg=20.0, width=width, height=width)
    rgb = np.asarray(render(GaussianSet.concat([front, back]), cam, (0.0, 0.0, 0.0)).rgb)
    c = width // 2
    r = int(0.03 / (2 * 0.3 * np.tan(np.radians(10.0))) * width)     # the middle 6 cm
    return 1.0 - rgb[c - r:c + r, c - r:c + r].mean(axis=2).ravel()


@pytest.fixture(scope="module")
def sheet():
    v, faces = _sheet()
    discs, area, share = _random_discs(v, faces, 400)
    return v, faces, discs, area, share


def test_random_discs_leave_holes_the_dark_plane_shows_through(sheet):
    # the case's premise: without the fill, the black plane behind shows through the white sheet
    # (discs ~8 px sigma at this size, as the face's are at 768 px)
    v, faces, discs, area, share = sheet
    leak = _leak(discs)
    assert leak.max() > 0.2 and (leak > 0.05).mean() > 0.01


def test_fill_holes_keeps_the_dark_plane_from_showing_through(sheet):
    v, faces, discs, area, share = sheet
    # at the library's own HOLE_ALPHA (on: this fails with it None)
    filled = bald_discs.fill_holes(v, faces, area, share, discs, np.random.default_rng(7))
    n = len(discs[0])
    for before, after in zip(discs, filled):
        np.testing.assert_array_equal(after[:n], before)              # the drawn discs untouched
    extra = len(filled[0]) - n
    assert 0 < extra < 0.25 * n                                        # only where the sheet is thin
    assert np.allclose(filled[0][n:, 2], 0.0) and np.allclose(filled[4][n:], [0, 0, 1])   # lying in it
    leak = _leak(filled)
    assert leak.max() < 0.06 and (leak > 0.05).mean() == 0.0       # without: 0.22, 4 % of the pixels (0.04 here)


def test_surface_coverage_counts_each_disc_once_where_it_is_and_not_from_the_other_side():
    # one disc of opacity 0.9: 0.9 at its centre, 0.9 exp(-1/2) one sigma along either in-plane
    # axis, nothing past 3 sigma, nothing for a point whose normal faces the other way
    rot = np.eye(3)[None]                                  # columns e0 = X, n = Y, b = Z
    scales = np.array([[0.01, 0.001, 0.02]])
    pts = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0, 0.02], [0.031, 0, 0], [0, 0, 0]], float)
    nrm = np.array([[0, 1, 0]] * 4 + [[0, -1, 0]], float)
    cov = bald_discs.surface_coverage(pts, nrm, np.zeros((1, 3)), rot, scales, opacity=0.9)
    np.testing.assert_allclose(cov, [0.9, 0.9 * np.exp(-0.5), 0.9 * np.exp(-0.5), 0.0, 0.0], atol=1e-12)
    # two discs on the same spot: 1 - (1 - 0.9)^2
    two = bald_discs.surface_coverage(pts[:1], nrm[:1], np.zeros((2, 3)), np.repeat(rot, 2, 0),
                                      np.repeat(scales, 2, 0), opacity=0.9)
    np.testing.assert_allclose(two, [0.99], atol=1e-12)


def test_sample_bald_adds_discs_only_after_the_drawn_ones(monkeypatch):
    # the head's n discs and the caller's next draws are as without the fill; the extra discs
    # lie on the head's triangles
    from avatarkit.recon.fit import synthetic_head_view

    fit = synthetic_head_view((0.0, 0.15, 0.0), distance=0.6, size=64, n_gaussians=500).truth
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    monkeypatch.setattr(bald_discs, "INSET", None)          # the discs on the surface (set in: test_bald_inset.py)
    monkeypatch.setattr(bald_discs, "HOLE_ALPHA", None)
    plain = bald_discs.sample_bald(fit, 3000, rng_a)
    monkeypatch.undo()                                     # the library's HOLE_ALPHA (on)
    monkeypatch.setattr(bald_discs, "INSET", None)
    filled = bald_discs.sample_bald(fit, 3000, rng_b)
    assert len(plain[0]) == 3000 and len(filled[0]) > 3000
    for a, b in zip(plain, filled):
        np.testing.assert_array_equal(b[:3000], a)
    assert rng_a.random() == rng_b.random()
    v = np.asarray(fit.rest_vertices, np.float64)
    tri = v[np.asarray(fit.model.faces)[filled[3][3000:]]]
    normal = quat_to_matrix(np.asarray(filled[1][3000:], np.float64))[:, :, 1]
    # each extra disc's centre is in its triangle's plane
    off = np.einsum("nc,nc->n", np.asarray(filled[0][3000:], np.float64) - tri[:, 0], normal)
    assert np.abs(off).max() < 1e-5


# the fast path (`thin_coverage`, `_spread`) against its slow reference (`surface_coverage` over
# every probe, `_spread_reference`): the same discs, bit for bit

def _random_cloud(rng, k: int, p: int):
    """k discs and p probes scattered over a 6 cm box with random orientations (so some discs
    face away from a probe) and sizes near the face's: (points, normals, means, rot, scales)."""
    from avatarkit.rotations import quat_to_matrix

    means = rng.uniform(-0.03, 0.03, (k, 3))
    q = rng.normal(size=(k, 4))
    rot = quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    r = rng.uniform(0.002, 0.006, k)
    scales = np.stack([r, 0.15 * r, r * rng.uniform(0.85, 1.15, k)], 1)
    pts = rng.uniform(-0.03, 0.03, (p, 3))
    nrm = rot[rng.integers(0, k, p), :, 1] + rng.normal(scale=0.4, size=(p, 3))     # mostly agreeing
    return pts, nrm / np.linalg.norm(nrm, axis=1, keepdims=True), means, rot, scales


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_thin_coverage_is_surface_coverage_below_the_threshold_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    pts, nrm, means, rot, scales = _random_cloud(rng, 3000, 4000)
    ref = bald_discs.surface_coverage(pts, nrm, means, rot, scales)
    assert 0.05 < (ref < 0.95).mean() < 0.95                       # both kinds of probe here
    # thresholds on either side, and exactly at a probe's own coverage (not below it: not thin)
    for threshold in (0.5, 0.95, 0.99, float(np.sort(ref)[len(ref) // 2])):
        idx, cov = bald_discs.thin_coverage(pts, nrm, means, rot, scales, threshold)
        np.testing.assert_array_equal(idx, np.flatnonzero(ref < threshold))
        np.testing.assert_array_equal(cov, ref[idx])
    # fewer discs than the first pass takes: the reference alone
    idx, cov = bald_discs.thin_coverage(pts[:50], nrm[:50], means[:5], rot[:5], scales[:5], 0.95)
    ref5 = bald_discs.surface_coverage(pts[:50], nrm[:50], means[:5], rot[:5], scales[:5])
    np.testing.assert_array_equal(idx, np.flatnonzero(ref5 < 0.95))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_spread_keeps_what_the_greedy_reference_keeps(seed):
    rng = np.random.default_rng(seed)
    # clusters (many points within one another's spacing) and a sparse scatter, spacings varied
    centres = rng.uniform(-0.05, 0.05, (20, 3))
    pts = np.concatenate([centres[rng.integers(0, 20, 1500)] + rng.normal(scale=0.004, size=(1500, 3)),
                          rng.uniform(-0.05, 0.05, (500, 3))])
    spacing = rng.uniform(0.001, 0.006, len(pts))
    order = rng.permutation(len(pts))
    ref = bald_discs._spread_reference(pts, order, spacing)
    assert 50 < len(ref) < len(pts) - 50                            # the thinning does something
    np.testing.assert_array_equal(bald_discs._spread(pts, order, spacing), ref)
    assert len(bald_discs._spread(pts[:0], order[:0], spacing[:0])) == 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sample_bald_fast_path_gives_the_references_discs(monkeypatch, seed):
    from avatarkit.recon.fit import synthetic_head_view

    fit = synthetic_head_view((0.0, 0.15, 0.0), distance=0.6, size=64, n_gaussians=500).truth
    fast = bald_discs.sample_bald(fit, 6000, np.random.default_rng(seed))
    monkeypatch.setattr(bald_discs, "HOLE_REFERENCE", True)
    ref = bald_discs.sample_bald(fit, 6000, np.random.default_rng(seed))
    assert len(ref[0]) > 6000 + 100                                 # holes were filled
    for a, b in zip(ref, fast):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(b, a)


def test_fill_holes_fast_path_on_the_sheet_gives_the_references_discs(sheet, monkeypatch):
    v, faces, discs, area, share = sheet
    fast = bald_discs.fill_holes(v, faces, area, share, discs, np.random.default_rng(11))
    monkeypatch.setattr(bald_discs, "HOLE_REFERENCE", True)
    ref = bald_discs.fill_holes(v, faces, area, share, discs, np.random.default_rng(11))
    assert len(ref[0]) > len(discs[0])
    for a, b in zip(ref, fast):
        np.testing.assert_array_equal(b, a)
