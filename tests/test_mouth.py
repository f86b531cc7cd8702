"""recon.mouth: teeth and cavity hidden at rest, shown between parted lips when the jaw opens,
riding the skull (upper) and the jaw (lower); a model without mouth regions gets none."""
import dataclasses

import numpy as np
import pytest

from avatarkit.head.model import HeadParams, load_template
from avatarkit.recon import mouth
from avatarkit.render import render
from avatarkit.render.camera import Camera
from avatarkit.rig.binding import TriangleBinding
from avatarkit.synthetic.sample_avatar import make_bald


@pytest.fixture(scope="module")
def head():
    model = load_template()
    shape = np.zeros(model.num_shape, np.float32)
    rest = mouth.posed_rest(model, shape, 0.0)
    bald = make_bald(model, rest, 60_000, seed=3)
    opened, info = mouth.open_mouth(model, rest, shape, bald)
    return model, shape, rest, bald, opened, info


def _posed(model, shape, rest, gs, jaw):
    v = mouth.posed_rest(model, shape, mouth.opening_sign(model, shape) * jaw)
    return TriangleBinding.bind(gs, rest, model.faces, gs.extras["binding"]).to_world(v)


def _view(model, rest, gs, az=0.0, el=0.0, size=128):
    geo = mouth.mouth_geometry(model, rest)
    cam = Camera.orbit(geo.centre + [0, -0.005, 0.01], az, el, 0.3, 20, size, size)
    return np.clip(render(gs, cam, (1.0, 1.0, 1.0)).rgb, 0, 1), cam


def test_adds_teeth_and_cavity_and_parts_lips(head):
    model, shape, rest, bald, opened, info = head
    assert info["teeth"] > 300 and info["cavity"] > 1000 and info["lips_rebound"] > 0
    assert len(opened) == len(bald) + info["teeth"] + info["cavity"]
    # the bald set's own Gaussians keep their place; none rides a face that opens with the jaw
    np.testing.assert_array_equal(opened.means[:len(bald)], bald.means)
    mouth_faces = np.zeros(model.num_vertices, bool)
    mouth_faces[model.regions["lips"]] = mouth_faces[model.regions["mouth_interior"]] = True
    opens = mouth.stretching_faces(model, shape) & (mouth_faces[model.faces].sum(axis=1) >= 2)
    assert opens.any() and not opens[opened.extras["binding"]].any()


@pytest.mark.parametrize("az,el", [(0, 0), (45, 0), (-45, 0), (90, 0), (-90, 0), (0, 30), (0, -30)])
def test_hidden_at_rest(head, az, el):
    model, shape, rest, bald, opened, info = head
    without, _ = _view(model, rest, bald, az, el)
    with_, _ = _view(model, rest, opened, az, el)
    diff = np.abs(with_ - without).max(axis=-1)
    # measured: mean <= 0.0003, pixels off by > 0.1 <= 0.012 %; with the teeth 4 mm in front of
    # the crease's back wall and no inside test, mean 0.0003-0.0011 and 0.03-0.34 % of pixels
    assert diff.mean() < 0.0005, diff.mean()
    assert (diff > 0.1).mean() < 0.001, (diff > 0.1).mean()


def test_shown_between_the_lips_when_open(head):
    model, shape, rest, bald, opened, info = head
    geo = mouth.mouth_geometry(model, rest)
    before, cam = _view(model, rest, _posed(model, shape, rest, bald, 0.3))
    after, _ = _view(model, rest, _posed(model, shape, rest, opened, 0.3))
    # the box between the mouth corners, from the mouth line to 20 mm below it
    corners = geo.centre + np.array([[-0.7 * geo.half_width, 0.0, 0.0], [0.7 * geo.half_width, -0.02, 0.0]])
    (x0, y0), (x1, y1) = np.sort(cam.project(corners)[0], axis=0).astype(int)
    box_b, box_a = before[y0:y1, x0:x1].reshape(-1, 3), after[y0:y1, x0:x1].reshape(-1, 3)
    pink = lambda c: (c[:, 0] - c[:, 1] > 0.15) & (c.mean(axis=1) > 0.35)
    dark = lambda c: c.mean(axis=1) < 0.2
    ivory = lambda c: (c.min(axis=1) > 0.3) & ((c.max(axis=1) - c.min(axis=1)) / c.max(axis=1) < 0.3)
    # measured on the sample bald: pink 0.84 -> 0.30, dark 0.02 -> 0.39, ivory 0 -> 0.037
    assert pink(box_a).mean() < pink(box_b).mean() - 0.3
    assert (dark(box_a) | ivory(box_a)).mean() > (dark(box_b) | ivory(box_b)).mean() + 0.3
    assert ivory(box_a).mean() > 0.02 > ivory(box_b).mean()


def test_upper_teeth_ride_the_skull_lower_the_jaw(head):
    model, shape, rest, bald, opened, info = head
    extra = np.arange(len(bald), len(opened))
    jaw = mouth.opening_sign(model, shape) * 0.3
    _, T = model.forward(HeadParams(jaw=np.array([jaw, 0.0, 0.0]), shape=shape))
    posed = _posed(model, shape, rest, opened, 0.3).means[extra].astype(np.float64)
    p = opened.means[extra].astype(np.float64)
    jaw_moved = (T[0, 2, :3, :3] @ p.T).T + T[0, 2, :3, 3]
    ids = opened.extras["binding"][extra]
    w = model.weights[:, 2][model.faces[ids]].mean(axis=1)
    upper, lower = w < 0.5, w >= 0.5
    assert upper.sum() > 500 and lower.sum() > 500
    np.testing.assert_allclose(posed[upper], p[upper], atol=5e-4)          # the skull did not move
    np.testing.assert_allclose(posed[lower], jaw_moved[lower], atol=5e-4)  # rigidly with the jaw


def test_model_without_mouth_regions_gets_no_teeth(head):
    model, shape, rest, bald, _, _ = head
    flat = dataclasses.replace(model, regions={k: v for k, v in model.regions.items() if k != "mouth_interior"})
    out, info = mouth.open_mouth(flat, rest, shape, bald)
    assert len(out) == len(bald) and info["teeth"] == 0 and info["cavity"] == 0


def test_photo_teeth_colour():
    img = np.full((100, 100, 3), (150, 60, 60), np.uint8)        # a dark red open mouth
    poly = np.array([[20, 40], [80, 40], [80, 70], [20, 70]], float)
    assert mouth.photo_teeth_colour(img, poly) is None
    img[40:50, 25:75] = (230, 225, 210)                          # teeth showing
    np.testing.assert_allclose(mouth.photo_teeth_colour(img, poly), np.array([230, 225, 210]) / 255, atol=0.01)
    assert mouth.photo_teeth_colour(img, None) is None


@pytest.mark.slow
def test_build_with_the_open_mouth_round_trips(tmp_path, monkeypatch):
    """pipeline.OPEN_MOUTH on the sample portrait: the teeth and cavity are saved as bald
    Gaussians with their binding and come back from the avatar folder."""
    from pathlib import Path

    from avatarkit.avatar import load_avatar
    from avatarkit.recon import pipeline

    monkeypatch.setattr(pipeline, "OPEN_MOUTH", True)
    sample = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"
    options = pipeline.BuildOptions(n_bald=6000, n_hair=5000, cage_vertices=200, preview=False)
    avatar = pipeline.build_avatar(sample, options)
    info = avatar.provenance["build"]["mouth"]
    assert info["teeth"] > 300 and info["cavity"] > 1000
    loaded = load_avatar(pipeline.save_avatar(avatar, tmp_path / "av"))
    assert len(loaded.bald) == 6000 + avatar.provenance["build"]["lift"]["bald_extra"] \
        + avatar.provenance["build"]["coverage"]["bald_added"] + info["teeth"] + info["cavity"]
    np.testing.assert_array_equal(loaded.bald.extras["binding"], avatar.bald.extras["binding"])


def test_mouth_sized_by_this_heads_joints(head):
    """The teeth's arch is sized by the eyes' spacing of the head given, not the mean head's: a
    head 1.2x larger has a 1.2x wider mouth unit (the joints are a linear regression of it)."""
    model, shape, rest, _, _, _ = head
    geo = mouth.mouth_geometry(model, rest)
    big = mouth.mouth_geometry(model, 1.2 * rest)
    assert big.u == pytest.approx(1.2 * geo.u, rel=1e-6)
    np.testing.assert_allclose(big.centre[:2], 1.2 * geo.centre[:2], rtol=1e-6, atol=1e-9)


def test_one_jaw_probe_gives_what_posing_each_time_did(head):
    model, shape, rest, _, _, _ = head
    probe = mouth.jaw_probe(model, shape)
    np.testing.assert_array_equal(probe.rest, mouth.posed_rest(model, shape, 0.0))
    np.testing.assert_array_equal(probe.opened, mouth.posed_rest(model, shape, probe.sign * mouth.PROBE_JAW))
    np.testing.assert_array_equal(mouth.stretching_faces(model, shape), mouth.stretching_faces(model, shape, probe))


def test_the_frame_colours_stage_colours_the_teeth_a_frame_shows_and_keeps_the_guess_elsewhere(head):
    """The video build's stage (`track.frame_colours`) on the open mouth: two frames of a person
    whose teeth are white where the build guessed ivory, one with the jaw open 0.3 rad, one
    closed. The teeth the open frame shows are fused toward white; the teeth no frame shows
    (the closed frame hides them; the lower row hides behind the lower lip) keep the guess
    to the bit, and so does every Gaussian outside the selection."""
    from avatarkit.track.frame_colours import FrameView, frame_shows, refine_colours_frames

    model, shape, rest, bald, opened, info = head
    teeth = np.zeros(len(opened), bool)
    teeth[len(bald):len(bald) + info["teeth"]] = True     # open_mouth appends the teeth first
    white = np.array([0.95, 0.95, 0.92], np.float32)
    truth = opened.with_colors(np.where(teeth[:, None], white, opened.colors))
    views = []
    for jaw in (0.3, 0.0):
        shown, cam = _view(model, rest, _posed(model, shape, rest, truth, jaw))
        guess = _posed(model, shape, rest, opened, jaw)
        image = (shown * 255).round().astype(np.uint8)
        views.append(FrameView(guess, cam, image, np.ones(image.shape[:2], bool)))
    shows = [frame_shows(v) & teeth for v in views]
    # closed, a few teeth weigh over a twentieth of a pixel through the lips' crease (measured
    # 31 against the open frame's 180)
    assert shows[0].sum() > 50 and shows[1].sum() < 0.25 * shows[0].sum()
    fused = refine_colours_frames(views, teeth, iterations=4, background=np.ones(3))
    seen, unseen = shows[0], teeth & ~(shows[0] | shows[1])
    assert unseen.sum() > 50                                # the lower row, the arch's ends
    # a pixel's weight or more: not behind a lip (measured: 29 teeth, 0.42 -> 0.07 off; every tooth
    # the open frame shows 0.44 -> 0.26)
    clear = frame_shows(views[0], 1.0) & teeth
    err = lambda rgb, sel: np.abs(rgb[sel] - white).mean()
    assert err(fused.rgb, clear) < 0.3 * err(opened.colors, clear)
    assert err(fused.rgb, seen) < 0.8 * err(opened.colors, seen)
    np.testing.assert_array_equal(fused.rgb[unseen], opened.colors[unseen])
    np.testing.assert_array_equal(fused.rgb[~teeth], opened.colors[~teeth])
    np.testing.assert_array_equal(fused.updated, shows[0] | shows[1])


def test_open_avatar_mouth_is_open_mouth_on_the_avatars_bald_set(head):
    """The video build's way in (`track.video_build.OPEN_MOUTH`): on a built avatar it gives
    what `open_mouth` gives its bald set on its own rest head, bindings included, and the
    avatar's cached binding follows."""
    from avatarkit.avatar import Avatar
    from avatarkit.gaussians.gaussian_set import GaussianSet

    model, shape, rest, bald, opened, info = head
    avatar = Avatar(model, bald.replace(extras={"binding": bald.extras["binding"].astype(np.int32)}),
                    GaussianSet.empty(), None, None, shape)
    assert len(avatar.binding.face_ids) == len(bald)
    out, info = mouth.open_avatar_mouth(avatar, teeth_rgb=(0.9, 0.9, 0.9))
    expected, _ = mouth.open_mouth(model, np.asarray(avatar.rest_head_vertices, np.float64), shape, bald,
                                   teeth_rgb=(0.9, 0.9, 0.9))
    assert out is avatar and info["teeth"] > 100 and info["teeth_from_photo"]
    assert len(avatar.bald) == len(expected) == len(bald) + info["teeth"] + info["cavity"]
    np.testing.assert_array_equal(avatar.bald.colors, expected.colors)
    np.testing.assert_array_equal(avatar.bald.means, expected.means)
    np.testing.assert_array_equal(avatar.bald.extras["binding"], expected.extras["binding"])
    assert set(avatar.bald.extras) == {"binding"}
    np.testing.assert_array_equal(avatar.binding.face_ids, avatar.bald.extras["binding"])


def test_the_video_build_opens_the_mouth_once(head, monkeypatch):
    """`video_build._open_mouth` (OPEN_MOUTH's call site): it opens a built avatar's mouth, with
    the teeth's guess from the reference frame when that shows teeth, and leaves an avatar the
    portrait build opened already (`pipeline.OPEN_MOUTH`) as it is."""
    from types import SimpleNamespace

    from avatarkit.avatar import Avatar
    from avatarkit.gaussians.gaussian_set import GaussianSet
    from avatarkit.recon import pipeline
    from avatarkit.track import video_build

    model, shape, rest, bald, opened, info = head
    make = lambda: Avatar(model, bald.replace(extras={"binding": bald.extras["binding"].astype(np.int32)}),
                          GaussianSet.empty(), None, None, shape)
    image = np.full((100, 100, 3), (230, 225, 210), np.uint8)          # all teeth
    mesh = SimpleNamespace(points=np.array([[20, 20], [80, 20], [80, 80], [20, 80]] * 120, float)[:478] + 0.5)
    result = SimpleNamespace(frame_index=np.array([3, 7, 9]), meshes=[None, mesh, None])
    avatar, got = video_build._open_mouth(make(), result, image, 7)
    assert len(avatar.bald) == len(opened) and got["teeth_from_photo"]
    assert got["teeth_rgb"] == pytest.approx([230 / 255, 225 / 255, 210 / 255], abs=0.01)
    avatar, got = video_build._open_mouth(make(), SimpleNamespace(frame_index=np.array([7]), meshes=None), image, 7)
    assert len(avatar.bald) == len(opened) and not got["teeth_from_photo"]
    monkeypatch.setattr(pipeline, "OPEN_MOUTH", True)
    avatar, got = video_build._open_mouth(make(), result, image, 7)
    assert len(avatar.bald) == len(bald) and got == {"by": "recon.pipeline"}
