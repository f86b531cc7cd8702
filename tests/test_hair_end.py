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


def _first_hits(cam, size: int):
    """The sphere seen by cam at size x size pixels: (first hit points (size, size, 3), hit
    (size, size) bool)."""
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    r = cam.rotation
    d = ((xs[..., None] - cam.cx) / cam.fx) * r[0] + ((ys[..., None] - cam.cy) / cam.fy) * r[1] + r[2]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.asarray(cam.camera_center, np.float64)
    b = d @ c
    disc = b ** 2 - (c @ c - R ** 2)
    return c + (-b - np.sqrt(np.maximum(disc, 0)))[..., None] * d, disc > 0


def _labels(cam, hair_from: float, behind_only: bool = False) -> np.ndarray:
    """(SIZE, SIZE) labels of the sphere seen by cam: hair where the first hit lies above
    hair_from (and behind the centre, z < 0, when behind_only), skin elsewhere on it."""
    p, on = _first_hits(cam, SIZE)
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


def test_connected_hair_keeps_the_body_of_hair_and_bridges_small_gaps():
    from avatarkit.recon.hair_end import connected_hair

    hair = np.zeros((100, 100), bool)
    hair[10:40, 20:80] = True            # the body of the hair
    hair[41:60, 30:34] = True            # a streak 1 px below it (a gap the segmentation left)
    hair[80:84, 50:53] = True            # a speck on the neck, 20 px below
    kept = connected_hair(hair)
    assert kept[10:40, 20:80].all() and kept[41:60, 30:34].all()
    assert not kept[80:84, 50:53].any()
    assert not connected_hair(np.zeros((8, 8), bool)).any()


def _with_speck(view, y_from, y_to, where):
    """The view's labels plus hair on the sphere's points p between heights y_from and y_to
    where where(p, towards the camera) holds."""
    cam = view.camera
    p, on = _first_hits(cam, view.labels.shape[0])
    c = np.asarray(cam.camera_center, np.float64)
    speck = on & (p[..., 1] > y_from) & (p[..., 1] < y_to) & where(p, c / np.linalg.norm(c))
    return View(view.image, cam, np.where(speck, HAIR, view.labels).astype(np.int32), 1.0, 0, False)


def test_a_speck_of_hair_apart_from_the_hair_does_not_lower_the_end(sphere):
    v, f = sphere
    ref = _view(0.0, 0.04, reference=True)
    turned = _view(80.0, 0.0, behind_only=True)
    end = hair_end_from_views(v, f, [ref, turned])
    assert end is not None and -0.008 < end < 0.006
    # the segmentation's spill: a speck low on the front (the neck's shaded edge)
    specked = _with_speck(turned, -0.05, -0.04, lambda p, c: p @ c > 0.6 * R)
    assert (specked.labels == HAIR).sum() > (turned.labels == HAIR).sum() + 5
    assert abs(hair_end_from_views(v, f, [ref, specked]) - end) < 1e-9


def test_only_the_back_of_the_head_counts(sphere):
    from avatarkit.recon.hair_end import back_of_head

    v, f = sphere
    ref = _view(0.0, 0.04, reference=True)
    # hair over the whole sphere above -0.03: its front (the face's side) reaches as low
    turned = _view(80.0, -0.03)
    everywhere = hair_end_from_views(v, f, [ref, turned])
    # the back: vertices behind a "face" region made of the front cap (z > 0.3 R)
    face = np.flatnonzero(v[:, 2] > 0.3 * R)
    neck = np.flatnonzero(v[:, 1] < -0.6 * R)
    back = back_of_head(v, {"face": face, "neck": neck})
    assert back.sum() > 0 and not back[face].any() and not back[neck].any()
    assert np.all(v[back, 2] < v[face, 2].min())
    behind = hair_end_from_views(v, f, [ref, turned], back)
    assert -0.036 < everywhere < -0.022 and -0.036 < behind < -0.022
    # hair that only reaches low on the face's side: the back's end stays where its own hair ends
    low_front = _with_speck(_view(80.0, 0.0), -0.045, 0.001, lambda p, c: p[..., 2] > 0.35 * R)
    assert hair_end_from_views(v, f, [ref, low_front]) < -0.035
    assert -0.01 < hair_end_from_views(v, f, [ref, low_front], back) < 0.006
    # the template head: the back of the head is the scalp's back and the skin behind the ears
    from avatarkit.head.model import HeadModel

    model = HeadModel.template()
    tb = back_of_head(model.v_template, model.regions)
    assert not tb[model.regions["neck"]].any() and not tb[model.regions["face"]].any()
    assert tb[model.regions["scalp"]].sum() > 0.3 * len(model.regions["scalp"])
