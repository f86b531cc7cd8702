"""The video build's frame_colours stage (`track.frame_colours`) on cases whose answer is known."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.gaussians.gaussian_set import GaussianSet, rgb_to_dc
from avatarkit.render import render
from avatarkit.render.camera import Camera
from helpers import region_model
from avatarkit.track.frame_colours import (FrameView, colour_frames, fusion_selection, outline_band,
                                           outline_selection, refine_colours_frames)

SIZE = 96


def _plane(colours: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> GaussianSet:
    X, Y = np.meshgrid(xs, ys)
    n = X.size
    means = np.stack([X.ravel(), Y.ravel(), np.zeros(n)], 1)
    return GaussianSet(means, np.tile([1.0, 0, 0, 0], (n, 1)), np.tile([0.008, 0.008, 0.001], (n, 1)),
                       np.full(n, 0.99), rgb_to_dc(np.asarray(colours, np.float32).reshape(n, 3)))


def _camera():
    return Camera.look_at((0.0, 0.0, 0.5), (0.0, 0.0, 0.0), width=SIZE, height=SIZE, fov_deg=40)


def test_colours_fused_over_frames_average_out_what_each_frame_adds():
    """Each frame shows the plane's true colours plus a tint of its own (light, a collar that
    moves: what one frame adds); the plane moves a little between frames. Started from frame 0's
    colours (the single-frame build), the selected Gaussians come out at the true colours plus
    the frames' mean tint (zero), far nearer the truth than frame 0; the others keep theirs."""
    rng = np.random.default_rng(3)
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    X, Y = np.meshgrid(xs, ys)
    n = X.size
    truth = np.stack([0.5 + 2 * X.ravel(), 0.4 + 0.5 * Y.ravel() + X.ravel(), np.full(n, 0.45)], 1)
    tints = rng.normal(0.0, 0.1, (6, 3))
    tints -= tints.mean(axis=0)                       # the frames' mean tint is zero
    cam = _camera()
    views = []
    for k, tint in enumerate(tints):
        shift = np.array([0.004 * np.cos(k), 0.004 * np.sin(k), 0.0])
        shown = _plane(np.clip(truth + tint, 0, 1), xs, ys)
        shown = shown.replace(means=shown.means + shift)
        image = (np.clip(render(shown, cam, np.ones(3)).rgb, 0, 1) * 255).round().astype(np.uint8)
        start = shown.with_colors(np.clip(truth + tints[0], 0, 1))       # frame 0's colours
        views.append(FrameView(start, cam, image, np.ones((SIZE, SIZE), bool)))
    select = X.ravel() < 0.0
    fused = refine_colours_frames(views, select, background=np.ones(3))
    start = np.clip(truth + tints[0], 0, 1)
    inner = (np.abs(X.ravel()) < 0.08) & (np.abs(Y.ravel()) < 0.08)       # away from the plane's edge
    err_fused = np.abs(fused.rgb - truth)[select & inner].mean()
    err_one = np.abs(start - truth)[select & inner].mean()
    assert err_fused < 0.015, err_fused
    assert err_fused < 0.25 * err_one, (err_fused, err_one)
    np.testing.assert_allclose(fused.rgb[~select], views[0].gaussians.colors[~select], atol=0)
    assert fused.updated[select & inner].all() and not fused.updated[~select].any()
    assert fused.info["updated"] == int(fused.updated.sum()) and fused.info["frames"] == 6


def _gradient_plane():
    """A plane of Gaussians whose true colours are a gradient, its render (the one frame), and
    the same plane in flat grey (the colours to recover): (X, Y, truth, cam, image, grey plane)."""
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    X, Y = np.meshgrid(xs, ys)
    truth = np.stack([0.3 + X.ravel(), np.full(X.size, 0.6), 0.5 - Y.ravel()], 1)
    cam = _camera()
    image = (np.clip(render(_plane(truth, xs, ys), cam, np.ones(3)).rgb, 0, 1) * 255).round().astype(np.uint8)
    return X, Y, truth, cam, image, _plane(np.full_like(truth, 0.5), xs, ys)


def test_one_frame_recovers_its_own_colours():
    """With one frame the stage is the portrait's colour refine: it reproduces that frame."""
    X, Y, truth, cam, image, g = _gradient_plane()
    fused = refine_colours_frames([FrameView(g, cam, image, np.ones((SIZE, SIZE), bool))],
                                  np.ones(len(g), bool), background=np.ones(3))
    inner = (np.abs(X.ravel()) < 0.08) & (np.abs(Y.ravel()) < 0.08)
    assert np.abs(fused.rgb - truth)[inner].mean() < 0.01


def test_outline_gaussians_are_those_on_the_silhouette_band():
    """A disc of Gaussians seen head on: its rim (within the band of the render's outline) is
    selected, its middle is not."""
    xs = ys = np.arange(-0.12, 0.12 + 1e-9, 0.006)
    X, Y = np.meshgrid(xs, ys)
    r = np.hypot(X, Y).ravel()
    g = _plane(np.full((X.size, 3), 0.5), xs, ys).subset(r <= 0.1)
    r = r[r <= 0.1]
    cam = _camera()
    person = render(g, cam, np.ones(3)).alpha > 0.5
    band = outline_band(person, 0.05)                    # 5 px at 96
    assert band.any() and not band[SIZE // 2, SIZE // 2]
    sel = outline_selection([FrameView(g, cam, np.zeros((SIZE, SIZE, 3), np.uint8), person, band)])
    assert not sel[r < 0.06].any()
    assert sel[r > 0.095].mean() > 0.9


def test_colour_frames_are_eligible_spread_and_within_the_span():
    conf = np.full(100, 0.9)
    conf[10:20] = 0.3                                      # poorly tracked: never used
    found = np.ones(100, bool)
    found[50] = False
    result = SimpleNamespace(found=found, confidence=conf, frame_index=np.arange(100) + 7)
    rows = colour_frames(result, None, 10)
    assert len(rows) == 10 and rows[0] == 0 and rows[-1] == 99
    assert not np.isin(rows, np.r_[10:20, 50]).any()
    gaps = np.diff(rows)
    assert gaps.max() <= 2 * gaps.min() + 10
    half = colour_frames(result, (7, 57), 24)               # video frames 7..56: rows 0..49
    assert half.max() <= 49 and len(half) == 24
    everything = colour_frames(result, (7, 30), 24)      # rows 0..22, of which 10..19 are not eligible
    np.testing.assert_array_equal(everything, np.r_[0:10, 20:23])


def test_colour_frames_keep_to_the_reference_view():
    """Frames turned more than MAX_TURN from the reference are the keyframes' job, not fused."""
    from scipy.spatial.transform import Rotation

    from avatarkit.track.frame_colours import MAX_TURN

    yaw = np.linspace(-0.5, 0.5, 41)                     # -29 .. +29 degrees
    rot = Rotation.from_euler("YXZ", np.stack([yaw, np.zeros(41), np.zeros(41)], 1)).as_rotvec()
    result = SimpleNamespace(found=np.ones(41, bool), confidence=np.ones(41), frame_index=np.arange(41),
                             clip=SimpleNamespace(rotation=rot))
    rows = colour_frames(result, None, 41, reference=20)
    np.testing.assert_array_equal(rows, np.flatnonzero(np.abs(yaw) <= MAX_TURN + 1e-9))
    assert 0 < len(rows) < 41
    assert len(colour_frames(result, None, 41)) == 41


def test_colour_frames_read_the_module_settings_when_called(monkeypatch):
    """MAX_TURN and FRAMES set after import take effect (they were bound as defaults before)."""
    from scipy.spatial.transform import Rotation

    import avatarkit.track.frame_colours as fc

    yaw = np.linspace(-0.5, 0.5, 41)
    rot = Rotation.from_euler("YXZ", np.stack([yaw, np.zeros(41), np.zeros(41)], 1)).as_rotvec()
    result = SimpleNamespace(found=np.ones(41, bool), confidence=np.ones(41), frame_index=np.arange(41),
                             clip=SimpleNamespace(rotation=rot))
    monkeypatch.setattr(fc, "MAX_TURN", 1.0)
    monkeypatch.setattr(fc, "FRAMES", 41)
    assert len(colour_frames(result, reference=20)) == 41
    monkeypatch.setattr(fc, "FRAMES", 5)
    assert len(colour_frames(result, reference=20)) == 5


def test_fusion_selection_takes_the_bald_gaussians_on_the_regions_and_the_hair_if_asked():
    model = region_model(np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]]),
                         {"neck": np.array([0, 1]), "lips": np.array([3, 4, 5])}, 7)
    bald = _plane(np.full((4, 3), 0.5), np.array([0.0, 0.1]), np.array([0.0, 0.1]))
    bald = bald.replace(extras={"binding": np.array([0, 1, 2, 0], np.int32)})
    hair = _plane(np.full((2, 3), 0.5), np.array([0.0, 0.1]), np.array([0.0]))
    sel = fusion_selection(SimpleNamespace(head_model=model, bald=bald, hair=hair), ("neck", "lips", "mouth_interior"))
    # face 0: 2 neck vertices; face 1: 2 lips vertices; face 2: 2 lips vertices; hair never
    np.testing.assert_array_equal(sel, [True, True, True, True, False, False])
    sel = fusion_selection(SimpleNamespace(head_model=model, bald=bald, hair=hair), ("neck",))
    np.testing.assert_array_equal(sel, [True, False, False, True, False, False])
    # regions None (`FUSE_ALL`): every bald Gaussian, still no hair
    sel = fusion_selection(SimpleNamespace(head_model=model, bald=bald, hair=hair), None)
    np.testing.assert_array_equal(sel, [True, True, True, True, False, False])
    # hair (`FUSE_HAIR`): every hair Gaussian as well, whatever the regions
    sel = fusion_selection(SimpleNamespace(head_model=model, bald=bald, hair=hair), ("neck",), hair=True)
    np.testing.assert_array_equal(sel, [True, False, False, True, True, True])
    sel = fusion_selection(SimpleNamespace(head_model=model, bald=bald, hair=hair), None, hair=True)
    assert sel.all()


def _posing_case(seed: int, T: int):
    """A small sample avatar, a random T-frame clip from `seed` and a 48 px camera, as a
    TrackResult stand-in with frames 100.. (each image a flat grey of its row): -> (avatar,
    clip, result, images, rng)."""
    from avatarkit.motion.clip import MotionClip
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    avatar = make_sample_avatar(n_hair=800, n_bald=1000, cage_vertices=150, seed=5)
    rng = np.random.default_rng(seed)
    clip = MotionClip(30.0, rng.normal(0, 0.1, (T, 3)), rng.normal(0, 0.01, (T, 3)), np.zeros((T, 3)),
                      np.abs(rng.normal(0, 0.1, (T, 3))), np.zeros((T, 6)), np.zeros((T, 0)))
    camera = Camera.look_at((0.0, 0.0, 0.8), (0.0, 0.0, 0.0), width=48, height=48, fov_deg=40)
    result = SimpleNamespace(clip=clip, camera=camera, frame_index=np.arange(T) + 100)
    images = {int(f): np.full((48, 48, 3), k, np.uint8) for k, f in enumerate(np.arange(T) + 100)}
    return avatar, clip, result, images, rng


def test_posed_frames_bake_only_their_rows_as_the_whole_clip_would():
    """`posed_frames` bakes the chosen rows alone (the fast path); the reference is the bake of
    the whole clip: with the hair riding the head the poses are the same."""
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.sim.config import SimConfig
    from avatarkit.track.frame_colours import posed_frames

    avatar, clip, result, images, _ = _posing_case(0, 9)
    rows = [1, 4, 8]
    views = posed_frames(avatar, result, rows, images)
    static, baked = bake(avatar, clip, BakeConfig(sim=SimConfig(static=True)))
    whole = list(baked)
    for r, v in zip(rows, views):
        ref = np.concatenate([whole[r].face.means, whole[r].hair.means])
        np.testing.assert_allclose(v.gaussians.means, ref, atol=1e-6)
        assert int(v.image[0, 0, 0]) == r and v.mask.shape == (48, 48)
    # without masks (the frame hull's rounds): the same poses, nothing rendered
    for v, bare in zip(views, posed_frames(avatar, result, rows, images, masks=False)):
        np.testing.assert_array_equal(bare.gaussians.means, v.gaussians.means)
        assert bare.mask is None and bare.shows is None and bare.weights is None


def test_shared_weights_give_the_same_refine_and_outline():
    """`posed_frames` computes each frame's `frame_shows` once for the refine and the outline
    selection (the fast path); without it both compute their own (the reference)."""
    from dataclasses import replace

    from avatarkit.track.frame_colours import frame_shows

    X, Y, truth, cam, image, g = _gradient_plane()
    person = render(g, cam, np.ones(3)).alpha > 0.5
    mask = person.copy()
    mask[:, SIZE // 2 + 8:] = False                      # the right part is not compared: its Gaussians do not show
    plain = FrameView(g, cam, image, mask, outline_band(person, 0.05))
    shared = replace(plain, shows=frame_shows(plain))
    select = X.ravel() < 0.03
    a = refine_colours_frames([plain], select, background=np.ones(3))
    b = refine_colours_frames([shared], select, background=np.ones(3))
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.updated, b.updated)
    np.testing.assert_array_equal(outline_selection([plain]), outline_selection([shared]))
    assert shared.shows.any() and not shared.shows.all()


def test_registered_frames_fuse_every_gaussian_for_more_rounds(monkeypatch):
    """With the landmark fit's poses the stage fuses REGIONS' bald Gaussians for ITERATIONS
    rounds; with frames registered by the refinement every bald Gaussian and the hair for
    REGISTERED_ITERATIONS; FUSE_ALL / FUSE_HAIR, where set, hold either way."""
    from avatarkit.track import frame_colours as fc

    monkeypatch.setattr(fc, "FUSE_ALL", None)
    monkeypatch.setattr(fc, "FUSE_HAIR", None)
    assert fc.stage_settings(None) == fc.StageSettings(False, False, fc.ITERATIONS)
    assert fc.stage_settings("photometric") == fc.StageSettings(True, True, fc.REGISTERED_ITERATIONS)
    assert fc.REGISTERED_ITERATIONS > fc.ITERATIONS
    monkeypatch.setattr(fc, "FUSE_HAIR", False)
    assert fc.stage_settings("photometric") == fc.StageSettings(True, False, fc.REGISTERED_ITERATIONS)
    monkeypatch.setattr(fc, "FUSE_ALL", True)
    assert fc.stage_settings(None) == fc.StageSettings(True, False, fc.ITERATIONS)


def test_plain_builds_register_the_stages_frames_with_photometric_fast():
    """A plain `avatarkit build VIDEO` (no refine= handed down) registers the stage's frames with
    photometric-fast (session 17), at its own spacing (every 5th frame, sparser than
    REFINE_EVERY's 3), and so fuses every bald Gaussian and the hair for more rounds."""
    from avatarkit.track import frame_colours as fc
    from avatarkit.track.tracker import REFINE_EVERY

    assert fc.REFINE == "photometric-fast" and fc.REFINE_EVERY == 3
    assert fc.stage_spacing(fc.REFINE) == REFINE_EVERY["photometric-fast"] == 5
    assert fc.stage_settings(fc.REFINE).fuse_all and fc.stage_settings(fc.REFINE).hair


@pytest.mark.parametrize("stage, refine, expected, every", [
    (None, None, None, 1), ("photometric-fast", None, "photometric-fast", 5), (None, "photometric", "photometric", 3),
    (None, "photometric-fast", "photometric-fast", 5), ("photometric-fast", "photometric-pose", "photometric-pose", 3),
    ("photometric-fast", "none", None, 1)])
def test_the_stage_tracks_its_frames_with_the_refinement_asked(monkeypatch, stage, refine, expected, every):
    """`fuse_frame_colours(refine=)` tracks the video with that refinement (None: the stage's
    REFINE; "none": the landmark fit's poses even while REFINE is set), every REFINE_EVERY-th
    frame or the setting's own sparser spacing (photometric-fast's 5; none: every frame a fit)."""
    from contextlib import contextmanager

    import avatarkit.track.video as video
    from avatarkit.track import frame_colours as fc

    seen = {}

    @contextmanager
    def fake(avatar, path, meshes=None, options=None):
        seen["options"] = options
        raise KeyboardInterrupt   # stop before any work
        yield

    monkeypatch.setattr(video, "tracked_with_built_avatar", fake)
    monkeypatch.setattr(fc, "REFINE", stage)
    with pytest.raises(KeyboardInterrupt):
        fc.fuse_frame_colours(SimpleNamespace(), "v.mp4", SimpleNamespace(meshes=None, camera=SimpleNamespace(fx=266.0)),
                              0, refine=refine)
    assert seen["options"].refine == expected
    assert seen["options"].refine_every == every == fc.stage_spacing(expected)


def test_a_hidden_gaussian_keeps_its_colour_when_updates_are_weighted_by_what_shows():
    """A grey plane in front of a second one (the second hidden but for a sliver of weight,
    as the discs under the chin are) and a frame showing the front plane red: without the
    weighting (`hidden` 0) the hidden plane's discs take the whole residual and turn as red as
    the front's; with it (`hidden` 0.5 px) they move by their share of the render, nearly not at
    all, while the front plane still reaches the frame's red."""
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    cam = _camera()
    front = _plane(np.full((len(xs) ** 2, 3), 0.5), xs, ys).replace(opacities=np.full(len(xs) ** 2, 0.7))
    back = front.replace(means=front.means - np.array([0.0, 0.0, 0.02]))
    both = GaussianSet.concat([front, back])
    red = front.with_colors(np.tile(np.float32([0.8, 0.2, 0.2]), (len(front), 1)))
    image = (np.clip(render(red, cam, np.ones(3)).rgb, 0, 1) * 255).round().astype(np.uint8)
    X, Y = np.meshgrid(xs, ys)
    inner = np.tile((np.abs(X.ravel()) < 0.06) & (np.abs(Y.ravel()) < 0.06), 2)
    n = len(front)
    view = FrameView(both, cam, image, np.ones((SIZE, SIZE), bool))
    from avatarkit.track.frame_colours import frame_weights

    w = frame_weights(view)
    assert (w[n:][inner[n:]] < 0.3).all() and (w[n:][inner[n:]] >= 0.05).any() and (w[:n][inner[:n]] > 1).all()
    plain = refine_colours_frames([view], np.ones(2 * n, bool), background=np.ones(3), hidden=0.0, depth=0.0)
    weighted = refine_colours_frames([view], np.ones(2 * n, bool), background=np.ones(3), hidden=0.5, depth=0.0)
    shown_back = inner & (np.arange(2 * n) >= n) & (w >= 0.05)
    for fused in (plain, weighted):
        np.testing.assert_allclose(fused.rgb[:n][inner[:n]].mean(axis=0), [0.8, 0.2, 0.2], atol=0.05)
    drift = lambda f: np.abs(f.rgb[shown_back] - 0.5).max(axis=1).mean()
    assert drift(plain) > 0.1 and drift(weighted) < 0.5 * drift(plain), (drift(plain), drift(weighted))


def test_the_recessions_reposer_gives_the_bakes_frames_as_the_bald_moves():
    """`bald_reposer` (the head meshes and hair baked once, the bald Gaussians posed again on
    the current binding) gives what `posed_frames(masks=False)` gives, bit for bit, at its first
    call and after the bald Gaussians moved (as `recede` moves them) twice."""
    from avatarkit.track.frame_colours import _set_bald_means, bald_reposer, posed_frames

    avatar, _, result, images, rng = _posing_case(1, 7)
    rows = np.array([0, 3, 6])
    pose = bald_reposer(avatar, result, rows, images)
    rest = np.asarray(avatar.bald.means, np.float64)
    moves = rng.normal(0, 0.002, rest.shape) * (rng.random(len(rest)) < 0.3)[:, None]
    for k in range(3):
        _set_bald_means(avatar, rest + k * moves)
        fast, slow = pose(), posed_frames(avatar, result, rows, images, masks=False)
        for a, b in zip(fast, slow):
            for name in ("means", "quats", "scales", "opacities", "sh"):
                np.testing.assert_array_equal(getattr(a.gaussians, name), getattr(b.gaussians, name))
            assert a.image is b.image and a.mask is None and a.camera is b.camera
        if k:
            assert not np.array_equal(fast[0].gaussians.means, before)
        before = fast[0].gaussians.means


def _front_and_hidden_planes(gap: float = 0.05, hidden_colour=(0.5, 0.5, 0.5)):
    """A grey plane (opacity 0.7) in front of a second one `gap` behind it (hidden but for a
    sliver of weight, as the back of the neck is behind the front of it and the chin) and a
    frame showing the front plane red. -> (gaussians, camera, image, n per plane, inner (2n,)
    bool: away from the planes' edges)."""
    xs = ys = np.arange(-0.1, 0.1 + 1e-9, 0.01)
    cam = _camera()
    front = _plane(np.full((len(xs) ** 2, 3), 0.5), xs, ys).replace(opacities=np.full(len(xs) ** 2, 0.7))
    back = front.replace(means=front.means - np.array([0.0, 0.0, gap])).with_colors(
        np.tile(np.float32(hidden_colour), (len(front), 1)))
    red = front.with_colors(np.tile(np.float32([0.8, 0.2, 0.2]), (len(front), 1)))
    image = (np.clip(render(red, cam, np.ones(3)).rgb, 0, 1) * 255).round().astype(np.uint8)
    X, Y = np.meshgrid(xs, ys)
    inner = np.tile((np.abs(X.ravel()) < 0.06) & (np.abs(Y.ravel()) < 0.06), 2)
    return GaussianSet.concat([front, back]), cam, image, len(front), inner


@pytest.mark.parametrize("count", [True, False])
def test_a_disc_behind_the_surface_keeps_its_colour_and_one_in_view_takes_the_frames(monkeypatch, count):
    """The back plane's discs show (weight >= MIN_WEIGHT) but lie 5 cm behind what the frame
    shows: without HIDDEN_DEPTH (0) they take the front's residual every round and turn red;
    with it (3 cm) they keep their grey exactly and are not counted as updated (whether the
    hiding frame counts in their mean or not: HIDDEN_COUNT), while the front plane reaches the
    frame's red as before."""
    from avatarkit.track import frame_colours as fc
    from avatarkit.track.frame_colours import MIN_WEIGHT, frame_weights

    monkeypatch.setattr(fc, "HIDDEN_COUNT", count)

    g, cam, image, n, inner = _front_and_hidden_planes()
    view = FrameView(g, cam, image, np.ones((SIZE, SIZE), bool))
    shown_back = inner & (np.arange(2 * n) >= n) & (frame_weights(view) >= MIN_WEIGHT)
    assert shown_back.sum() > 10
    plain = refine_colours_frames([view], np.ones(2 * n, bool), background=np.ones(3), hidden=0.0, depth=0.0)
    kept = refine_colours_frames([view], np.ones(2 * n, bool), background=np.ones(3), hidden=0.0, depth=0.03)
    for fused in (plain, kept):
        np.testing.assert_allclose(fused.rgb[:n][inner[:n]].mean(axis=0), [0.8, 0.2, 0.2], atol=0.05)
    assert np.abs(plain.rgb[shown_back] - 0.5).max(axis=1).mean() > 0.25
    np.testing.assert_array_equal(kept.rgb[shown_back], g.colors[shown_back])
    assert plain.updated[shown_back].all() and not kept.updated[shown_back].any()


def test_a_disc_seen_in_one_frame_takes_that_frames_colour_whole():
    """Two frames of the same discs: in one the front plane hides the back plane (5 cm behind),
    in the other the front plane is moved out of view and the frame shows the back plane blue.
    The back plane takes the blue from the frame that sees it, the mean over the frames that
    see it (HIDDEN_COUNT): two rounds reach it, where averaging in the hiding frame's zero
    update would leave it a quarter short."""
    from avatarkit.track import frame_colours as fc

    g, cam, image, n, inner = _front_and_hidden_planes()
    away = g.replace(means=np.where((np.arange(2 * n) < n)[:, None], g.means + np.array([1.0, 0.0, 0.0]), g.means))
    blue = away.with_colors(np.tile(np.float32([0.2, 0.3, 0.8]), (2 * n, 1)))
    image2 = (np.clip(render(blue, cam, np.ones(3)).rgb, 0, 1) * 255).round().astype(np.uint8)
    views = [FrameView(g, cam, image, np.ones((SIZE, SIZE), bool)),
             FrameView(away, cam, image2, np.ones((SIZE, SIZE), bool))]
    back = inner & (np.arange(2 * n) >= n)
    fused = refine_colours_frames(views, np.ones(2 * n, bool), iterations=2, background=np.ones(3), hidden=0.0, depth=0.03)
    np.testing.assert_allclose(fused.rgb[back].mean(axis=0), [0.2, 0.3, 0.8], atol=0.03)
    np.testing.assert_allclose(fused.rgb[:n][inner[:n]].mean(axis=0), [0.8, 0.2, 0.2], atol=0.05)
