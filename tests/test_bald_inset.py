"""The bald layer's outline (`bald_discs.INSET`, `inset_depth`, `set_in`): discs on the head's
surface, each at its full opacity, stack along the line of sight at the outline and pass alpha 0.5
beyond it. Set in along their normal by `inset_depth`, their outline falls on the surface.
Cases with a known answer: a sphere of discs drawn as `sample_bald` draws them, whose outline
seen from any camera is a circle."""
from __future__ import annotations

import math

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import bald_discs
from avatarkit.render import render
from avatarkit.render.camera import Camera
from helpers import uv_sphere

DISTANCE = 0.78        # the synthetic benchmark's camera distance: 2.2 mm pixels at 192 px
ON = 0.45              # `INSET` when on (off by default)


@pytest.fixture(autouse=True)
def inset_on(monkeypatch):
    monkeypatch.setattr(bald_discs, "INSET", ON)


def _sphere_discs(radius: float, tile: float, seed: int = 0):
    """Discs on the sphere as `sample_bald` draws them (area-weighted, `_discs_on`'s sizes for a
    share of pi tile^2 each, the holes filled, opacity 0.95-1): (points, quats, scales, ids,
    normals, opacity) and the sphere's faces' disc sigma (F,)."""
    v, faces = uv_sphere(radius)
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n = int(round(area.sum() / (np.pi * tile ** 2)))
    rng = np.random.default_rng(seed)
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    share = np.full(len(faces), area.sum() / n)
    pts, quats, scales, normals = bald_discs._discs_on(v, faces, ids, share[ids], rng)
    discs = bald_discs.fill_holes(v, faces, area, share, (pts, quats, scales, ids, normals), rng.spawn(1)[0])
    opacity = rng.uniform(0.95, 1.0, len(discs[0]))
    return discs, opacity, bald_discs.COVERAGE * np.sqrt(share / np.pi)


def _overshoot(points, discs, opacity, radius: float, width: int) -> float:
    """How far (px) the render's alpha-0.5 outline lies beyond the sphere's circle, seen from
    `DISTANCE` at `width` px (the circle of the same area as the alpha > 0.5 pixels)."""
    g = GaussianSet.from_colors(points.astype(np.float32), discs[1].astype(np.float32), discs[2].astype(np.float32),
                                opacity.astype(np.float32), np.full((len(points), 3), 0.5, np.float32))
    cam = Camera.look_at((0.0, 0.0, DISTANCE), (0.0, 0.0, 0.0), fov_deg=30.0, width=width, height=width)
    alpha = np.asarray(render(g, cam, (1.0, 1.0, 1.0)).alpha)
    return math.sqrt((alpha > 0.5).sum() / math.pi) - cam.fy * math.tan(math.asin(radius / DISTANCE))


@pytest.mark.parametrize("radius,tile", [(0.05, 0.0038), (0.05, 0.0022), (0.08, 0.0038)])
def test_a_sphere_of_discs_set_in_has_its_outline_on_the_sphere(radius, tile):
    # a neck-sized and a face-sized disc on a neck-sized sphere, the large disc on a cranium-sized
    # one; each camera's discs set in for its own pixel. On the surface the outline stands 1.4-5
    # px out (more the finer the pixels); set in, within 0.4 px at 192 and 384 px, and at 768 px
    # (pixels 4x finer than the synthetic videos') within 0.8 px and a fifth of it
    discs, opacity, sigma_of = _sphere_discs(radius, tile)
    points, _, _, ids, normals = discs
    for width in (192, 384, 768):
        pixel = DISTANCE / (0.5 * width / math.tan(math.radians(15.0)))
        on = _overshoot(points, discs, opacity, radius, width)
        depth = bald_discs.inset_depth(sigma_of, pixel)
        inset = _overshoot(bald_discs.set_in(points, normals, ids, depth), discs, opacity, radius, width)
        assert on > 1.3, (width, on)
        if width < 768:
            assert abs(inset) < 0.4, (width, on, inset)
        else:
            assert abs(inset) < min(0.8, 0.2 * on), (width, on, inset)


def test_inset_depth_grows_with_the_discs_and_the_pixel_and_is_none_when_off(monkeypatch):
    sigma = np.array([0.002, 0.004, 0.008])
    fine, coarse = bald_discs.inset_depth(sigma, 0.0), bald_discs.inset_depth(sigma, 0.002)
    np.testing.assert_allclose(fine, bald_discs.INSET * sigma)
    assert (np.diff(fine) > 0).all() and (coarse > fine).all()
    # the dilation's part never more than a pixel, however coarse the camera
    assert (bald_discs.inset_depth(sigma, 0.05) - fine <= 0.05 + 1e-12).all()
    monkeypatch.setattr(bald_discs, "INSET", None)
    assert (bald_discs.inset_depth(sigma, 0.002) == 0).all()


@pytest.fixture(scope="module")
def view():
    from avatarkit.recon.fit import synthetic_head_view

    return synthetic_head_view((0.0, 0.15, 0.0), distance=0.6, size=256)


def test_sample_bald_sets_each_face_in_along_its_normal_and_keeps_the_creases(view, monkeypatch):
    fit = view.truth
    on = bald_discs.sample_bald(fit, 6000, np.random.default_rng(1))
    monkeypatch.setattr(bald_discs, "INSET", None)
    flat = bald_discs.sample_bald(fit, 6000, np.random.default_rng(1))
    monkeypatch.setattr(bald_discs, "INSET", ON)
    for a, b in zip(on[1:], flat[1:]):                       # quats, scales, faces, normals as before
        np.testing.assert_array_equal(a, b)
    move = np.asarray(flat[0], np.float64) - np.asarray(on[0], np.float64)      # (N, 3) inward
    normals = np.asarray(flat[4], np.float64)
    depth = np.einsum("nc,nc->n", move, normals)
    # along the normal only, by the depth of its face
    np.testing.assert_allclose(move, depth[:, None] * normals, atol=1e-7)
    kept = bald_discs._inset_kept(fit.model, np.asarray(fit.rest_vertices, np.float64))[on[3]]
    assert kept.any() and (~kept).any()
    np.testing.assert_allclose(depth[kept], 0.0, atol=1e-7)
    pixel = bald_discs.camera_pixel(fit.camera, fit.rest_vertices)
    assert 0.001 < pixel < 0.003                             # 256 px at 0.6 m: ~1.7 mm
    v = np.asarray(fit.rest_vertices, np.float64)
    faces = np.asarray(fit.model.faces)
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    # the face's disc sigma from its share of the surface, as `_discs_on` sizes it (the face 3x denser)
    density = np.where(bald_discs._face_weights(fit.model), 3.0, 1.0)
    from avatarkit.rig.frames import degenerate_faces
    density[degenerate_faces(v, faces)] = 0.0
    sigma = bald_discs.COVERAGE * np.sqrt((area * density).sum() / 6000 / np.maximum(density, 1e-12) / np.pi)
    np.testing.assert_allclose(depth[~kept], bald_discs.inset_depth(sigma, pixel)[on[3][~kept]], rtol=1e-5)


def test_the_lift_keeps_the_face_inside_its_outline(view, monkeypatch):
    # the lips and the lids stay on the surface: set in with the rest, the closed lips part and
    # the lids leave their eyeballs, and the dark inside shows through (inside the outline,
    # eroded 2 px so that the outline itself does not count: the truth is a render of discs too,
    # whose own outline stands out as the build's did)
    import cv2
    from types import SimpleNamespace

    from avatarkit.recon.assemble import psnr

    inner = cv2.erode((view.alpha > 0.5).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0

    def face_psnr():
        bald, _ = bald_discs.lift_bald(view.image, view.analysis, view.segmentation,
                                       SimpleNamespace(image=view.image, labels=view.segmentation.labels),
                                       view.truth, 20000, np.random.default_rng(0))
        again = render(bald.replace(extras={}), view.truth.camera, background=(0.47, 0.59, 0.73)).rgb
        return psnr(again, view.image / 255.0, inner)

    kept = face_psnr()
    monkeypatch.setattr(bald_discs, "INSET", None)
    flat = face_psnr()
    monkeypatch.setattr(bald_discs, "INSET", ON)
    monkeypatch.setattr(bald_discs, "INSET_KEEP", ())
    opened = face_psnr()
    # measured 30.04 / 30.13 / 28.93 dB
    assert kept > flat - 0.2
    assert opened < flat - 0.8
