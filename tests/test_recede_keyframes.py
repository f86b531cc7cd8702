"""The bald layer's outline set in by the keyframes' silhouettes (`multiview.recede_outline`,
`RECEDE_KEYFRAMES`): a bald disc whose blending weight falls on the wall in enough of the
keyframes that show it moves inward along its face's normal. Cases with a known answer: a sphere
of discs on its surface (their outline stands 1.8 px past the sphere at 192 px: many discs
stacked along the line of sight) seen by three cameras whose person masks are the true sphere's
silhouette set in until their outline is within about half a pixel of it; a truth made of the same
discs (its silhouette overshoots as they do) leaves them where they are."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import bald_discs, multiview
from avatarkit.recon.multiview import View, head_silhouette, recede_outline
from avatarkit.recon.segment import SKIN
from avatarkit.render import render
from avatarkit.render.camera import Camera
from helpers import uv_sphere

DISTANCE = 0.78        # the synthetic benchmark's camera distance: ~2.2 mm pixels at 192 px
RADIUS = 0.05
WIDTH = 192


@pytest.fixture(autouse=True)
def on(monkeypatch):
    # rounds enough to reach the fixed point (the build's default stops after a pixel)
    monkeypatch.setattr(multiview, "RECEDE_KEYFRAMES", True)
    monkeypatch.setattr(multiview, "RECEDE_ROUNDS", 10)
    monkeypatch.setattr(bald_discs, "INSET", None)


@pytest.fixture(scope="module")
def sphere():
    return _sphere_bald()


def _sphere_bald():
    """The sphere (V, 3), (F, 3) and its bald discs drawn as `sample_bald` draws them (a face-sized
    disc, opacity 0.95-1), with their host faces in extras["binding"]."""
    v, faces = uv_sphere(RADIUS)
    tri = v[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n = int(round(area.sum() / (np.pi * 0.0038 ** 2)))
    rng = np.random.default_rng(0)
    ids = rng.choice(len(faces), size=n, p=area / area.sum())
    share = np.full(len(faces), area.sum() / n)
    pts, quats, scales, normals = bald_discs._discs_on(v, faces, ids, share[ids], rng)
    pts, quats, scales, ids, _ = bald_discs.fill_holes(v, faces, area, share, (pts, quats, scales, ids, normals),
                                                       rng.spawn(1)[0])
    bald = GaussianSet.from_colors(pts.astype(np.float32), quats.astype(np.float32), scales.astype(np.float32),
                                   rng.uniform(0.95, 1.0, len(pts)).astype(np.float32),
                                   np.full((len(pts), 3), 0.5, np.float32), extras={"binding": ids.astype(np.int64)})
    return v, faces, bald


def _camera(yaw_deg: float) -> Camera:
    a = math.radians(yaw_deg)
    return Camera.look_at((DISTANCE * math.sin(a), 0.0, DISTANCE * math.cos(a)), (0.0, 0.0, 0.0), fov_deg=30.0,
                          width=WIDTH, height=WIDTH)


CAMERAS = [_camera(y) for y in (0.0, 60.0, -60.0)]


def _overshoot(bald, cam: Camera) -> float:
    """How far (px) the render's alpha-0.5 outline lies beyond the sphere's circle (the circle of
    the same area as the alpha > 0.5 pixels)."""
    alpha = np.asarray(render(bald.replace(extras={}), cam, (1.0, 1.0, 1.0)).alpha)
    return math.sqrt((alpha > 0.5).sum() / math.pi) - cam.fy * math.tan(math.asin(RADIUS / DISTANCE))


def _fit(v, faces, scalp=None):
    """A fit of the sphere; scalp (V,) bool: the head model's "scalp" region (None: no regions)."""
    regions = {} if scalp is None else {"scalp": np.flatnonzero(scalp)}
    return SimpleNamespace(rest_vertices=v, model=SimpleNamespace(faces=faces, regions=regions,
                                                                  region_mask=lambda name: scalp))


def _views(masks) -> list[View]:
    return [View(np.zeros((WIDTH, WIDTH, 3), np.uint8), cam, np.where(m, SKIN, 0).astype(np.int32))
            for cam, m in zip(CAMERAS, masks)]


def test_discs_over_the_true_silhouette_set_in_until_their_outline_is_on_it(sphere, monkeypatch):
    v, faces, bald = sphere
    fit = _fit(v, faces)
    views = _views([head_silhouette(v, faces, cam) for cam in CAMERAS])
    before = [_overshoot(bald, cam) for cam in CAMERAS]
    moved, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
    after = [_overshoot(moved, cam) for cam in CAMERAS]
    # on the surface 1.8 px out; set in, within 0.6 px (the front camera's outline, whose discs
    # every camera shows, within 0.1: a disc on a side camera's outline the two others show
    # inside, 1 vote in 3, is just at the quorum)
    assert min(before) > 1.5, before
    assert max(abs(a) for a in after) < 0.6 and min(b - a for b, a in zip(before, after)) > 1.2, (before, after)
    # the build's default rounds stop RECEDE_ROUNDS x RECEDE_STEP pixels in
    monkeypatch.setattr(multiview, "RECEDE_ROUNDS", 2)
    short, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    step = multiview.RECEDE_STEP * bald_discs.camera_pixel(CAMERAS[0], np.asarray(bald.means, np.float64))
    reach = np.linalg.norm(np.asarray(short.means, np.float64) - np.asarray(bald.means, np.float64), axis=1)
    assert reach.max() <= 2 * step * 1.001 and (reach > 1.5 * step).any()
    # each moved disc straight inward along its face's normal, nothing else changed
    shift = np.asarray(moved.means, np.float64) - np.asarray(bald.means, np.float64)
    depth = np.linalg.norm(shift, axis=1)
    assert (depth > 0).any(), figures
    radial = np.einsum("nc,nc->n", shift, np.asarray(bald.means, np.float64)) / np.linalg.norm(bald.means, axis=1)
    assert (radial[depth > 0] < -0.9 * depth[depth > 0]).all()
    np.testing.assert_array_equal(moved.quats, bald.quats)
    np.testing.assert_array_equal(moved.extras["binding"], bald.extras["binding"])


def test_a_truth_that_overshoots_as_the_discs_do_leaves_them(sphere):
    v, faces, bald = sphere
    fit = _fit(v, faces)
    views = _views([np.asarray(render(bald.replace(extras={}), cam, (1.0, 1.0, 1.0)).alpha) > 0.5 for cam in CAMERAS])
    moved, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
    before = [_overshoot(bald, cam) for cam in CAMERAS]
    after = [_overshoot(moved, cam) for cam in CAMERAS]
    assert max(b - a for b, a in zip(before, after)) < 0.25, (before, after, figures)


def test_the_drafts_and_the_switch_off_leave_the_outline(sphere, monkeypatch):
    views = multiview.VideoViews(np.zeros(1), [], {"draft": True})
    assert not views.recedes()
    views.info["draft"] = False
    assert views.recedes()
    monkeypatch.setattr(multiview, "RECEDE_KEYFRAMES", False)
    assert not views.recedes()


def test_the_keyframes_vote_at_the_outline_stages_poses(monkeypatch):
    from test_keyframe_refine import _outline_scene

    fit, vv, views, _ = _outline_scene()
    monkeypatch.setattr(multiview, "RECEDE_OUTLINE_POSES", True)
    got = vv.recede_views(fit, views)
    want = vv.outline_views(fit, views)
    np.testing.assert_allclose(got[1].camera.world_to_camera, want[1].camera.world_to_camera, atol=1e-12)
    assert not np.allclose(got[1].camera.world_to_camera, views[1].camera.world_to_camera, atol=1e-3)
    monkeypatch.setattr(multiview, "RECEDE_OUTLINE_POSES", False)
    assert vv.recede_views(fit, views) is views


def test_the_scalp_stays_under_the_hair(sphere, monkeypatch):
    # the sphere's upper half a scalp: its discs stay on the surface, the rest set in as before
    v, faces, bald = sphere
    scalp = v[:, 1] > 0.0
    views = _views([head_silhouette(v, faces, cam) for cam in CAMERAS])
    monkeypatch.setattr(multiview, "RECEDE_SCALP", False)
    moved, _ = recede_outline(bald, GaussianSet.empty(), views, _fit(v, faces, scalp))
    depth = np.linalg.norm(np.asarray(moved.means, np.float64) - np.asarray(bald.means, np.float64), axis=1)
    on_scalp = scalp[faces].any(axis=1)[bald.extras["binding"]]
    assert (depth[on_scalp] == 0).all() and (depth[~on_scalp] > 0).sum() > 50
    monkeypatch.setattr(multiview, "RECEDE_SCALP", True)
    every, _ = recede_outline(bald, GaussianSet.empty(), views, _fit(v, faces, scalp))
    assert (np.linalg.norm(np.asarray(every.means) - np.asarray(bald.means), axis=1)[on_scalp] > 0).sum() > 50


# `RECEDE_EDGE`: only the keyframes that see a disc at their outline count in its quorum. Five
# cameras across the front (0, +-15, +-30 degrees) and one at the side (+90), all with the true
# sphere's silhouette: the side camera's outline runs over the sphere's front and back (the
# profile line), which the front cameras see face on (the front) or not at all (the back).
PROFILE_YAWS = (0.0, 15.0, -15.0, 30.0, -30.0, 90.0)


def _front_end(bald, cam: Camera) -> float:
    """How far (px) the alpha-0.5 render reaches beyond the true sphere at the end of `cam`'s
    middle rows where the sphere's front (+Z, the point the front cameras face) lies (the side
    camera at +90 sees it at the image's left), averaged over the 5 rows about the centre."""
    alpha = np.asarray(render(bald.replace(extras={}), cam, (1.0, 1.0, 1.0)).alpha)
    c = WIDTH // 2
    left = np.mean([np.flatnonzero(row).min() for row in alpha[c - 2:c + 3] > 0.5])
    front = cam.project(np.array([[0.0, 0.0, RADIUS]]))[0][0, 0]
    assert front < c       # the sphere's front at the left of the side camera's image
    return front - left


SKIN_RGB = (200, 150, 130)


def _profile_views(v, faces, masks=None, wall=(255, 255, 255)) -> list[View]:
    """The profile cameras' views: the person mask skin-coloured over a plain `wall` colour."""
    cams = [_camera(y) for y in PROFILE_YAWS]
    masks = [head_silhouette(v, faces, cam) for cam in cams] if masks is None else masks
    return [View(np.where(m[..., None], np.array(SKIN_RGB, np.uint8), np.array(wall, np.uint8)).astype(np.uint8), cam,
                 np.where(m, SKIN, 0).astype(np.int32), frame=i)
            for i, (cam, m) in enumerate(zip(cams, masks))]


def test_the_profile_line_seen_at_one_keyframes_outline_sets_in_with_the_edge_rule(sphere, monkeypatch):
    v, faces, bald = sphere
    fit = _fit(v, faces)
    views = _profile_views(v, faces)
    side = views[-1].camera
    before = _front_end(bald, side)
    monkeypatch.setattr(multiview, "RECEDE_EDGE", None)
    old, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_TURN", None)      # session 26's rule: every keyframe leads
    new, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
    # every keyframe that shows a disc counting, the front of the profile line (shown face on by
    # the five front cameras, voted out by the side one: 1 in 6) stays out; counted only where a
    # keyframe sees it at its outline, it sets in with the side camera's vote
    assert before > 1.5, before
    assert _front_end(old, side) > before - 0.2, (before, _front_end(old, side))
    assert _front_end(new, side) < 0.5, (before, _front_end(new, side), figures)
    # the front cameras' own outlines (the sphere's sides) set in as before
    front = views[0].camera
    assert abs(_overshoot(new, front) - _overshoot(old, front)) < 0.3, (_overshoot(new, front), _overshoot(old, front))
    # each moved disc straight inward along its face's normal
    shift = np.asarray(new.means, np.float64) - np.asarray(bald.means, np.float64)
    depth = np.linalg.norm(shift, axis=1)
    radial = np.einsum("nc,nc->n", shift, np.asarray(bald.means, np.float64)) / np.linalg.norm(bald.means, axis=1)
    assert (radial[depth > 0] < -0.9 * depth[depth > 0]).all()
    np.testing.assert_array_equal(new.quats, bald.quats)
    # with the edge rule a keyframe votes at RECEDE_EDGE_SHARE, not RECEDE_SHARE: past all of a
    # disc's weight no keyframe votes, and nothing moves
    monkeypatch.setattr(multiview, "RECEDE_EDGE_SHARE", 1.01)
    none, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    np.testing.assert_array_equal(none.means, bald.means)


def test_with_the_edge_rule_a_truth_that_overshoots_as_the_discs_do_still_leaves_them(sphere, monkeypatch):
    v, faces, bald = sphere
    cams = [_camera(y) for y in PROFILE_YAWS]
    views = _profile_views(v, faces, [np.asarray(render(bald.replace(extras={}), c, (1.0, 1.0, 1.0)).alpha) > 0.5
                                      for c in cams])
    monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_TURN", None)
    moved, figures = recede_outline(bald, GaussianSet.empty(), views, _fit(v, faces))
    for cam in cams:
        assert _overshoot(bald, cam) - _overshoot(moved, cam) < 0.25, figures
    assert _front_end(bald, cams[-1]) - _front_end(moved, cams[-1]) < 0.3, figures


def test_near_outline_is_the_distance_to_the_renders_outline(sphere):
    from avatarkit.track.frame_hull import near_outline

    v, faces, bald = sphere
    cam = _camera(0.0)
    g = bald.replace(extras={})
    means = np.asarray(bald.means, np.float64)
    px, z = cam.project(means)
    px = np.asarray(px, np.float64)
    r_px = np.linalg.norm(px - WIDTH / 2, axis=1)
    circle = cam.fy * math.tan(math.asin(RADIUS / DISTANCE))
    front = means[:, 2] > 0
    near = near_outline(g, cam, 4.0)
    # the discs facing the camera within the circle's inner part are far from the outline (which
    # stands ~1.8 px beyond the circle), the ones projecting within a pixel of the circle near it
    assert not near[front & (r_px < circle - 8)].any()
    assert (front & (r_px > circle - 1)).sum() > 50 and near[front & (r_px > circle - 1)].all()
    # behind the camera: never near (a camera at the same place looking away)
    away = Camera.look_at((0.0, 0.0, DISTANCE), (0.0, 0.0, 2 * DISTANCE), fov_deg=30.0, width=WIDTH, height=WIDTH)
    assert not near_outline(g, away, 4.0).any()


# `RECEDE_EDGE_TURN`: only the far-turned keyframes lead the edge rule. The profile cameras again,
# the side one (+90) with the true silhouette; the four front ones at +-15, +-30 with a silhouette
# made of the discs' own render (a truth that overshoots as they do: the sample avatar's), and the
# reference (0) with the true silhouette eroded by 2 px (a keyframe whose pose or segmentation is
# off by that much at the cheeks).
def _half_width(bald, cam: Camera) -> float:
    """How far (px) the alpha-0.5 render's middle rows reach beyond the true sphere on either
    side (half their width less the circle's radius), averaged over the 5 rows about the centre."""
    alpha = np.asarray(render(bald.replace(extras={}), cam, (1.0, 1.0, 1.0)).alpha) > 0.5
    c = WIDTH // 2
    width = np.mean([np.flatnonzero(row).max() - np.flatnonzero(row).min() + 1 for row in alpha[c - 2:c + 3]])
    return width / 2 - cam.fx * math.tan(math.asin(RADIUS / DISTANCE))


def test_with_the_turned_keyframes_leading_the_profile_sets_in_and_a_near_frontal_keyframe_alone_does_not(
        sphere, monkeypatch):
    import cv2

    v, faces, bald = sphere
    fit = _fit(v, faces)
    cams = [_camera(y) for y in PROFILE_YAWS]
    tight = cv2.erode(head_silhouette(v, faces, cams[0]).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    masks = ([tight] + [np.asarray(render(bald.replace(extras={}), c, (1.0, 1.0, 1.0)).alpha) > 0.5 for c in cams[1:5]]
             + [head_silhouette(v, faces, cams[5])])
    views = _profile_views(v, faces, masks)
    views[0].reference = True
    front, side = cams[0], cams[5]
    monkeypatch.setattr(multiview, "RECEDE_EDGE", None)
    old, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_TURN", None)
    every, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_TURN", 60.0)
    led, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
    assert figures["lead"] == [views[5].frame]
    # the profile line, which only the side camera sees at its outline: set in as with every
    # keyframe leading (2 px out before), not with session 23's quorum
    assert _front_end(bald, side) > 1.5 and _front_end(old, side) > _front_end(bald, side) - 0.2
    assert _front_end(led, side) < 0.5, (_front_end(led, side), figures)
    # the front camera's sides, which the reference alone votes out (the others' silhouettes
    # overshoot as the discs do): with every keyframe leading they set in past the others' by
    # 0.7 px; led by the turned keyframes, as session 23's quorum leaves them
    assert _half_width(every, front) < _half_width(old, front) - 0.5, (_half_width(every, front), _half_width(old, front))
    assert abs(_half_width(led, front) - _half_width(old, front)) < 0.15, (_half_width(led, front), _half_width(old, front))
    # each moved disc straight inward along its face's normal
    shift = np.asarray(led.means, np.float64) - np.asarray(bald.means, np.float64)
    depth = np.linalg.norm(shift, axis=1)
    radial = np.einsum("nc,nc->n", shift, np.asarray(bald.means, np.float64)) / np.linalg.norm(bald.means, axis=1)
    assert (radial[depth > 0] < -0.9 * depth[depth > 0]).all()
    # the lead keyframe votes at RECEDE_EDGE_SHARE: past all of a disc's weight it votes nothing,
    # and the quorum's moves are all that is left
    monkeypatch.setattr(multiview, "RECEDE_EDGE_SHARE", 1.01)
    quorum, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    np.testing.assert_array_equal(quorum.means, old.means)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_SHARE", 0.3)
    # the side camera's silhouette 8 px off (its pose wrong): the sphere's inside lies over its
    # wall, so it does not lead, and the quorum's moves are all that is left; with no test it leads
    shifted = [m for m in masks]
    shifted[5] = np.roll(masks[5], 8, axis=1)
    off = _profile_views(v, faces, shifted)
    off[0].reference = True
    monkeypatch.setattr(multiview, "RECEDE_EDGE", None)
    old_off, _ = recede_outline(bald, GaussianSet.empty(), off, fit)
    monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
    kept, figures = recede_outline(bald, GaussianSet.empty(), off, fit)
    assert figures["lead"] == []
    np.testing.assert_array_equal(kept.means, old_off.means)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_AGREE", None)
    untested, figures = recede_outline(bald, GaussianSet.empty(), off, fit)
    assert figures["lead"] == [off[5].frame]
    assert not np.array_equal(untested.means, old_off.means)


def test_deep_disagreement_counts_the_wall_under_the_renders_inside(sphere):
    from avatarkit.track import frame_hull

    v, faces, bald = sphere
    g = bald.replace(extras={})
    cam = _camera(0.0)
    alpha = np.asarray(render(g, cam, (1.0, 1.0, 1.0)).alpha) > 0.5
    # the render's own silhouette: no wall under it; the true sphere's (1.8 px inside it on
    # average): a few pixels deeper than 2 px, under RECEDE_EDGE_AGREE (such a keyframe leads)
    assert multiview.deep_disagreement(g, cam, frame_hull.wall_image(alpha, 0)) == 0.0
    assert multiview.deep_disagreement(g, cam, frame_hull.wall_image(head_silhouette(v, faces, cam), 0)) < 0.06
    # the silhouette 6 px to the side: a crescent up to 6 px deep, (6 - 2) / pi per outline px on average
    moved = multiview.deep_disagreement(g, cam, frame_hull.wall_image(np.roll(alpha, 6, axis=1), 0))
    assert 0.8 < moved < 1.6, moved


def test_turned_yaws_are_the_cameras_turns_from_the_reference(sphere):
    v, faces, _ = sphere
    views = _profile_views(v, faces)
    np.testing.assert_allclose(multiview.turned_yaws(views, np.zeros(3)), [0, 15, 15, 30, 30, 90], atol=1e-6)
    # from the marked reference (+30), whichever view comes first; the turn's sign left out
    views[3].reference = True
    np.testing.assert_allclose(multiview.turned_yaws(views, np.zeros(3)), [30, 15, 45, 0, 60, 60], atol=1e-6)
    # a camera pitched over the head is not turned; one behind it is turned 180
    up = Camera.look_at((0.0, -DISTANCE * math.sin(0.5), DISTANCE * math.cos(0.5)), (0.0, 0.0, 0.0), fov_deg=30.0,
                        width=WIDTH, height=WIDTH)
    views = [View(np.zeros((WIDTH, WIDTH, 3), np.uint8), c, None) for c in (_camera(0.0), up, _camera(180.0))]
    np.testing.assert_allclose(multiview.turned_yaws(views, np.zeros(3)), [0, 0, 180], atol=1e-6)


def test_the_turned_keyframes_lead_their_own_rounds_past_the_quorums(sphere, monkeypatch):
    # RECEDE_ROUNDS 1, RECEDE_EDGE_ROUNDS 3: the quorum's discs one step in, the side camera's
    # profile line up to three
    v, faces, bald = sphere
    fit = _fit(v, faces)
    views = _profile_views(v, faces)
    views[0].reference = True
    step = multiview.RECEDE_STEP * bald_discs.camera_pixel(views[0].camera, np.asarray(bald.means, np.float64))
    monkeypatch.setattr(multiview, "RECEDE_ROUNDS", 1)
    monkeypatch.setattr(multiview, "RECEDE_EDGE", None)
    old, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_TURN", 60.0)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_ROUNDS", 3)
    led, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
    depth = np.linalg.norm(np.asarray(led.means, np.float64) - np.asarray(bald.means, np.float64), axis=1)
    assert len(figures["moved"]) == 3 and depth.max() <= 3 * step * 1.001 and (depth > 2.5 * step).any(), figures
    # the discs past one step are the side camera's: the sphere's sides at the equator (the front
    # camera's outline, which the side camera sees face on or not at all) stay at one
    means = np.asarray(bald.means, np.float64)
    sides = (np.abs(means[:, 1]) < 0.01) & (np.abs(means[:, 2]) < 0.01)
    assert sides.sum() > 10 and (depth[sides] <= 1.001 * step).all()
    monkeypatch.setattr(multiview, "RECEDE_EDGE_ROUNDS", None)
    two, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
    assert len(figures["moved"]) <= 1



def test_a_leading_keyframe_votes_only_over_the_wall_unlike_the_person(sphere, monkeypatch):
    # the side camera's silhouette the true sphere's, 1.8 px inside the discs' outline (as a
    # segmentation's edge a pixel or two tight would be): over a white wall it leads the profile
    # line in; over a wall within RECEDE_EDGE_LIKE levels of the skin it votes nothing that
    # would move, and the profile line stays out
    v, faces, bald = sphere
    fit = _fit(v, faces)
    cams = [_camera(y) for y in PROFILE_YAWS]
    masks = [np.asarray(render(bald.replace(extras={}), c, (1.0, 1.0, 1.0)).alpha) > 0.5 for c in cams[:5]]
    masks.append(head_silhouette(v, faces, cams[5]))
    monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
    monkeypatch.setattr(multiview, "RECEDE_EDGE_TURN", 60.0)
    ends = {}
    for name, wall in (("white", (255, 255, 255)), ("beige", (215, 175, 150))):
        views = _profile_views(v, faces, masks, wall)
        views[0].reference = True
        monkeypatch.setattr(multiview, "RECEDE_EDGE", None)
        old, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
        monkeypatch.setattr(multiview, "RECEDE_EDGE", 4.0)
        led, figures = recede_outline(bald, GaussianSet.empty(), views, fit)
        assert figures["lead"] == [5]
        ends[name] = (_front_end(old, cams[5]), _front_end(led, cams[5]))
    # white: the profile line's front end comes in by more than a pixel; beige: it stays out as
    # session 23's quorum leaves it (the side camera votes over none of its wall)
    assert ends["white"][1] < ends["white"][0] - 1.0, ends
    assert ends["beige"][1] > ends["beige"][0] - 0.3, ends
    # RECEDE_EDGE_LIKE None: the labels' wall, whatever its colour
    monkeypatch.setattr(multiview, "RECEDE_EDGE_LIKE", None)
    views = _profile_views(v, faces, masks, (215, 175, 150))
    views[0].reference = True
    anyway, _ = recede_outline(bald, GaussianSet.empty(), views, fit)
    assert _front_end(anyway, cams[5]) < ends["beige"][0] - 1.0


def test_the_sure_wall_leaves_out_the_wall_that_looks_like_the_person_beside_it():
    person = np.zeros((40, 40), bool)
    person[10:30, 10:30] = True
    image = np.full((40, 40, 3), 255, np.uint8)
    image[person] = SKIN_RGB
    image[:, :5] = (190, 160, 120)          # a strip of wall within 40 levels of the skin
    # the frame's blends of skin and white at the edge: the person's last column, the wall's first
    image[10:30, 29] = (228, 203, 193)
    image[10:30, 30] = (240, 230, 225)
    wall = (~person).astype(np.int32)
    sure = multiview.sure_wall(wall, image, person, 40)
    assert (sure[:, :5] == 0).all()                                # like the skin: left out
    # white, and the wall's blend (like the person's blended edge, not its skin inside): kept
    assert (sure[:, 5:][~person[:, 5:]] == 1).all()
    assert (sure[person] == 0).all()
    assert (multiview.sure_wall(wall, image, person, 0)[:, 5:][~person[:, 5:]] == 1).all()
