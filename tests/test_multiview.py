"""Multi-view pieces of the video build (`recon.multiview`) on cases whose answer is known."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.multiview import (REFERENCE_WEIGHT, View, blend_colours, camera_centre, keyframe_cameras,
                                       pose_matrix, silhouette_outside, view_samples)
from avatarkit.render.camera import Camera

from helpers import splat_plane

SIZE = 64


@pytest.fixture(scope="module")
def planes():
    """A back plane (z = 0, x in [-0.1, 0.1]) and a front plane (z = 0.05) covering its left
    half; normals +Z; cameras on +Z."""
    back = splat_plane(0.0, (-0.1, 0.1), (0.2, 0.4, 0.9))
    front = splat_plane(0.05, (-0.1, 0.0), (0.9, 0.3, 0.1))
    both = GaussianSet.concat([back, front])
    normals = np.tile([0.0, 0.0, 1.0], (len(both), 1))
    return back, front, both, normals


def _image(colour):
    return np.tile((np.asarray(colour) * 255).astype(np.uint8), (SIZE, SIZE, 1))


def test_occluded_gaussians_are_not_seen_and_weights_follow_the_angle(planes):
    back, front, both, normals = planes
    head_on = Camera.look_at((0.0, 0.0, 0.8), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)
    s = view_samples(both, normals, View(_image((0.5, 0.5, 0.5)), head_on, None, 1.0))
    nb = len(back)
    bx = back.means[:, 0]
    # the front plane is seen; the back plane only where the front one does not cover it
    inner_front = np.abs(front.means[:, 0] + 0.05) < 0.04
    assert s.seen[nb:][inner_front].all()
    assert not s.seen[:nb][bx < -0.02].any()
    assert s.seen[:nb][(bx > 0.02) & (bx < 0.08) & (np.abs(back.means[:, 1]) < 0.08)].all()
    # weight = cos^2 of the angle to the normal x sharpness
    c = camera_centre(head_on)
    d = c[None] - both.means
    cos = d[:, 2] / np.linalg.norm(d, axis=1)
    np.testing.assert_allclose(s.weight[s.seen], cos[s.seen] ** 2, rtol=1e-5)
    np.testing.assert_allclose(s.colour[s.seen], 0.5, atol=0.01)
    # a camera 60 degrees off the normal: weights ~cos(60)^2 = 0.25; sharpness scales them
    side = Camera.look_at((0.8 * np.sin(np.radians(60)), 0.0, 0.8 * np.cos(np.radians(60))), (0, 0, 0),
                          width=SIZE, height=SIZE, fov_deg=40)
    s2 = view_samples(both, normals, View(_image((0.5, 0.5, 0.5)), side, None, 0.5))
    assert s2.seen.any()
    assert np.all(np.abs(s2.weight[s2.seen] - 0.5 * 0.25) < 0.05)
    # the reference view weighs REFERENCE_WEIGHT times more
    s3 = view_samples(both, normals, View(_image((0.5, 0.5, 0.5)), head_on, None, 1.0, reference=True))
    np.testing.assert_allclose(s3.weight, REFERENCE_WEIGHT * s.weight, rtol=1e-6)


def test_grazing_views_give_no_sample(planes):
    _, _, both, normals = planes
    grazing = Camera.look_at((0.8, 0.0, 0.05), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)
    s = view_samples(both, normals, View(_image((0.5, 0.5, 0.5)), grazing, None, 1.0))
    assert not s.seen.any()


def test_blend_is_the_weighted_mean_and_keeps_unseen_and_kept():
    from avatarkit.recon.multiview import Samples

    cur = np.full((4, 3), 0.1, np.float32)
    a = Samples(np.array([1, 1, 0, 1], bool), np.array([1.0, 3.0, 0, 1.0]), np.full((4, 3), 0.2, np.float32))
    b = Samples(np.array([1, 0, 0, 1], bool), np.array([3.0, 0, 0, 1.0]), np.full((4, 3), 0.6, np.float32))
    out, seen = blend_colours(cur, [a, b], keep=np.array([0, 0, 0, 1], bool))
    np.testing.assert_allclose(out[:, 0], [0.5, 0.2, 0.1, 0.1], atol=1e-6)
    assert seen.tolist() == [True, True, False, False]


def test_keyframe_cameras_register_poses_to_the_build_camera():
    from avatarkit.recon.fit import view_camera

    build_rot, build_t = np.array([0.02, -0.05, 0.01]), np.array([0.0, -0.03, -0.62])
    ref_rot, ref_t = np.array([0.03, -0.04, 0.0]), np.array([0.004, -0.03, -0.6])
    build = view_camera(build_rot, build_t, 320, 240)
    mb, mr = pose_matrix(build_rot, build_t), pose_matrix(ref_rot, ref_t)
    turn = pose_matrix(np.array([0.0, 0.5, 0.0]), np.zeros(3)) @ mr      # the head turned 0.5 rad
    cams = keyframe_cameras(build, mb, mr, [mr, turn])
    np.testing.assert_allclose(cams[0].world_to_camera, build.world_to_camera, atol=1e-9)
    # the turned view sees the avatar's point p where the reference saw R_turn-rotated p
    p = np.array([[0.03, 0.05, 0.08]])
    q = (np.linalg.inv(mr) @ mb @ np.append(p[0], 1))[:3]                 # p in the joint fit's head frame
    want = (np.diag([1, -1, -1]) @ (turn @ np.append(q, 1))[:3])
    got = (cams[1].world_to_camera @ np.append(p[0], 1))[:3]
    np.testing.assert_allclose(got, want, atol=1e-9)


def test_silhouette_counts_views_where_a_point_falls_outside_the_person():
    from avatarkit.recon.segment import BACKGROUND, SKIN

    cam = Camera.look_at((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)
    labels = np.full((SIZE, SIZE), BACKGROUND, np.int32)
    labels[16:48, 16:48] = SKIN
    pts = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [5.0, 0.0, 0.0]])   # centre, outside, off-image
    img = _image((0.5, 0.5, 0.5))
    views = [View(img, cam, labels), View(img, cam, labels), View(img, cam, None)]
    assert silhouette_outside(pts, views).tolist() == [0, 2, 0]


def test_hidden_hair_takes_the_colour_of_the_nearest_seen_hair():
    from avatarkit.recon.multiview import fill_hidden_hair

    means = np.array([[0.0, 0, 0], [0.01, 0, 0], [1.0, 0, 0], [1.01, 0, 0], [0.005, 0.001, 0], [1.004, 0, 0]])
    colours = np.array([[1, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [0, 1, 0]], np.float32)
    source = np.array([1, 1, 1, 1, 0, 0], bool)
    target = np.array([0, 0, 0, 0, 1, 1], bool)
    out, n = fill_hidden_hair(means, colours, source, target, k=2)
    assert n == 2
    np.testing.assert_allclose(out[4], [1, 0, 0])
    np.testing.assert_allclose(out[5], [0, 0, 1])
    np.testing.assert_allclose(out[:4], colours[:4])


def test_refine_over_the_reference_view_alone_is_refine_colours():
    """The multi-view colour matching with one (reference) view is the single-view one."""
    from avatarkit.recon.assemble import refine_colours
    from avatarkit.recon.multiview import refine_colours_views
    from avatarkit.recon.segment import BACKGROUND, SKIN

    rng = np.random.default_rng(1)
    gs = splat_plane(0.0, (-0.1, 0.1), (0.5, 0.5, 0.5))
    gs = gs.with_colors(rng.random((len(gs), 3)).astype(np.float32))
    cam = Camera.look_at((0.0, 0.0, 0.8), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)
    photo = (rng.random((SIZE, SIZE, 3)) * 255).astype(np.uint8)
    labels = np.full((SIZE, SIZE), BACKGROUND, np.int32)
    labels[12:52, 12:52] = SKIN
    normals = np.tile([0.0, 0.0, 1.0], (len(gs), 1))
    a, fa = refine_colours(gs, cam, photo, labels == SKIN, iterations=3)
    b, fb = refine_colours_views(gs, normals, [View(photo, cam, labels, 0.7, reference=True)], iterations=3)
    np.testing.assert_allclose(b.colors, a.colors, atol=1e-5)
    assert fb["psnr_after"] == pytest.approx(fa["psnr_after"], abs=1e-3)
    assert fb["psnr_after"] > fb["psnr_before"]


def _noisy(shape, colour, rng):
    """(shape, 3) uint8 around an RGB colour in [0, 255] (a little noise: the colour models
    need a spread)."""
    return np.clip(np.asarray(colour, np.float64) + rng.normal(0, 4, (*shape, 3)), 0, 255).astype(np.uint8)


def _reference(n, skin_rgb, hair_rgb, wall_rgb, rng):
    """A reference photo n x n and its labels: skin on the left half, hair on the right half of
    a band (rows 20:60), wall elsewhere."""
    from avatarkit.recon.segment import BACKGROUND, HAIR, SKIN

    ref = _noisy((n, n), wall_rgb, rng)
    ref_labels = np.full((n, n), BACKGROUND)
    ref[20:60, 10:45], ref_labels[20:60, 10:45] = _noisy((40, 35), skin_rgb, rng), SKIN
    ref[20:60, 45:80], ref_labels[20:60, 45:80] = _noisy((40, 35), hair_rgb, rng), HAIR
    return ref, ref_labels


def test_turned_keyframe_head_is_relabelled_by_the_reference_colours():
    """A keyframe whose segmentation called the hair at the back of the head "body" and lost
    part of it to the background (what a portrait segmentation does to a turned head): within
    reach of the head the reference's colour models put hair and skin back; the clothes, the
    wall and everything far from the head keep their labels."""
    from avatarkit.recon.multiview import reference_colours, relabel_head
    from avatarkit.recon.segment import BACKGROUND, BODY, HAIR, SKIN

    rng = np.random.default_rng(0)
    skin_rgb, hair_rgb, wall_rgb, shirt_rgb = (220, 170, 140), (70, 45, 25), (245, 245, 245), (40, 90, 200)
    n = 96
    # the reference: skin on the left half, hair on the right half of a band, wall elsewhere
    ref, ref_labels = _reference(n, skin_rgb, hair_rgb, wall_rgb, rng)
    # the keyframe: face 20:60 x 20:50, hair 20:60 x 50:70 (labelled body, its outer part
    # background), a shirt below the head (body), the wall; a far dark patch at the corner
    img = _noisy((n, n), wall_rgb, rng)
    labels = np.full((n, n), BACKGROUND)
    img[20:60, 20:50], labels[20:60, 20:50] = _noisy((40, 30), skin_rgb, rng), SKIN
    img[20:60, 50:70] = _noisy((40, 20), hair_rgb, rng)
    labels[20:60, 50:62] = BODY
    img[60:80, 20:70], labels[60:80, 20:70] = _noisy((20, 50), shirt_rgb, rng), BODY
    img[85:95, 85:95] = _noisy((10, 10), hair_rgb, rng)
    # shadowed hair the segmentation lost, like neither model: the person's, of unknown part
    img[10:20, 40:60] = _noisy((10, 20), (25, 15, 8), rng)
    head = np.zeros((n, n), bool)
    head[22:58, 22:66] = True
    out = relabel_head(labels, img, head, reference_colours(ref, ref_labels))
    assert (out[22:58, 52:68] == HAIR).mean() > 0.95
    assert (out[22:58, 22:48] == SKIN).mean() > 0.95
    assert (out[60:80, 20:70] == BODY).all()        # within reach, but neither skin- nor hair-coloured
    assert (out[17:20, 42:58] == BODY).all() and (out[10:15, 40:60] == BACKGROUND).all()   # out of reach
    assert (out[:10] == BACKGROUND).all() and (out[85:95, 85:95] == BACKGROUND).all()
    # a reference without hair (a bald subject) gives no hair model: nothing changes
    assert reference_colours(ref, np.where(ref_labels == HAIR, BODY, ref_labels)) is None
    np.testing.assert_array_equal(relabel_head(labels, img, head, None), labels)


def test_strands_hanging_beyond_the_reach_are_relabelled_when_connected():
    """`relabel_head(connected=)` (`RELABEL_CONNECTED`): a strand two pixels wide hanging from
    the hair 12 px beyond the fitted head (past `RELABEL_REACH`, 6 px at 96) is the person's
    hair when it connects to the head's person pixels, up to `connected` of the image (14 px
    at 0.15) and no further; a dark patch as far out that touches nothing stays background,
    and without `connected` the strand is cut at the reach."""
    from avatarkit.recon.multiview import reference_colours, relabel_head
    from avatarkit.recon.segment import BACKGROUND, HAIR, SKIN

    rng = np.random.default_rng(1)
    skin_rgb, hair_rgb, wall_rgb = (220, 170, 140), (40, 30, 25), (245, 245, 245)
    n = 96
    ref, ref_labels = _reference(n, skin_rgb, hair_rgb, wall_rgb, rng)
    # a profile frame without a face for the segmentation: every pixel background
    img = _noisy((n, n), wall_rgb, rng)
    img[20:50, 20:45] = _noisy((30, 25), skin_rgb, rng)
    img[20:50, 45:60] = _noisy((30, 15), hair_rgb, rng)
    img[50:70, 56:58] = _noisy((20, 2), hair_rgb, rng)        # the strand: rows 50..69, 0..19 px below the head
    img[56:62, 30:36] = _noisy((6, 6), hair_rgb, rng)         # a detached patch 6..11 px below the head
    labels = np.full((n, n), BACKGROUND)
    head = np.zeros((n, n), bool)
    head[20:50, 20:60] = True
    colours = reference_colours(ref, ref_labels)
    cut = relabel_head(labels, img, head, colours)
    assert (cut[50:55, 56:58] == HAIR).all() and (cut[58:70, 56:58] == BACKGROUND).all()
    out = relabel_head(labels, img, head, colours, connected=0.15)
    assert (out[50:63, 56:58] == HAIR).all()                  # to 12 px below the head
    assert (out[65:70, 56:58] == BACKGROUND).all()            # beyond 14 px
    assert (out[56:62, 30:36] == BACKGROUND).all()            # not connected
    assert (out[:18] == BACKGROUND).all() and (out[:, 64:] == BACKGROUND).all()


def test_colours_only_other_keyframes_saw_are_put_back_after_the_reference_refine():
    """`VideoViews.keep_view_colours`: the Gaussians the blend coloured from other keyframes
    only get those colours back, found by their centres in sets that gained and lost rows in
    between (the silhouette cover); every other row keeps what the refine gave it."""
    from avatarkit.recon.multiview import VideoViews

    rng = np.random.default_rng(1)
    bald = splat_plane(0.0, (-0.1, 0.1), (0.5, 0.5, 0.5))
    hair = splat_plane(0.05, (-0.1, 0.0), (0.2, 0.2, 0.2))
    vv = VideoViews(np.zeros(3), [])
    both = GaussianSet.concat([bald, hair])
    pick = rng.random(len(both)) < 0.3
    target = rng.random((int(pick.sum()), 3)).astype(np.float32)
    bald_c, hair_c, _ = vv.keep_view_colours(bald, hair)          # nothing stored yet: unchanged
    np.testing.assert_array_equal(bald_c.sh, bald.sh)
    vv._only_others = (both.means[pick], target)
    # in between: the refine changed every colour, the cover dropped the first bald row and
    # appended a new one
    refined_bald = bald.with_colors(np.full((len(bald), 3), 0.9, np.float32)).subset(np.arange(1, len(bald)))
    refined_bald = GaussianSet.concat([refined_bald, splat_plane(0.2, (0.0, 0.0), (0.9, 0.9, 0.9))])
    refined_hair = hair.with_colors(np.full((len(hair), 3), 0.9, np.float32))
    out_bald, out_hair, n = vv.keep_view_colours(refined_bald, refined_hair)
    expect = np.full((len(both), 3), 0.9, np.float32)
    expect[pick] = target
    got = np.concatenate([out_bald.colors[:len(bald) - 1], out_hair.colors])
    np.testing.assert_allclose(got, np.concatenate([expect[1:len(bald)], expect[len(bald):]]), atol=1e-5)
    assert n == int(pick[1:].sum())
    np.testing.assert_allclose(out_bald.colors[len(bald) - 1:], 0.9, atol=1e-5)


def test_the_neck_the_reference_does_not_show_is_left_to_the_blend(planes):
    """`neck_kept` (`NECK_SHOWN`): of the neck's rows, those the reference camera shows keep the
    portrait's colour; those hidden behind the front plane do not; rows off the neck never do.
    Then `blend_colours` gives the hidden ones the other view's colour and leaves the shown ones."""
    from avatarkit.recon.multiview import Samples, neck_kept

    back, front, both, normals = planes
    nb = len(back)
    head_on = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    neck = np.ones(len(both), bool)
    bx = back.means[:, 0]
    neck[:nb][bx > 0.05] = False                                     # part of the open back: not neck
    kept = neck_kept(neck, both, head_on, 0.05)
    assert kept[nb:].all()                                           # the front plane: shown
    assert not kept[:nb][bx < -0.02].any()                           # behind the front plane: hidden
    assert kept[:nb][(bx > 0.02) & (bx < 0.05) & (np.abs(back.means[:, 1]) < 0.08)].all()
    assert not kept[~neck].any()
    assert not neck_kept(np.zeros(len(both), bool), both, head_on, 0.05).any()
    # the blend: every row seen by a view of colour 0.7; kept rows stay at 0.2
    current = np.full((len(both), 3), 0.2, np.float32)
    s = Samples(np.ones(len(both), bool), np.ones(len(both)), np.full((len(both), 3), 0.7, np.float32))
    out, _ = blend_colours(current, [s], kept)
    np.testing.assert_allclose(out[kept], 0.2)
    np.testing.assert_allclose(out[~kept], 0.7, atol=1e-6)


def test_body_pixels_on_the_head_are_sampled_only_by_the_rows_allowed_and_not_in_the_reference(planes):
    """`view_samples(body=)` (`SCALP_BODY`): a keyframe whose right half is labelled body (the
    shadowed hair a portrait segmentation calls body) gives the bald Gaussians there no sample,
    unless they are allowed the body pixels and the body lies on the view's fitted head; the
    reference view never lends them; the samples are the body pixels' colour."""
    from avatarkit.recon.segment import BODY, SKIN

    back, _, _, _ = planes
    normals = np.tile([0.0, 0.0, 1.0], (len(back), 1))
    cam = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    img = _image((0.8, 0.6, 0.5))
    img[:, SIZE // 2:] = (np.array([0.2, 0.1, 0.05]) * 255).astype(np.uint8)
    labels = np.full((SIZE, SIZE), SKIN, np.int32)
    labels[:, SIZE // 2:] = BODY
    head = np.ones((SIZE, SIZE), bool)
    x = back.means[:, 0]
    right = (x > 0.02) & (x < 0.08) & (np.abs(back.means[:, 1]) < 0.08)
    allowed = np.ones(len(back), bool)
    plain = view_samples(back, normals, View(img, cam, labels, 1.0, head=head))
    assert not plain.seen[right].any()
    with_body = view_samples(back, normals, View(img, cam, labels, 1.0, head=head), body=allowed)
    assert with_body.seen[right].all()
    np.testing.assert_allclose(with_body.colour[right], np.tile([0.2, 0.1, 0.05], (int(right.sum()), 1)), atol=0.01)
    np.testing.assert_array_equal(with_body.seen[x < -0.02], plain.seen[x < -0.02])
    # only the rows allowed; not where the body is off the fitted head; not in the reference
    half = allowed & (back.means[:, 1] > 0)
    some = view_samples(back, normals, View(img, cam, labels, 1.0, head=head), body=half)
    assert some.seen[right & half].all() and not some.seen[right & ~half].any()
    off_head = view_samples(back, normals, View(img, cam, labels, 1.0, head=np.zeros_like(head)), body=allowed)
    assert not off_head.seen[right].any()
    ref = view_samples(back, normals, View(img, cam, labels, 1.0, reference=True, head=head), body=allowed)
    assert not ref.seen[right].any()


def _grey_and_dark_views():
    """Two views from +Z: a grey reference and a dark keyframe; -> (views, the colour their blend
    gives a Gaussian both see face-on)."""
    cam = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    dark = (0.2, 0.1, 0.05)
    views = [View(_image((0.5, 0.5, 0.5)), cam, None, 1.0, reference=True), View(_image(dark), cam, None, 1.0)]
    return views, (REFERENCE_WEIGHT * 0.5 + np.asarray(dark)) / (REFERENCE_WEIGHT + 1)


def _turned_planes(planes):
    """The planes fixture as a bald layer in one fill colour (no hair), its back plane's part at x >
    0.035 turned to face +X: -> (back, bald, hair, fill, nb, x (nb,), normals (N, 3), turned (nb,))."""
    back, front, _, _ = planes
    fill = (0.8, 0.6, 0.5)
    bald = GaussianSet.concat([back, front]).with_colors(np.tile(np.float32(fill), (len(back) + len(front), 1)))
    hair = front.subset(np.zeros(len(front), bool))
    nb = len(back)
    x = back.means[:, 0]
    normals = np.tile([0.0, 0.0, 1.0], (len(bald), 1))
    turned = x > 0.035
    normals[:nb][turned] = [1.0, 0.0, 0.0]
    return back, bald, hair, fill, nb, x, normals, turned


def test_the_scalp_no_view_saw_takes_the_colour_of_the_seen_scalp_where_the_reference_looks_away(planes):
    """`colour_from_views(scalp=)` (`SCALP_FILL`): the back plane is scalp, the front plane (its
    left half's cover) is not. Two views on +Z, grey reference and a dark keyframe: the back
    plane's open strip facing +Z is seen (their blend); its right part, turned to face +X, no
    view sees and the reference looks away from it: it takes the seen scalp's blend instead of
    keeping the portrait's fill. The back plane behind the front one faces the reference (only
    hidden) keeps the fill, and so does the turned part off the scalp, as every row does without
    `scalp`."""
    from avatarkit.recon.multiview import colour_from_views

    back, bald, hair, fill, nb, x, normals, turned = _turned_planes(planes)
    open_strip = (x > 0.015) & (x < 0.035)
    behind = x < -0.02
    off_scalp = turned & (back.means[:, 1] > 0.045)                  # turned away too, but not scalp
    turned &= ~off_scalp
    scalp = np.zeros(len(bald), bool)
    scalp[:nb] = ~off_scalp
    views, blend = _grey_and_dark_views()

    plain, _, _ = colour_from_views(bald, hair, views, normals)
    filled, _, figures = colour_from_views(bald, hair, views, normals, scalp=scalp)
    pc, fc = plain.colors[:nb], filled.colors[:nb]
    np.testing.assert_allclose(fc[open_strip], np.tile(blend, (int(open_strip.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(pc[open_strip], fc[open_strip])
    np.testing.assert_allclose(pc[turned], np.tile(fill, (int(turned.sum()), 1)), atol=1e-3)
    np.testing.assert_allclose(fc[turned], np.tile(blend, (int(turned.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(fc[behind], np.tile(fill, (int(behind.sum()), 1)), atol=1e-3)
    np.testing.assert_allclose(fc[off_scalp], np.tile(fill, (int(off_scalp.sum()), 1)), atol=1e-3)
    assert figures["hidden_scalp_filled"] == int(turned.sum())
    # rows off the scalp are never filled: the front plane is seen and blended the same either way
    np.testing.assert_allclose(filled.colors[nb:], plain.colors[nb:])
    # none of it without seen scalp to fill from
    only_turned = np.zeros(len(bald), bool)
    only_turned[:nb] = turned
    _, _, f2 = colour_from_views(bald, hair, views, normals, scalp=only_turned)
    assert f2["hidden_scalp_filled"] == 0


def test_the_neck_no_view_saw_takes_the_colour_of_the_neck_that_has_one(planes):
    """`colour_from_views(neck=)` (`NECK_FILL`): the back plane is neck, the front plane (its left
    half's cover) is not. Two views on +Z, grey reference and a dark keyframe: the back plane's
    open strip facing +Z is seen (their blend); its right part, turned to face +X (the neck's
    side and back), no view sees: it takes the seen neck's blend instead of keeping the
    portrait's fill, and so does the neck hidden behind the front plane. The turned part facing
    down (the neck's cut end, `NECK_FILL_DOWN`) keeps the fill, as every row does without
    `neck`; the front plane (not neck) is blended the same either way. Kept rows (the neck the
    reference shows, `NECK_SHOWN`) keep their colour and lend it."""
    from avatarkit.recon.multiview import colour_from_views

    back, front, _, _ = planes
    fill = (0.8, 0.6, 0.5)
    bald = GaussianSet.concat([back, front]).with_colors(np.tile(np.float32(fill), (len(back) + len(front), 1)))
    hair = front.subset(np.zeros(len(front), bool))
    nb = len(back)
    x, y = back.means[:, 0], back.means[:, 1]
    normals = np.tile([0.0, 0.0, 1.0], (len(bald), 1))
    turned = x > 0.035
    under = turned & (y < -0.06)                                     # facing down: the cut end
    side = turned & ~under
    normals[:nb][side] = [1.0, 0.0, 0.0]
    normals[:nb][under] = [0.0, -1.0, 0.0]
    open_strip = (x > 0.015) & (x < 0.035)
    behind = x < -0.02
    neck = np.zeros(len(bald), bool)
    neck[:nb] = True
    views, blend = _grey_and_dark_views()

    plain, _, _ = colour_from_views(bald, hair, views, normals)
    filled, _, figures = colour_from_views(bald, hair, views, normals, neck=neck)
    pc, fc = plain.colors[:nb], filled.colors[:nb]
    np.testing.assert_allclose(fc[open_strip], np.tile(blend, (int(open_strip.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(pc[open_strip], fc[open_strip])
    np.testing.assert_allclose(pc[side], np.tile(fill, (int(side.sum()), 1)), atol=1e-3)
    np.testing.assert_allclose(fc[side], np.tile(blend, (int(side.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(fc[behind], np.tile(blend, (int(behind.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(fc[under], np.tile(fill, (int(under.sum()), 1)), atol=1e-3)
    assert figures["hidden_neck_filled"] >= int(side.sum() + behind.sum())
    np.testing.assert_allclose(filled.colors[nb:], plain.colors[nb:])
    # kept rows (the open strip, in the photo's own colour) keep it and lend it to the unseen neck
    photo = np.float32([0.3, 0.6, 0.3])
    rgb = bald.colors.copy()
    rgb[:nb][open_strip] = photo
    keep = np.zeros(len(bald), bool)
    keep[:nb] = open_strip
    kept, _, _ = colour_from_views(bald.with_colors(rgb), hair, views, normals, keep=keep, neck=neck)
    kc = kept.colors[:nb]
    np.testing.assert_allclose(kc[open_strip], np.tile(photo, (int(open_strip.sum()), 1)), atol=1e-5)
    np.testing.assert_allclose(kc[side], np.tile(photo, (int(side.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(kc[under], np.tile(fill, (int(under.sum()), 1)), atol=1e-3)


def test_the_registration_drafts_do_not_fill_the_neck(monkeypatch):
    """`VideoViews.fills_neck`: with `NECK_FILL` the final build fills the neck no view saw, a
    draft the video build registers against (info["draft"]) does not (the default since session
    27); off, neither."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    assert final.fills_neck() and not draft.fills_neck()
    monkeypatch.setattr(multiview, "NECK_FILL", False)
    assert not final.fills_neck() and not draft.fills_neck()


def test_the_registration_drafts_keep_the_coverage_of_the_wall_coloured_skin():
    """`VideoViews.covers_plate`: the final build's coverage leaves the skin pixels that continue
    the known wall without discs (`coverage.COVER_PLATE`), a draft the video build registers
    against (info["draft"]) covers them as before."""
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    assert final.covers_plate() and not draft.covers_plate()


def test_the_registration_drafts_sample_the_body_pixels_beside_the_wall(monkeypatch):
    """`VideoViews.fringes_wall`: on by default (`BODY_WALL_FRINGE` 0.01), the final build's
    keyframes give no sample from the body pixels beside the known wall's colours, a draft the
    video build registers against (info["draft"]) samples them as before unless
    `BODY_WALL_FRINGE_IN_DRAFTS`."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    assert final.fringes_wall() and not draft.fringes_wall()
    monkeypatch.setattr(multiview, "BODY_WALL_FRINGE", None)
    assert not final.fringes_wall() and not draft.fringes_wall()
    monkeypatch.setattr(multiview, "BODY_WALL_FRINGE", 0.01)
    monkeypatch.setattr(multiview, "BODY_WALL_FRINGE_IN_DRAFTS", True)
    assert final.fringes_wall() and draft.fringes_wall()


def test_the_registration_drafts_do_not_fill_the_scalp(monkeypatch):
    """`VideoViews.fills_scalp`: the final build fills (`SCALP_FILL`), a draft the video build
    registers against (info["draft"]) does not unless `DRAFT_SCALP_FILL`; off, neither does."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    # by default the final build fills and its drafts do not (session 22: with the bald layer's
    # holes filled, `bald_discs.HOLE_ALPHA`, the filled scalp no longer shows through the face)
    assert final.fills_scalp() and not draft.fills_scalp()
    monkeypatch.setattr(multiview, "SCALP_FILL", True)
    monkeypatch.setattr(multiview, "DRAFT_SCALP_FILL", False)
    assert final.fills_scalp() and not draft.fills_scalp()
    monkeypatch.setattr(multiview, "DRAFT_SCALP_FILL", True)
    assert final.fills_scalp() and draft.fills_scalp()
    monkeypatch.setattr(multiview, "SCALP_FILL", False)
    assert not final.fills_scalp() and not draft.fills_scalp()


def test_the_registration_drafts_keep_the_hair_the_clear_votes_would_take_out(monkeypatch):
    """`VideoViews.clears_hair`: the final build lets the keyframes' clear votes take hair out
    (`hair_reassign.CLEAR_SHARE`); a draft the turned keyframes register against does not
    unless `hair_reassign.CLEAR_IN_DRAFTS`."""
    from avatarkit.recon import hair_reassign
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    assert final.clears_hair() and not draft.clears_hair()
    monkeypatch.setattr(hair_reassign, "CLEAR_IN_DRAFTS", True)
    assert final.clears_hair() and draft.clears_hair()


def test_hair_the_reference_shows_edge_on_and_the_keyframes_see_on_skin_is_dropped(planes, monkeypatch):
    """`colour_from_views(drop_skin_hair=)` (`EDGE_HAIR_ON_SKIN`): a plane of hair, a reference and
    a keyframe on +Z; the keyframe's upper half is labelled skin, its lower half hair (the
    reference's all hair). The plane's
    right part has its normal turned to +X (the reference sees it edge-on): there the hair the
    keyframe sees on skin is dropped and the hair it sees on hair kept; the left part, which
    the reference faces, is kept on skin too. Nothing is dropped without drop_skin_hair or with
    the switch None; a registration draft does not drop (`VideoViews.drops_skin_hair`)."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import VideoViews, colour_from_views
    from avatarkit.recon.segment import HAIR, SKIN

    back, _, _, _ = planes
    hair = back.with_colors(np.tile(np.float32([0.3, 0.2, 0.1]), (len(back), 1)))
    bald = back.subset(np.zeros(len(back), bool))
    x, y = back.means[:, 0], back.means[:, 1]
    inner = (np.abs(x) < 0.08) & (np.abs(y) < 0.08)
    normals = np.tile([0.0, 0.0, 1.0], (len(hair), 1))
    turned = x > 0.0
    normals[turned] = [1.0, 0.0, 0.0]
    cam = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    labels = np.full((SIZE, SIZE), HAIR, np.int32)
    labels[:SIZE // 2] = SKIN
    py = np.asarray(cam.project(back.means)[0])[:, 1]
    on_skin, on_hair = py < SIZE // 2 - 3, py > SIZE // 2 + 3
    assert (inner & turned & on_skin).sum() > 20 and (inner & turned & on_hair).sum() > 20
    # the reference labels it all hair (its label reaches over the temples it sees edge-on): its
    # labels are not counted, the keyframes' are
    views = [View(_image((0.5, 0.5, 0.5)), cam, np.full((SIZE, SIZE), HAIR, np.int32), 1.0, reference=True),
             View(_image((0.8, 0.6, 0.5)), cam, labels, 1.0)]
    key = lambda m: {tuple(p) for p in np.round(np.asarray(m, np.float64), 9)}

    monkeypatch.setattr(multiview, "EDGE_HAIR_ON_SKIN", 0.5)
    _, out, figures = colour_from_views(bald, hair, views, normals, drop_skin_hair=True)
    left = key(out.means)
    assert not key(back.means[inner & turned & on_skin]) & left                  # dropped
    assert key(back.means[inner & turned & on_hair]) <= left                     # kept: seen on hair
    assert key(back.means[inner & ~turned & on_skin]) <= left                    # kept: the reference faces it
    assert figures["edge_hair_on_skin_dropped"] == len(hair) - len(out)
    _, kept, f_kept = colour_from_views(bald, hair, views, normals)
    assert len(kept) == len(hair) and f_kept["edge_hair_on_skin_dropped"] == 0
    monkeypatch.setattr(multiview, "EDGE_HAIR_ON_SKIN", None)
    _, off, _ = colour_from_views(bald, hair, views, normals, drop_skin_hair=True)
    assert len(off) == len(hair)
    assert not VideoViews(np.zeros(3), []).drops_skin_hair()
    monkeypatch.setattr(multiview, "EDGE_HAIR_ON_SKIN", 0.5)
    assert VideoViews(np.zeros(3), []).drops_skin_hair()
    assert not VideoViews(np.zeros(3), [], {"draft": True}).drops_skin_hair()


def test_body_pixels_in_the_known_walls_colours_give_no_sample_in_a_turned_keyframe(planes, monkeypatch):
    """`BODY_WALL`: a turned keyframe whose right half is labelled body shows there the poster
    (top: the known wall's red) and shadowed hair (bottom: a brown the wall has nowhere). The
    bald rows allowed the body pixels (`SCALP_BODY`) and the hair rows (renderer visibility)
    take the brown and never the red; with the rule off both take the red; the skin half and
    the reference view are sampled as before."""
    from avatarkit.recon import multiview
    from avatarkit.recon.segment import BODY, SKIN
    from avatarkit.track.background_plate import Plate

    back, _, _, _ = planes
    normals = np.tile([0.0, 0.0, 1.0], (len(back), 1))
    cam = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    red, brown, skin = np.array([0.8, 0.15, 0.12]), np.array([0.2, 0.1, 0.05]), np.array([0.8, 0.6, 0.5])
    img = _image(skin)
    img[: SIZE // 2, SIZE // 2:] = (red * 255).astype(np.uint8)
    img[SIZE // 2:, SIZE // 2:] = (brown * 255).astype(np.uint8)
    labels = np.full((SIZE, SIZE), SKIN, np.int32)
    labels[:, SIZE // 2:] = BODY
    # the plate knows the poster's red in a band at the frame's top, nothing else
    colour = np.zeros((SIZE, SIZE, 3), np.uint8)
    colour[:12] = (red * 255).astype(np.uint8)
    support = np.zeros((SIZE, SIZE), np.int32)
    support[:12] = 10
    plate = Plate(colour, support, support.copy(), 20)
    wall = multiview.wall_palette_pixels(plate, img)
    assert wall[: SIZE // 2, SIZE // 2:].all() and not wall[SIZE // 2:].any() and not wall[:, : SIZE // 2].any()
    assert multiview.wall_palette_pixels(None, img) is None

    x, y = back.means[:, 0], back.means[:, 1]
    # the camera's image y grows downwards: the top half of the image is y > 0 in the world
    poster = (x > 0.02) & (x < 0.08) & (y > 0.02) & (y < 0.08)
    shadow = (x > 0.02) & (x < 0.08) & (y < -0.02) & (y > -0.08)
    face = (x < -0.02) & (x > -0.08) & (np.abs(y) < 0.08)
    assert poster.any() and shadow.any()
    allowed = np.ones(len(back), bool)

    def view(reference=False):
        v = View(img, cam, labels, 1.0, reference=reference, head=np.ones((SIZE, SIZE), bool))
        v.info["wall_coloured"] = wall
        return v

    for kw in (dict(body=allowed), dict(hair=allowed)):
        s = view_samples(back, normals, view(), **kw)
        assert not s.seen[poster].any()
        assert s.seen[shadow].all() and s.seen[face].all()
        np.testing.assert_allclose(s.colour[shadow], np.tile(brown, (int(shadow.sum()), 1)), atol=0.01)
        monkeypatch.setattr(multiview, "BODY_WALL", False)
        off = view_samples(back, normals, view(), **kw)
        monkeypatch.setattr(multiview, "BODY_WALL", True)
        assert off.seen[poster].all()
        np.testing.assert_allclose(off.colour[poster], np.tile(red, (int(poster.sum()), 1)), atol=0.01)
        far = (x < -0.01) | (y < -0.01)                     # away from the poster quadrant
        np.testing.assert_array_equal(off.seen[far], s.seen[far])
        np.testing.assert_array_equal(off.weight[far], s.weight[far])
    # the reference view's pixels are the portrait's: the rule leaves them alone
    ref = view_samples(back, normals, view(reference=True), hair=allowed)
    assert ref.seen[poster].all()


def test_body_pixels_beside_the_wall_a_turned_keyframe_shows_give_no_sample(planes, monkeypatch):
    """`BODY_WALL_FRINGE`: a turned keyframe whose right half is labelled body shows the poster
    (the known wall's red) above, three rows of the head's outline blended with it (a colour neither
    the wall's palette nor the head's) and shadowed hair below. The blended rows give no sample
    to any layer (with the rule off both layers take its colour); the hair below, the skin half
    (beside the poster too: only body pixels) and the reference view are sampled as before. A white wall labelled background above the same
    rows (a plain wall: no body pixel in its colours) leaves every sample as it was."""
    from avatarkit.recon import multiview
    from avatarkit.recon.segment import BACKGROUND, BODY, SKIN
    from avatarkit.track.background_plate import Plate

    back, _, _, _ = planes
    normals = np.tile([0.0, 0.0, 1.0], (len(back), 1))
    cam = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    red, blend, brown = np.array([0.8, 0.15, 0.12]), np.array([0.55, 0.3, 0.2]), np.array([0.2, 0.1, 0.05])
    edge = 30                                               # the blended rows: 30-32
    img = _image((0.8, 0.6, 0.5))
    img[:edge, SIZE // 2:] = (red * 255).astype(np.uint8)
    img[edge:edge + 3, SIZE // 2:] = (blend * 255).astype(np.uint8)
    img[edge + 3:, SIZE // 2:] = (brown * 255).astype(np.uint8)
    labels = np.full((SIZE, SIZE), SKIN, np.int32)
    labels[:, SIZE // 2:] = BODY
    colour = np.zeros((SIZE, SIZE, 3), np.uint8)
    colour[:8] = (red * 255).astype(np.uint8)               # the plate knows the poster's top
    support = np.zeros((SIZE, SIZE), np.int32)
    support[:8] = 10
    wall = multiview.wall_palette_pixels(Plate(colour, support, support.copy(), 20), img)
    assert wall[:edge, SIZE // 2:].all() and not wall[edge:].any()

    px, _ = cam.project(back.means)
    ix = np.floor(np.asarray(px)).astype(int)
    right = ix[:, 0] >= SIZE // 2 + 2
    py = np.asarray(px)[:, 1]
    fringe = right & (py >= edge + 0.5) & (py <= edge + 2.5)     # bilinear: the blend alone
    below = right & (py >= edge + 4)
    skin = ix[:, 0] < SIZE // 2 - 2
    beside = (ix[:, 0] == SIZE // 2 - 2) & (py < edge - 2)     # skin 2 px from the poster
    assert fringe.any() and below.any() and skin.any() and beside.any()
    allowed = np.ones(len(back), bool)

    def samples(image, lab, wall_coloured, rule, reference=False, **kw):
        monkeypatch.setattr(multiview, "BODY_WALL_FRINGE", rule)
        v = View(image, cam, lab, 1.0, reference=reference, head=np.ones((SIZE, SIZE), bool))
        v.info["wall_coloured"] = wall_coloured
        return view_samples(back, normals, v, **kw)

    for kw in (dict(body=allowed), dict(hair=allowed)):
        # 0.05 of 64 px: the three rows beside the red
        on, off = samples(img, labels, wall, 0.05, **kw), samples(img, labels, wall, None, **kw)
        assert not on.seen[fringe].any()
        assert off.seen[fringe].all()
        np.testing.assert_allclose(off.colour[fringe], np.tile(blend, (int(fringe.sum()), 1)), atol=0.01)
        for rows in (below, skin, beside):                 # only body pixels are the wall's fringe
            assert on.seen[rows].all()
            np.testing.assert_array_equal(on.weight[rows], off.weight[rows])
        np.testing.assert_allclose(on.colour[below], np.tile(brown, (int(below.sum()), 1)), atol=0.01)
    # the reference view's pixels are the portrait's: the rule leaves them alone
    assert samples(img, labels, wall, 0.05, reference=True, hair=allowed).seen[fringe].all()
    # ...and so does a view that says so (a registration draft's, `VideoViews.fringes_wall`)
    monkeypatch.setattr(multiview, "BODY_WALL_FRINGE", 0.05)
    v = View(img, cam, labels, 1.0, head=np.ones((SIZE, SIZE), bool), info={"wall_coloured": wall, "wall_fringe": False})
    assert view_samples(back, normals, v, hair=allowed).seen[fringe].all()

    # a plain white wall, labelled background, above the same blended rows and hair (the
    # person's outline there: `person_weight` weighs the blend down as it should)
    white = img.copy()
    white[:edge, SIZE // 2:] = 255
    plain = labels.copy()
    plain[:edge, SIZE // 2:] = BACKGROUND
    colour[:8] = 255
    wall = multiview.wall_palette_pixels(Plate(colour, support, support.copy(), 20), white)
    assert wall[:edge, SIZE // 2:].all()
    for kw in (dict(body=allowed), dict(hair=allowed)):
        on, off = samples(white, plain, wall, 0.05, **kw), samples(white, plain, wall, None, **kw)
        np.testing.assert_array_equal(on.seen, off.seen)
        np.testing.assert_array_equal(on.weight, off.weight)
        assert on.seen[below].all()


def test_the_bald_layer_no_view_saw_off_the_neck_takes_the_seen_bald_colour_where_the_reference_looks_away(planes):
    """`colour_from_views(hidden_bald=)` (`HIDDEN_BALD_FILL`): two views on +Z, a grey reference
    and a dark keyframe. The back plane's right part, turned to face +X (the side of a head
    behind the ear), no view sees and the reference looks away from it: it takes the blend of
    the seen bald rows beside it instead of keeping the portrait's fill. The back plane behind
    the front one faces the reference (only hidden) and keeps the fill; so does the turned part
    left out of `hidden_bald` (the neck), and every row without it. The turned rows lie outside
    the reference camera's picture; left where its camera shows them (if only edge-on, at the
    photo's outline: `HIDDEN_BALD_SHOWN`) they keep the fill too. Rows the scalp fill took are
    left to it."""
    from avatarkit.recon.multiview import colour_from_views

    back, bald, hair, fill, nb, x, normals, turned = _turned_planes(planes)
    behind = x < -0.02
    neck = turned & (back.means[:, 1] > 0.045)                       # turned away too, but left out
    turned &= ~neck
    rows = np.ones(len(bald), bool)
    rows[:nb] &= ~neck
    views, blend = _grey_and_dark_views()
    # shown by the reference camera (in its picture, facing +Z): not filled
    _, _, shown = colour_from_views(bald, hair, views, normals, hidden_bald=rows)
    assert shown["hidden_bald_filled"] == 0
    # the turned rows moved out of the picture (the side of the head the photo does not show)
    means = np.asarray(bald.means, np.float64).copy()
    means[:nb][turned | neck] += [0.5, 0.0, 0.0]
    bald = bald.replace(means=means.astype(np.asarray(bald.means).dtype))

    plain, _, f0 = colour_from_views(bald, hair, views, normals)
    filled, _, figures = colour_from_views(bald, hair, views, normals, hidden_bald=rows)
    pc, fc = plain.colors[:nb], filled.colors[:nb]
    np.testing.assert_allclose(pc[turned], np.tile(fill, (int(turned.sum()), 1)), atol=1e-3)
    np.testing.assert_allclose(fc[turned], np.tile(blend, (int(turned.sum()), 1)), atol=0.02)
    np.testing.assert_allclose(fc[behind], np.tile(fill, (int(behind.sum()), 1)), atol=1e-3)
    np.testing.assert_allclose(fc[neck], np.tile(fill, (int(neck.sum()), 1)), atol=1e-3)
    np.testing.assert_allclose(fc[~turned], pc[~turned])                # the rest as without it
    np.testing.assert_allclose(filled.colors[nb:], plain.colors[nb:])
    assert figures["hidden_bald_filled"] == int(turned.sum()) and f0["hidden_bald_filled"] == 0
    # the scalp's own fill comes first: the rows it filled are not filled again
    scalp = np.zeros(len(bald), bool)
    scalp[:nb] = ~neck
    _, _, f2 = colour_from_views(bald, hair, views, normals, scalp=scalp, hidden_bald=rows)
    assert f2["hidden_scalp_filled"] == int(turned.sum()) and f2["hidden_bald_filled"] == 0


def test_the_registration_drafts_do_not_fill_the_hidden_bald_layer(monkeypatch):
    """`VideoViews.fills_hidden_bald`: off by default; on, the final build fills and a draft the
    video build registers against (info["draft"]) does not."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    assert not final.fills_hidden_bald() and not draft.fills_hidden_bald()
    monkeypatch.setattr(multiview, "HIDDEN_BALD_FILL", True)
    assert final.fills_hidden_bald() and not draft.fills_hidden_bald()


def _hair_plane_views(lit=(0.85, 0.65, 0.55), brown=(0.36, 0.24, 0.15), turn=75.0, reference=True):
    """A hair plane (the fixture's back plane, normals +Z) seen by a reference on +Z whose image is
    brown and by a keyframe turned `turn` degrees about Y, which looks along the plane and whose
    image is lit skin (the hair's outline over the temple): -> (hair, normals, views, cos of the
    turned camera per Gaussian)."""
    hair = splat_plane(0.0, (-0.1, 0.1), (0.5, 0.5, 0.5))
    normals = np.tile([0.0, 0.0, 1.0], (len(hair), 1))
    front = Camera.look_at((0.0, 0.0, 0.8), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    t = np.radians(turn)
    side = Camera.look_at((0.8 * np.sin(t), 0.0, 0.8 * np.cos(t)), (0, 0, 0), width=SIZE, height=SIZE, fov_deg=40)
    views = [View(_image(brown), front, None, 1.0, reference=reference), View(_image(lit), side, None, 1.0)]
    d = camera_centre(side)[None] - hair.means
    cos = d[:, 2] / np.linalg.norm(d, axis=1)
    return hair, normals, views, cos


def test_hair_samples_are_weighted_by_facing_the_view_only_when_asked():
    """`view_samples(hair_facing=)` (`HAIR_FACING`): a hair row's weight is its footprint's
    visibility x min(1, max(cos / hair_facing, HAIR_FACING_FLOOR)) ^ COS_POWER, cos to the camera
    along the head's outward normal: a view facing the shell (cos over the knee) keeps the
    visibility alone, one looking along it is weighed down, to the floor at most; the seen set does
    not change (the floor keeps every visible hair Gaussian a sample), the bald rows' weights do not
    change, and without it the weight is the visibility alone."""
    from avatarkit.recon.multiview import COS_POWER, HAIR_FACING_FLOOR

    hair, normals, views, cos = _hair_plane_views(turn=80.0)
    is_hair = np.ones(len(hair), bool)
    plain = view_samples(hair, normals, views[1], hair=is_hair)
    faced = view_samples(hair, normals, views[1], hair=is_hair, hair_facing=0.5)
    assert plain.seen.sum() > 50
    np.testing.assert_array_equal(plain.seen, faced.seen)
    s = plain.seen
    factor = np.clip(cos[s] / 0.5, HAIR_FACING_FLOOR, 1.0) ** COS_POWER
    np.testing.assert_allclose(faced.weight[s], plain.weight[s] * factor, rtol=1e-6)
    assert np.all(faced.weight[s] < 0.2 * plain.weight[s])       # (cos(80 deg) / 0.5)^2 = 0.12
    # the view facing the plane (cos ~1, over the knee) is not weighed down
    front = view_samples(hair, normals, views[0], hair=is_hair)
    front_faced = view_samples(hair, normals, views[0], hair=is_hair, hair_facing=0.5)
    np.testing.assert_allclose(front_faced.weight, front.weight, rtol=1e-6)
    # a knee past every cos: the floor's square, for every row alike
    floor = view_samples(hair, normals, views[1], hair=is_hair, hair_facing=100.0)
    np.testing.assert_allclose(floor.weight[s], HAIR_FACING_FLOOR ** COS_POWER * plain.weight[s], rtol=1e-6)
    # bald rows (hair=False) are weighted by cos^2 whatever hair_facing says
    bald_plain = view_samples(hair, normals, views[1], hair=np.zeros(len(hair), bool))
    bald_faced = view_samples(hair, normals, views[1], hair=np.zeros(len(hair), bool), hair_facing=0.5)
    np.testing.assert_array_equal(bald_plain.weight, bald_faced.weight)


def test_the_hair_a_keyframe_sees_along_the_shell_takes_the_colour_the_facing_view_shows():
    """`colour_from_views(hair_facing=)`: the hair plane seen face-on in brown by one keyframe and
    along its shell in lit skin by another turned 80 degrees (neither the reference, whose weight
    would lead either way). By visibility alone the blend is pulled well toward
    the skin; weighted by facing it stays near the brown the facing view shows (median within
    0.05, a third of the pull or less), every hair row both see at least twice as near as by
    visibility alone; the seen counts are the same."""
    from avatarkit.recon.multiview import colour_from_views

    brown = np.float32([0.36, 0.24, 0.15])
    hair, normals, views, _ = _hair_plane_views(brown=tuple(brown), reference=False, turn=80.0)
    bald = hair.subset(np.zeros(len(hair), bool))
    _, plain, fp = colour_from_views(bald, hair, views, normals)
    _, faced, ff = colour_from_views(bald, hair, views, normals, hair_facing=0.5)
    assert fp["per_view"] == ff["per_view"] and fp["seen"] == ff["seen"]
    both = view_samples(hair, normals, views[0], hair=np.ones(len(hair), bool)).seen & \
        view_samples(hair, normals, views[1], hair=np.ones(len(hair), bool)).seen
    assert both.sum() > 50
    off_plain = np.abs(plain.colors[both] - brown).max(axis=1)
    off_faced = np.abs(faced.colors[both] - brown).max(axis=1)
    assert np.median(off_plain) > 0.15
    assert np.median(off_faced) < min(0.05, np.median(off_plain) / 3)
    assert np.all(off_faced < 0.5 * off_plain)


def test_the_registration_drafts_weigh_the_hairs_samples_by_visibility_alone(monkeypatch):
    """`VideoViews.hair_facing`: `HAIR_FACING` in the final build, None in a draft the video
    build registers its turned keyframes against (info["draft"]) and when the switch is None."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import VideoViews

    final, draft = VideoViews(np.zeros(3), []), VideoViews(np.zeros(3), [], {"draft": True})
    monkeypatch.setattr(multiview, "HAIR_FACING", 0.5)
    assert final.hair_facing() == 0.5 and draft.hair_facing() is None
    monkeypatch.setattr(multiview, "HAIR_FACING", None)
    assert final.hair_facing() is None and draft.hair_facing() is None


def test_hair_the_reference_sees_along_its_shell_little_of_it_shown_keeps_the_facing_blend(monkeypatch):
    """With `hair_facing` the hair rows the reference sees at a grazing angle (cos < MIN_COS) of
    whose footprint its camera shows under `HAIR_FACING_SHOWN` join the rows that keep the blend's
    colour after the photo's matching (figures["_only_others"], `VideoViews.keep_view_colours`):
    the hair plane seen by the reference turned 75 degrees (its image the outline's light colour)
    and face-on by a brown keyframe. Kept: exactly the rows the reference saw with under 0.2 of
    their footprint shown, in the blend's colour, nearer the brown than the light; the rows it shows more of (the
    plane's near edge) are not; without hair_facing, or with HAIR_FACING_SHOWN 0, none is."""
    from avatarkit.recon import multiview
    from avatarkit.recon.multiview import colour_from_views, footprint_visibility

    brown = np.float32([0.36, 0.24, 0.15])
    hair, normals, views, _ = _hair_plane_views(brown=tuple(brown), turn=75.0, reference=False)
    side, front = views[1], views[0]
    views = [View(side.image, side.camera, None, 1.0, reference=True), front]
    bald = hair.subset(np.zeros(len(hair), bool))
    by_ref = view_samples(hair, normals, views[0], hair=np.ones(len(hair), bool)).seen
    shown = footprint_visibility(hair, views[0].camera)
    little = by_ref & (shown < multiview.HAIR_FACING_SHOWN)
    assert little.sum() > 50 and (by_ref & ~little).sum() > 5

    def kept(**kw):
        _, out, figures = colour_from_views(bald, hair, views, normals, **kw)
        means, colours = figures["_only_others"]
        mask = np.zeros(len(hair), bool)
        if len(means):
            from scipy.spatial import cKDTree

            dist, _ = cKDTree(np.asarray(means, np.float64)).query(np.asarray(hair.means, np.float64))
            mask = dist < 1e-7
        return mask, out, colours, figures

    mask, out, colours, figures = kept(hair_facing=0.5)
    np.testing.assert_array_equal(mask & by_ref, little)
    assert figures["hair_grazed_kept"] == int(little.sum())
    np.testing.assert_allclose(colours, out.colors[mask], atol=1e-6)
    light = np.float32([0.85, 0.65, 0.55])                           # the reference's image
    assert np.median(np.abs(out.colors[little] - brown).max(axis=1)) < 0.5 * np.abs(light - brown).max()
    assert not (kept()[0] & by_ref).any()
    monkeypatch.setattr(multiview, "HAIR_FACING_SHOWN", 0.0)
    assert not (kept(hair_facing=0.5)[0] & by_ref).any()
