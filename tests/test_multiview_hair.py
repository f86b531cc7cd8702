"""The video build's hair colours from several views (`recon.multiview`) on cases whose answer is
known: the renderer's visibility of a Gaussian, the soft person mask that keeps background out
of the samples, and a two-coloured head of hair recovered from the views that see each colour."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.multiview import (HAIR_VISIBLE, View, colour_from_views, footprint_visibility, person_weight,
                                       soft_person)
from avatarkit.recon.segment import BACKGROUND, HAIR, SKIN
from avatarkit.render.camera import Camera
from avatarkit.rotations import matrix_to_quat

SIZE = 96
DARK = np.array([0.15, 0.10, 0.05], np.float32)
LIGHT = np.array([0.85, 0.70, 0.40], np.float32)
SKIN_RGB = np.array([0.80, 0.60, 0.50], np.float32)


def _shell(n: int, radius: float, min_y: float, scale: tuple[float, float, float], opacity: float):
    """n tangent discs on a sphere of `radius` at the origin, above y = min_y (a Fibonacci
    spiral: evenly spread), and their outward normals."""
    i = np.arange(n) + 0.5
    y = 1.0 - 2.0 * i / n
    keep = y * radius >= min_y
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    r = np.sqrt(1.0 - y * y)
    d = np.stack([r * np.cos(phi), y, r * np.sin(phi)], 1)[keep]
    t = np.cross(d, [0.0, 1.0, 0.0])
    t[np.linalg.norm(t, axis=1) < 1e-6] = [1.0, 0.0, 0.0]
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    rot = np.stack([t, np.cross(d, t), d], axis=2)
    m = len(d)
    gs = GaussianSet.from_colors(radius * d, matrix_to_quat(rot), np.tile(scale, (m, 1)), np.full(m, opacity),
                                 np.zeros((m, 3), np.float32))
    return gs, d


@pytest.fixture(scope="module")
def head():
    """A skin sphere (r = 9 cm) under a hair shell (r = 10 cm, above the ears' height): hair
    dark in front (z > 0, toward the front camera), light behind."""
    bald, nb = _shell(1800, 0.09, -1.0, (0.006, 0.006, 0.0008), 0.99)
    hair, nh = _shell(2400, 0.10, -0.02, (0.005, 0.005, 0.0008), 0.95)
    bald = bald.with_colors(np.tile(SKIN_RGB, (len(bald), 1)))
    truth = np.where(hair.means[:, 2:3] > 0, DARK, LIGHT).astype(np.float32)
    return bald, hair, truth, np.concatenate([nb, nh])


def _views(bald, hair_true, azimuths):
    from avatarkit.recon.label_lifting import render_label_images
    from avatarkit.render import render

    truth = GaussianSet.concat([bald, hair_true])
    labels = np.r_[np.full(len(bald), SKIN), np.full(len(hair_true), HAIR)]
    views = []
    for k, az in enumerate(azimuths):
        cam = Camera.orbit((0.0, 0.0, 0.0), az, 10.0, 0.6, 40.0, SIZE, SIZE)
        img = (np.clip(render(truth, cam, background=(1.0, 1.0, 1.0)).rgb, 0, 1) * 255).round().astype(np.uint8)
        lab = render_label_images(truth, labels, [cam], n_labels=4, background_label=BACKGROUND)[0]
        views.append(View(img, cam, lab, 1.0, k, k == 0))
    return views


def test_footprint_visibility_matches_each_gaussian_rendered_alone():
    """The own-footprint term is each Gaussian's alpha summed over the image when it is
    rendered alone (the slow reference); in front of nothing, well inside the image, it reads
    ~1; behind an opaque sheet, ~0; half behind it, ~0.5; outside the region, 0."""
    from avatarkit.render import project_gaussians, render

    rng = np.random.default_rng(3)
    n = 12
    means = np.c_[rng.uniform(-0.03, 0.03, (n, 2)), rng.uniform(-0.02, 0.02, n)]
    scales = rng.uniform(0.002, 0.006, (n, 3))
    quats = rng.normal(size=(n, 4))
    gs = GaussianSet.from_colors(means, quats, scales, rng.uniform(0.5, 0.95, n), np.zeros((n, 3)))
    cam = Camera.look_at((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=30)
    alone = np.array([render(gs.subset(np.array([i])), cam).alpha.sum() for i in range(n)])
    # each alone (no overlap): the ratio of its composited weight to the formula is its
    # rendered alpha sum over the formula; the two agree within 6 % (pixel sampling, the
    # 1/255 cut and the 0.99 clamp)
    for i in range(n):
        one = gs.subset(np.array([i]))
        v = footprint_visibility(one, cam)[0]
        c = np.asarray(project_gaussians(one, cam).conics, np.float64)[0]
        own = float(one.opacities[0]) * 2 * np.pi / np.sqrt(c[0] * c[2] - c[1] ** 2)
        assert abs(alone[i] / own - 1.0) < 0.06
        assert v > 0.94
    # an opaque sheet in front of the left half of a Gaussian at the centre
    target = GaussianSet.from_colors(np.zeros((1, 3)), np.array([[1.0, 0, 0, 0]]), np.array([[0.01, 0.01, 0.001]]),
                                     np.array([0.9]), np.zeros((1, 3)))
    xs, ys = np.meshgrid(np.arange(-0.06, 0.0, 0.002), np.arange(-0.06, 0.061, 0.002))
    m = xs.size
    sheet = GaussianSet.from_colors(np.c_[xs.ravel() - 0.001, ys.ravel(), np.full(m, 0.05)],
                                    np.tile([1.0, 0, 0, 0], (m, 1)), np.tile([0.0015, 0.0015, 0.0005], (m, 1)),
                                    np.full(m, 0.99), np.zeros((m, 3)))
    v = footprint_visibility(GaussianSet.concat([target, sheet]), cam)
    assert 0.4 < v[0] < 0.6
    behind = GaussianSet.concat([target.replace(means=np.array([[-0.03, 0.0, 0.0]])), sheet])
    assert footprint_visibility(behind, cam)[0] < 0.01
    region = np.zeros((SIZE, SIZE), bool)
    region[:, :10] = True
    assert footprint_visibility(target, cam, region)[0] == 0.0
    assert footprint_visibility(target, cam, ~region)[0] > 0.94


def test_soft_person_drops_a_background_coloured_halo_but_not_a_light_patch_inside():
    """A segmentation whose hair label runs 4 px out into a white background: the soft mask
    puts the silhouette back at the head's edge; a white patch inside the head (not touching
    the background) stays the person's; samples on the true edge weigh ~0, inside 1."""
    yy, xx = np.mgrid[:SIZE, :SIZE]
    r = np.hypot(xx + 0.5 - SIZE / 2, yy + 0.5 - SIZE / 2)
    img = np.full((SIZE, SIZE, 3), 255, np.uint8)
    img[r < 30] = (110, 70, 40)
    img[np.hypot(xx - 48, yy - 40) < 4] = 255                     # a white patch inside
    labels = np.full((SIZE, SIZE), BACKGROUND, np.int32)
    labels[r < 33] = HAIR                                         # 3 px of halo
    labels[r < 22] = SKIN
    plain = soft_person(labels)
    clean = soft_person(labels, img)
    assert plain[r < 32].min() > 0.5                              # without the image: the halo is person
    assert clean[(r > 31) & (r < 33)].max() < 0.5                 # with it: background
    assert clean[r < 28].min() > 0.5                              # the head, the white patch included
    edge = np.array([[48 + 30.0, 48.0]])
    inside = np.array([[48 + 20.0, 48.0]])
    assert person_weight(labels, edge, img)[0] < 0.1
    assert person_weight(labels, inside, img)[0] == pytest.approx(1.0)
    assert person_weight(labels, np.array([[np.nan, 0.0]]), img)[0] == 0.0


def test_two_coloured_hair_is_recovered_from_the_views_that_see_each_colour(head):
    """Hair dark in front and light behind, starting one grey (the single view's guess): views
    from the front and +-70 degrees colour the hair each sees, the fill gives hair no view saw
    the colour of the hair around it: front hair comes out dark, back hair light."""
    bald, hair, truth, normals = head
    views = _views(bald, hair.with_colors(truth), (0.0, 70.0, -70.0))
    grey = hair.with_colors(np.full((len(hair), 3), 0.5, np.float32))
    _, out, fig = colour_from_views(bald, grey, views, normals)
    got = out.colors
    z = hair.means[:, 2]
    front, back = z > 0.03, z < -0.03
    err = np.abs(got - truth).max(axis=1)
    # measured: median error 0.003 front / 0.002 back, every one below 0.15, 1140 of 1440
    # hair Gaussians seen (a shell whose discs overlap ~3 deep: most show only in part)
    assert np.median(err[front]) < 0.05
    assert np.median(err[back]) < 0.05
    assert np.mean(err[front | back] < 0.15) > 0.95
    assert fig["hair_seen"] > 0.6 * len(hair)
    # the front view alone would not do: back hair then takes the front's colour (measured 0.70)
    _, only_front, _ = colour_from_views(bald, grey, views[:1], normals)
    assert np.median(np.abs(only_front.colors - truth).max(axis=1)[back]) > 0.3


def test_hair_visibility_needs_a_footprint_share(head):
    """Hair the front camera sees only behind the front hair's layer is not a sample: its
    renderer visibility is below HAIR_VISIBLE."""
    bald, hair, truth, normals = head
    views = _views(bald, hair.with_colors(truth), (0.0,))
    both = GaussianSet.concat([bald, hair])
    vis = footprint_visibility(both, views[0].camera)
    back = hair.means[:, 2] < -0.03
    assert (vis[len(bald):][back] < HAIR_VISIBLE).all()
    # the hair facing the camera: each disc shows about a third of itself between the
    # neighbours over it (measured median 0.32), far above the hidden ones
    facing = hair.means[:, 2] > 0.08
    assert np.median(vis[len(bald):][facing]) > 0.2


def test_a_hole_in_a_keyframes_segmentation_removes_no_hair_where_the_head_is():
    """The silhouette bound joins each keyframe's person mask with the fitted head it sees
    (eroded by the margin): a hole in the segmentation over the face removes nothing there,
    a point outside both the person and the head is still outside."""
    from avatarkit.recon.multiview import head_silhouette, silhouette_outside

    cam = Camera.look_at((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)
    # the "head": a square 0.3 m wide at z = 0 (two triangles) covers its projection
    verts = np.array([[-0.15, -0.15, 0.0], [0.15, -0.15, 0.0], [0.15, 0.15, 0.0], [-0.15, 0.15, 0.0]])
    head = head_silhouette(verts, np.array([[0, 1, 2], [0, 2, 3]]), cam)
    px, _ = cam.project(verts)
    x, y = px[:, 0], px[:, 1]
    area = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))   # shoelace
    assert abs(head.sum() - area) < 0.05 * area
    labels = np.zeros((SIZE, SIZE), np.int32)
    labels[head] = SKIN
    labels[40:56, 40:56] = BACKGROUND                              # a hole in the middle
    img = np.full((SIZE, SIZE, 3), 200, np.uint8)
    img[labels == BACKGROUND] = 255
    pts = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])             # in the hole; outside everything
    assert silhouette_outside(pts, [View(img, cam, labels)]).tolist() == [1, 1]
    assert silhouette_outside(pts, [View(img, cam, labels, head=head)]).tolist() == [0, 1]
