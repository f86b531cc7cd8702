"""The single-frame build's outline trimmed to the photo's person (`recon.outline_trim`) on a
case whose answer is known: a sphere of bald discs whose true outline is a circle."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet, rgb_to_dc
from avatarkit.recon.outline_trim import narrow_across, outline_distance, sharpen_outline, trim_outline
from avatarkit.render import render
from avatarkit.render.camera import Camera

SIZE = 128
RADIUS = 0.08
DISTANCE = 0.5


def _icosphere(levels: int = 3):
    """(V, 3) unit vertices, (F, 3) faces of a subdivided icosahedron."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
         (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
         (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.asarray(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(levels):
        mid, out = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = verts[a] + verts[b]
                verts.append(p / np.linalg.norm(p))
                mid[key] = len(verts) - 1
            return mid[key]

        for a, b, c in f:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            out += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = out
    return np.asarray(verts), np.asarray(f, np.int64)


def _sphere_discs(per_face: int = 2, seed: int = 0, radius: float = RADIUS):
    """Discs in the triangles' planes of a sphere of `radius` at the origin (as `bald_discs`:
    random points on each triangle, 1.5 x the radius that tiles the surface), and the fit: the
    sphere of RADIUS (the head) seen by the camera."""
    from avatarkit.rotations import matrix_to_quat

    unit, faces = _icosphere()
    verts = radius * unit
    rng = np.random.default_rng(seed)
    ids = np.repeat(np.arange(len(faces)), per_face)
    w = rng.dirichlet(np.ones(3), len(ids))
    tri = verts[faces[ids]]                                      # (N, 3, 3)
    means = np.einsum("nk,nkd->nd", w, tri)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    normal *= np.sign(np.einsum("nd,nd->n", normal, means))[:, None]
    a = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(normal, a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    q = matrix_to_quat(np.stack([u, np.cross(normal, u), normal], 2))
    r = 1.5 * np.sqrt(4 * np.pi * radius ** 2 / len(ids) / np.pi)
    n = len(ids)
    bald = GaussianSet(means, q, np.tile([r, r, 0.15 * r], (n, 1)), np.full(n, 0.95),
                       rgb_to_dc(np.full((n, 3), 0.6, np.float32)), extras={"binding": ids.astype(np.int32)})
    cam = Camera.look_at((0.0, 0.0, DISTANCE), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)
    fit = SimpleNamespace(camera=cam, rest_vertices=RADIUS * unit, model=SimpleNamespace(faces=faces))
    return bald, fit


def _true_outline(cam, radius: float = RADIUS):
    """(H, W) bool: the exact silhouette of a sphere of `radius`, a circle about the image's centre."""
    radius_px = cam.fx * np.tan(np.arcsin(radius / DISTANCE))
    yy, xx = np.mgrid[:SIZE, :SIZE] + 0.5
    return (yy - cam.cy) ** 2 + (xx - cam.cx) ** 2 <= radius_px ** 2


def _overshoot(gaussians, cam, person):
    """(outward, inward) pixels per pixel of the person's outline: the render (alpha > 0.5)
    over the wall, and the person it leaves uncovered."""
    from scipy import ndimage

    m = np.asarray(render(gaussians, cam, np.ones(3)).alpha) > 0.5
    perim = (person & ~ndimage.binary_erosion(person)).sum()
    return (m & ~person).sum() / perim, (person & ~m).sum() / perim


def test_the_render_outline_comes_onto_the_person_outline():
    """Discs on the true surface overshoot its outline by their Gaussian tails (more than a pixel
    per outline pixel); trimmed, the render's outline is within half a pixel of the truth both
    ways, and only discs seen near the outline moved."""
    bald, fit = _sphere_discs()
    person = _true_outline(fit.camera)
    out0, in0 = _overshoot(bald, fit.camera, person)
    assert out0 > 1.0 and in0 < 0.2
    empty = bald.subset(np.arange(0)).replace(extras={})
    trimmed, _, info = trim_outline(bald, empty, fit, person)
    out1, in1 = _overshoot(trimmed, fit.camera, person)
    assert out1 < 0.5 and in1 < 0.5, (out0, out1, in1)
    moved = np.linalg.norm(np.asarray(trimmed.means, float) - np.asarray(bald.means, float), axis=1) > 0
    assert info["bald_moved"] == int(moved.sum()) > 0
    # the discs facing the camera (the middle of the view) stay where they were
    facing = np.asarray(bald.means, float)[:, 2] / RADIUS
    assert not moved[facing > 0.7].any()
    # moved inward (toward the centre), not out
    r0 = np.linalg.norm(np.asarray(bald.means, float)[moved], axis=1)
    r1 = np.linalg.norm(np.asarray(trimmed.means, float)[moved], axis=1)
    assert (r1 < r0).all()
    np.testing.assert_array_equal(trimmed.extras["binding"], bald.extras["binding"])


def test_a_person_wider_than_the_render_moves_nothing():
    """Where the photo's person covers the whole render (the wall is further out than any
    footprint), the discs stay put: the trim only pulls in, from the wall."""
    bald, fit = _sphere_discs()
    person = np.ones((SIZE, SIZE), bool)
    person[:2] = False
    empty = bald.subset(np.arange(0)).replace(extras={})
    trimmed, _, info = trim_outline(bald, empty, fit, person)
    assert info["bald_moved"] == 0
    np.testing.assert_array_equal(trimmed.means, bald.means)


def test_the_hair_over_the_wall_is_dropped():
    """A shell of finer hair discs 6 mm over the sphere hides the bald discs and overshoots the
    person (a sphere 3 mm over the head, seen). With the hair trimmed its Gaussians over the wall
    are dropped (the rest kept as they were) and the outline comes within half a pixel of the
    person; without (HAIR off) the hair's overshoot stays."""
    bald, fit = _sphere_discs()
    hair, _ = _sphere_discs(per_face=12, seed=1, radius=RADIUS + 0.006)
    hair = hair.replace(extras={"strand": np.arange(len(hair), dtype=np.int32)})
    person = _true_outline(fit.camera, RADIUS + 0.003)
    both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    out0, _ = _overshoot(both, fit.camera, person)
    assert out0 > 1.0
    b1, h1, info = trim_outline(bald, hair, fit, person)          # HAIR: on by default
    out1, in1 = _overshoot(GaussianSet.concat([b1.replace(extras={}), h1.replace(extras={})]), fit.camera, person)
    assert out1 < 0.5 and in1 < 0.5, (out0, out1, in1)
    assert 0 < info["hair_dropped"] == len(hair) - len(h1)
    kept = h1.extras["strand"]
    np.testing.assert_array_equal(h1.means, hair.means[kept])
    # the hair facing the camera stays
    facing = np.asarray(hair.means, float)[:, 2] / (RADIUS + 0.006)
    assert np.isin(np.flatnonzero(facing > 0.7), kept).all()
    b2, h2, info2 = trim_outline(bald, hair, fit, person, with_hair=False)
    assert info2["hair_dropped"] == 0 and len(h2) == len(hair)
    assert _overshoot(GaussianSet.concat([b2.replace(extras={}), h2.replace(extras={})]), fit.camera, person)[0] > 1.0


def _true_distance(cam, radius: float = RADIUS) -> np.ndarray:
    """(H, W) px from each pixel centre to the sphere's true outline, positive inside."""
    radius_px = cam.fx * np.tan(np.arcsin(radius / DISTANCE))
    yy, xx = np.mgrid[:SIZE, :SIZE] + 0.5
    return radius_px - np.hypot(yy - cam.cy, xx - cam.cx)


def test_the_sharpened_outline_is_the_true_outline():
    """The outline discs narrowed across the outline (their edge 2.5 sigmas out, on the
    outline): the render's outline is within half a pixel of the sphere's true circle both
    ways, its alpha is >= 0.95 everywhere one pixel inside it (the inside stays opaque: what
    moving the discs in costs) and under 0.5 half a pixel beyond; the discs facing the camera
    are untouched."""
    bald, fit = _sphere_discs()
    cam = fit.camera
    person = _true_outline(cam)
    d = _true_distance(cam)
    empty = bald.subset(np.arange(0)).replace(extras={})
    sharp, _, info = sharpen_outline(bald, empty, fit, person, edge_sigmas=2.5, beyond_px=0.0)
    out1, in1 = _overshoot(sharp, cam, person)
    assert out1 < 0.5 and in1 < 0.5, (out1, in1)
    alpha = np.asarray(render(sharp, cam, np.ones(3)).alpha)
    assert alpha[np.abs(d - 1.0) < 0.2].min() >= 0.95
    assert alpha[np.abs(d + 0.5) < 0.2].max() < 0.5
    # untouched, the same discs stand past it with alpha ~1 half a pixel beyond
    alpha0 = np.asarray(render(bald, cam, np.ones(3)).alpha)
    assert alpha0[np.abs(d + 0.5) < 0.2].mean() > 0.9
    changed = (np.abs(np.asarray(sharp.scales) - np.asarray(bald.scales)).max(axis=1) > 0) | \
        (np.abs(np.asarray(sharp.means) - np.asarray(bald.means)).max(axis=1) > 0)
    assert info["bald_narrowed"] == int(changed.sum()) > 0
    facing = np.asarray(bald.means, float)[:, 2] / RADIUS
    assert not changed[facing > 0.7].any()
    np.testing.assert_array_equal(sharp.extras["binding"], bald.extras["binding"])


def test_the_default_sharpening_keeps_the_last_pixel_opaque():
    """At the default settings (the edge 2 sigmas out, a quarter pixel past the outline: the
    photo's last person pixel must stay solid, as the head-mask figure wants) the overshoot
    falls by more than half and the alpha half a pixel inside the outline stays >= 0.99."""
    bald, fit = _sphere_discs()
    cam = fit.camera
    person = _true_outline(cam)
    d = _true_distance(cam)
    empty = bald.subset(np.arange(0)).replace(extras={})
    out0, _ = _overshoot(bald, cam, person)
    sharp, _, _ = sharpen_outline(bald, empty, fit, person)
    out1, in1 = _overshoot(sharp, cam, person)
    assert out1 < 0.55 * out0 and in1 < 0.1, (out0, out1, in1)
    alpha = np.asarray(render(sharp, cam, np.ones(3)).alpha)
    assert alpha[np.abs(d - 0.5) < 0.2].min() >= 0.99


def test_narrowing_keeps_the_extent_along_the_outline_and_the_inner_edge():
    """Each narrowed disc's projected footprint (the reference projection's 2D covariance, the
    renderer's dilation included) is narrower across the outline, as wide along it, its outer
    edge (EDGE sigmas out) on the outline or inside it, and its inner edge where it was."""
    from avatarkit.render.pipeline import DILATION
    from avatarkit.render.reference import project_reference

    bald, fit = _sphere_discs()
    cam = fit.camera
    sd = outline_distance(_true_outline(cam))
    sharp, narrowed = narrow_across(bald, cam, sd, 2.5, 0.0, 0.05)
    assert narrowed.sum() > 50
    p0, p1 = project_reference(bald, cam), project_reference(sharp, cam)
    c = cam.cx, cam.cy

    def footprint(p):
        conic = p.conics[narrowed]                                 # (k, 3): inverse 2D covariance
        cov = np.linalg.inv(np.stack([np.stack([conic[:, 0], conic[:, 1]], 1),
                                      np.stack([conic[:, 1], conic[:, 2]], 1)], 1))
        return p.means2d[narrowed], cov

    m0, cov0 = footprint(p0)
    m1, cov1 = footprint(p1)
    out = (m0 - c) / np.linalg.norm(m0 - c, axis=1, keepdims=True)    # outward: from the centre
    along = np.stack([-out[:, 1], out[:, 0]], 1)
    var = lambda cov, v: np.einsum("ni,nij,nj->n", v, cov, v)
    np.testing.assert_allclose(var(cov1, along), var(cov0, along), rtol=0.05, atol=0.02)
    s0, s1 = np.sqrt(var(cov0, out)), np.sqrt(var(cov1, out))
    assert (s1 <= s0 + 1e-3).all() and (s1 >= np.sqrt(DILATION) - 1e-3).all() and (s1 / s0).mean() < 0.95
    # px beyond the outline (the sphere's: the code's outward direction is the pixel mask's
    # distance field's, within ~0.5 px of the circle's radial one)
    radius_px = cam.fx * np.tan(np.arcsin(RADIUS / DISTANCE))
    beyond = lambda m: np.linalg.norm(m - c, axis=1) - radius_px
    assert (beyond(m1) + 2.5 * s1 < 0.5).all()
    # the inner edge stays where the new width allows it (a disc whose inner edge was within
    # 2 x 2.5 x the dilation's sigma of the outline cannot span it and moves in whole)
    wide = beyond(m0) - 2.5 * s0 < -5 * np.sqrt(DILATION) - 0.5
    assert wide.sum() > 50
    np.testing.assert_allclose((beyond(m1) - 2.5 * s1)[wide], (beyond(m0) - 2.5 * s0)[wide], atol=0.5)


def test_a_person_wider_than_the_render_sharpens_nothing():
    """Where no footprint reaches the photo's outline nothing changes."""
    bald, fit = _sphere_discs()
    person = np.ones((SIZE, SIZE), bool)
    person[:2] = False
    empty = bald.subset(np.arange(0)).replace(extras={})
    sharp, _, info = sharpen_outline(bald, empty, fit, person)
    assert info["bald_narrowed"] == 0
    for f in ("means", "scales", "quats"):
        np.testing.assert_array_equal(getattr(sharp, f), getattr(bald, f))


def test_the_sharpening_drops_the_hair_over_the_wall():
    """With the hair shell of `test_the_hair_over_the_wall_is_dropped`, the sharpening with
    hair rounds drops the hair voted over the wall as the trim does, and the outline comes
    within half a pixel; with none (HAIR_ROUNDS's default) the hair's overshoot stays."""
    bald, fit = _sphere_discs()
    hair, _ = _sphere_discs(per_face=12, seed=1, radius=RADIUS + 0.006)
    person = _true_outline(fit.camera, RADIUS + 0.003)
    b1, h1, info = sharpen_outline(bald, hair, fit, person, edge_sigmas=2.5, beyond_px=0.0, hair_rounds=8)
    out1, in1 = _overshoot(GaussianSet.concat([b1.replace(extras={}), h1.replace(extras={})]), fit.camera, person)
    assert out1 < 0.5 and in1 < 0.5, (out1, in1)
    assert 0 < info["hair_dropped"] == len(hair) - len(h1)
    b2, h2, info2 = sharpen_outline(bald, hair, fit, person)
    assert info2["hair_dropped"] == 0 and len(h2) == len(hair)
    assert _overshoot(GaussianSet.concat([b2.replace(extras={}), h2.replace(extras={})]), fit.camera, person)[0] > 1.0


def test_narrowed_hair_stays_outside_the_head(monkeypatch):
    """With NARROW_HAIR the hair shell's Gaussians past the outline are narrowed as the discs
    are (the overshoot falls), and none ends within `assemble.HAIR_MARGIN` of the head: those
    whose move would bring them there move less (or not at all)."""
    from avatarkit.recon import outline_trim
    from avatarkit.recon.assemble import HAIR_MARGIN
    from avatarkit.recon.mesh_distance import signed_distance

    bald, fit = _sphere_discs()
    hair, _ = _sphere_discs(per_face=12, seed=1, radius=RADIUS + 0.006)
    person = _true_outline(fit.camera, RADIUS + 0.003)
    both = lambda b, h: GaussianSet.concat([b.replace(extras={}), h.replace(extras={})])
    b0, h0, _ = sharpen_outline(bald, hair, fit, person, edge_sigmas=2.5, beyond_px=0.0)
    monkeypatch.setattr(outline_trim, "NARROW_HAIR", True)
    b1, h1, info = sharpen_outline(bald, hair, fit, person, edge_sigmas=2.5, beyond_px=0.0)
    assert info["hair_narrowed"] > 0 and 0 < info["hair_moves_cut"] < info["hair_narrowed"]
    assert len(h1) == len(hair)
    # 2.93 px per outline px without (the hair's), 1.38 with: the margin holds half the moves back
    assert _overshoot(both(b1, h1), fit.camera, person)[0] < 0.6 * _overshoot(both(b0, h0), fit.camera, person)[0]
    sd = signed_distance(h1.means, fit.rest_vertices, fit.model.faces)
    assert sd.min() >= HAIR_MARGIN - 1e-6
