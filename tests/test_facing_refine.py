"""The facing-weighted colour refine over a turning video's keyframes (`recon.facing_refine`) on
cases whose answer is known."""
from __future__ import annotations

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.facing_refine import (POWER, facing_weights, facing_weights_reference, refine_facing,
                                           refine_weighted)
from avatarkit.recon.multiview import REFERENCE_WEIGHT, View
from avatarkit.render import render
from avatarkit.render.camera import Camera

from helpers import splat_plane

SIZE = 64
GREY = (0.5, 0.5, 0.5)


def _camera(angle_deg: float, distance: float = 0.8) -> Camera:
    a = np.radians(angle_deg)
    return Camera.look_at((distance * np.sin(a), 0.0, distance * np.cos(a)), (0.0, 0.0, 0.0),
                          width=SIZE, height=SIZE, fov_deg=40)


def _view(gs, cam, colour, sharpness=1.0, reference=False) -> View:
    """A view of `gs` whose person (skin) is where gs renders, painted `colour`, on white."""
    from avatarkit.recon.segment import BACKGROUND, SKIN

    person = render(gs, cam, background=(1.0, 1.0, 1.0)).alpha > 0.5
    image = np.full((SIZE, SIZE, 3), 255, np.uint8)
    image[person] = (np.asarray(colour) * 255).round().astype(np.uint8)
    labels = np.where(person, SKIN, BACKGROUND).astype(np.int32)
    return View(image, cam, labels, sharpness, reference=reference)


@pytest.fixture(scope="module")
def planes():
    """A back plane (z = 0) and a front plane (z = 0.05) covering its left half; normals +Z."""
    back = splat_plane(0.0, (-0.1, 0.1), GREY)
    front = splat_plane(0.05, (-0.1, 0.0), GREY)
    both = GaussianSet.concat([back, front])
    return both, np.tile([0.0, 0.0, 1.0], (len(both), 1))


@pytest.mark.parametrize("angle", [0.0, 50.0])
def test_facing_weights_match_the_slow_reference(planes, angle):
    both, normals = planes
    is_hair = np.zeros(len(both), bool)
    is_hair[::7] = True                                  # a few by the renderer's visibility
    view = _view(both, _camera(angle), GREY, sharpness=0.7, reference=angle == 0.0)
    fast = facing_weights(both, normals, is_hair, view)
    slow = facing_weights_reference(both, normals, is_hair, view)
    assert (fast > 0).sum() > 100
    # pixels on a depth edge may round either way: nearly all agree exactly
    agree = np.isclose(fast, slow, rtol=1e-5, atol=1e-9)
    assert agree.mean() > 0.98


def test_weights_follow_the_facing_angle_and_the_reference_factor(planes):
    both, normals = planes
    no_hair = np.zeros(len(both), bool)
    head_on = facing_weights(both, normals, no_hair, _view(both, _camera(0.0), GREY))
    turned = facing_weights(both, normals, no_hair, _view(both, _camera(60.0), GREY, sharpness=0.5))
    seen = turned > 0
    assert seen.sum() > 50
    # cos(angle to the camera)^POWER x sharpness; ~cos(60)^POWER
    d = np.asarray(_camera(60.0).camera_center)[None] - both.means
    cos = d[:, 2] / np.linalg.norm(d, axis=1)
    np.testing.assert_allclose(turned[seen], 0.5 * cos[seen] ** POWER, rtol=1e-6)
    assert np.median(cos[seen]) == pytest.approx(0.5, abs=0.1)
    # hidden: the back plane behind the front one is not seen head-on
    back_hidden = np.zeros(len(both), bool)
    n_back = (both.means[:, 2] == 0.0)
    back_hidden[n_back & (both.means[:, 0] < -0.02)] = True
    assert not (head_on[back_hidden] > 0).any()
    ref = facing_weights(both, normals, no_hair, _view(both, _camera(0.0), GREY, reference=True))
    np.testing.assert_allclose(ref, REFERENCE_WEIGHT * head_on, rtol=1e-9)
    # a grazing view (80 degrees off the normal) sees nothing
    assert not (facing_weights(both, normals, no_hair, _view(both, _camera(80.0), GREY)) > 0).any()


def test_a_gaussian_seen_squarely_takes_that_views_colour_over_a_grazing_ones():
    """One plane, grey; the head-on view shows it red, one 65 degrees off the normal (cos 0.42,
    above the facing cut) shows it blue: the plane comes out red, not the views' mean."""
    gs = splat_plane(0.0, (-0.1, 0.1), GREY)
    normals = np.tile([0.0, 0.0, 1.0], (len(gs), 1))
    red, blue = (0.9, 0.1, 0.1), (0.1, 0.1, 0.9)
    views = [_view(gs, _camera(0.0), red), _view(gs, _camera(65.0), blue)]
    bald, _, info = refine_facing(gs, gs.subset(np.zeros(len(gs), bool)), views, normals, iterations=3)
    inner = (np.abs(gs.means[:, 0]) < 0.06) & (np.abs(gs.means[:, 1]) < 0.06)
    rgb = bald.colors[inner]
    assert info["updated"] > 0
    # the grazing view weighs 0.42^4 / (1 + 0.42^4) = 3 % of the mean
    assert np.all(np.abs(rgb[:, 0] - 0.9) < 0.08) and np.all(np.abs(rgb[:, 2] - 0.1) < 0.08)


def test_a_uniform_subject_seen_in_several_views_keeps_its_colour_and_the_kept_rows_stay():
    """The views are renders of the subject itself: nothing to correct. Rows marked keep (the
    neck) are never changed, even where every view shows them a different colour."""
    colour = (0.3, 0.6, 0.2)
    gs = splat_plane(0.0, (-0.1, 0.1), colour)
    normals = np.tile([0.0, 0.0, 1.0], (len(gs), 1))
    views = []
    for angle in (0.0, 30.0, -40.0):
        cam = _camera(angle)
        v = _view(gs, cam, colour)
        v.image = (render(gs, cam, background=(1.0, 1.0, 1.0)).rgb * 255).round().astype(np.uint8)
        views.append(v)
    keep = gs.means[:, 0] < -0.05
    bald, _, info = refine_facing(gs, gs.subset(np.zeros(len(gs), bool)), views, normals, keep=keep)
    inner = (np.abs(gs.means[:, 0]) < 0.05) & (np.abs(gs.means[:, 1]) < 0.05)
    np.testing.assert_allclose(bald.colors[inner], np.tile(colour, (inner.sum(), 1)), atol=0.01)
    np.testing.assert_array_equal(bald.colors[keep], gs.colors[keep])
    assert info["views"] == 3 and info["updated"] > 100


def test_the_weighted_refine_with_one_view_and_every_gaussian_is_refine_colours():
    """With one view, unit weights and every Gaussian showing, the weighted mean is that view's
    residual: the single-view `assemble.refine_colours`."""
    from avatarkit.recon.assemble import refine_colours
    from avatarkit.recon.label_lifting import accumulate_weights

    rng = np.random.default_rng(3)
    gs = splat_plane(0.0, (-0.1, 0.1), GREY)
    gs = gs.with_colors(rng.random((len(gs), 3)).astype(np.float32))
    cam = _camera(0.0)
    photo = (rng.random((SIZE, SIZE, 3)) * 255).astype(np.uint8)
    mask = np.zeros((SIZE, SIZE), bool)
    mask[12:52, 12:52] = True
    a, _ = refine_colours(gs, cam, photo, mask, iterations=2)
    target = photo.astype(np.float32) / 255.0
    shows = accumulate_weights(gs, cam, mask.astype(np.int32), 2)[:, 1] >= 0.05
    rgb, updated, (before, after) = refine_weighted(
        gs, [dict(camera=cam, target=target, mask=mask, background=np.median(target[~mask], axis=0),
                  weight=np.full(len(gs), 0.3), shows=shows)], np.ones(len(gs), bool), iterations=2)
    np.testing.assert_allclose(rgb, a.colors, atol=1e-5)
    assert updated.sum() == shows.sum() and after[0] > before[0]


def test_what_the_reference_view_sees_keeps_the_photos_colours():
    """The reference view (head-on) shows the plane red, a view 40 degrees off shows it blue:
    every Gaussian the reference sees keeps its colour (matched to the photo just before);
    the turned view recolours only what the reference does not see (here the back plane's
    part hidden behind the front plane, which the turned view sees past its edge)."""
    back = splat_plane(0.0, (-0.1, 0.1), GREY)
    front = splat_plane(0.05, (-0.1, 0.0), GREY)
    both = GaussianSet.concat([back, front])
    normals = np.tile([0.0, 0.0, 1.0], (len(both), 1))
    ref = _view(both, _camera(0.0), (0.9, 0.1, 0.1), reference=True)
    turned = _view(both, _camera(-40.0), (0.1, 0.1, 0.9))
    no_hair = np.zeros(len(both), bool)
    seen_by_ref = facing_weights(both, normals, no_hair, ref) > 0
    bald, _, info = refine_facing(both, both.subset(np.zeros(len(both), bool)), [ref, turned], normals)
    np.testing.assert_array_equal(bald.colors[seen_by_ref], both.colors[seen_by_ref])
    changed = np.any(np.abs(bald.colors - both.colors) > 0.05, axis=1)
    assert changed.sum() > 10 and not (changed & seen_by_ref).any()
    # what changed is bluer: the turned view's colour
    assert np.all(bald.colors[changed, 2] > both.colors[changed, 2])


@pytest.mark.slow
def test_the_video_build_runs_the_refine_over_its_keyframes_when_switched_on(tmp_path, monkeypatch):
    """`pipeline.FACING_REFINE` on: a turning video's build refines what its reference keyframe
    does not see from the other keyframes (the registered profile frames among them) and
    leaves the neck alone; the render of the keyframes gets no worse."""
    from avatarkit.recon import pipeline
    from avatarkit.recon.pipeline import BuildOptions
    from avatarkit.synthetic.sample_avatar import make_sample_avatar
    from avatarkit.synthetic.turning_video import eased_turning_clip, write_turning_video
    from avatarkit.track.video_build import build_video_avatar

    truth = make_sample_avatar(n_hair=1500, n_bald=6000, style="short", cage_vertices=200)
    write_turning_video(truth, tmp_path / "turn.mp4", size=160, clip=eased_turning_clip(72))
    monkeypatch.setattr(pipeline, "FACING_REFINE", True)
    avatar = build_video_avatar(tmp_path / "turn.mp4",
                                BuildOptions(n_bald=4000, n_hair=2000, preview=False, hair_mode="rigid"))
    info = avatar.provenance["build"]["facing_refine"]
    src = avatar.provenance["source_video"]
    assert info["views"] == len(src["keyframes"]) + len(src.get("registered", []))
    assert 0 < info["updated"] < info["of"]
    # the reference keyframe leads nothing: what it sees keeps the photo's colours
    lead = {int(k): v for k, v in info["led_by_view"].items()}
    assert lead[int(src["frame"])] == 0 and sum(lead.values()) == info["updated"]
    assert info["psnr_after"] >= info["psnr_before"] - 0.05
