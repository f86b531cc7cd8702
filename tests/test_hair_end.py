"""How low the hair reaches, from turned keyframes (`recon.hair_end`), on a sphere whose hair
ends at a known height, seen from known cameras."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.head.regions import vertex_normals
from avatarkit.recon.hair_end import hair_end_from_views
from avatarkit.recon.multiview import View
from avatarkit.recon.segment import HAIR, SKIN
from avatarkit.render.camera import Camera

R = 0.08
SIZE = 96


def _labels(cam, hair_from: float, behind_only: bool = False) -> np.ndarray:
    """(SIZE, SIZE) labels of the sphere seen by cam: hair where the first hit lies above
    hair_from (and behind the centre, z < 0, when behind_only), skin elsewhere on it."""
    ys, xs = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    r = cam.rotation
    d = ((xs[..., None] - cam.cx) / cam.fx) * r[0] + ((ys[..., None] - cam.cy) / cam.fy) * r[1] + r[2]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.asarray(cam.camera_center, np.float64)
    b = d @ c
    disc = b ** 2 - (c @ c - R ** 2)
    t = -b - np.sqrt(np.maximum(disc, 0))
    p = c + t[..., None] * d
    on = disc > 0
    hair = on & (p[..., 1] > hair_from) & ((p[..., 2] < 0) if behind_only else True)
    return np.where(hair, HAIR, np.where(on, SKIN, 0)).astype(np.int32)


@pytest.fixture(scope="module")
def sphere():
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=4, radius=R)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _view(az, hair_from, reference=False, behind_only=False):
    cam = Camera.orbit(np.zeros(3), az, 5.0, 0.5, 35.0, SIZE, SIZE)
    return View(np.zeros((SIZE, SIZE, 3), np.uint8), cam, _labels(cam, hair_from, behind_only), 1.0, 0, reference)


def test_vertex_normals_of_a_sphere_point_outward(sphere):
    v, f = sphere
    n = vertex_normals(v, f)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.min(np.einsum("ij,ij->i", n, v / R)) > 0.99


def test_the_end_is_where_the_turned_views_show_the_hair_end(sphere):
    v, f = sphere
    # the hair behind the head reaches down to y = -0.03; a profile view and a three-quarter one
    views = [_view(0.0, 0.04, reference=True), _view(80.0, -0.03, behind_only=True),
             _view(-50.0, -0.03, behind_only=True)]
    end = hair_end_from_views(v, f, views)
    # the lowest vertices under hair: within the mesh's spacing (~5 mm) and a pixel's footprint
    assert end is not None and -0.036 < end < -0.022
    # lower hair, lower end
    end2 = hair_end_from_views(v, f, [views[0], _view(80.0, -0.05, behind_only=True)])
    assert end2 < end - 0.01


def test_no_turned_view_or_no_hair_gives_no_end(sphere):
    v, f = sphere
    ref = _view(0.0, 0.04, reference=True)
    assert hair_end_from_views(v, f, [ref]) is None
    assert hair_end_from_views(v, f, [ref, _view(80.0, 1.0)]) is None      # no hair at all
    unlabelled = _view(80.0, -0.03)
    assert hair_end_from_views(v, f, [ref, View(unlabelled.image, unlabelled.camera, None)]) is None
