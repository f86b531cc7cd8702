"""`track.video_build.refine_keyframes` (a tracked keyframe's pose registered against the draft
build, for the hair's outline stage) and `multiview.VideoViews.outline_views` (the cameras that
stage measures with), on a known case: the avatar itself rendered at known poses, the keyframes
handed over with their yaw read short."""
from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.recon.multiview import Keyframe, View, VideoViews, keyframe_cameras, pose_matrix
from avatarkit.track.register import params_from_pose, pose_camera, pose_from_params


@pytest.fixture(scope="module")
def scene():
    from avatarkit.render import render
    from avatarkit.synthetic.head_video import head_video_camera
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    avatar = make_sample_avatar(n_hair=1200, n_bald=4000, style="short", cage_vertices=200)
    camera = head_video_camera(128, distance=0.5)
    ref_pose = pose_from_params([0.0, 0.0, 0.0, 0.0, -0.05, -0.5])
    draft = SimpleNamespace(rest_gaussians=avatar.rest_gaussians, head_model=avatar.head_model,
                            rest_head_vertices=avatar.rest_head_vertices,
                            provenance={"build": {"camera": camera.to_dict()}})
    gs = avatar.rest_gaussians()

    def frame(yaw_deg):
        truth = pose_from_params([math.radians(yaw_deg), 0.0, 0.0, 0.0, -0.05, -0.5])
        r = render(gs, pose_camera(camera, ref_pose, truth), background=(1.0, 1.0, 1.0))
        return truth, (np.clip(r.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)

    return draft, camera, ref_pose, frame


def _short(truth, degrees):
    """The pose `truth` with its yaw read `degrees` nearer the front."""
    p = params_from_pose(truth)
    p[0] -= math.copysign(math.radians(degrees), p[0])
    return pose_from_params(p)


def test_a_turned_keyframe_read_short_is_registered_at_its_yaw_for_the_outline_only(scene):
    from avatarkit.track.video_build import REFINE_BEYOND, refine_keyframes

    draft, camera, ref_pose, frame = scene
    ref_image = frame(0.0)[1]
    turned, turned_image = frame(40.0)
    left, left_image = frame(-35.0)
    near, near_image = frame(15.0)
    far, far_image = frame(60.0)
    keys = [Keyframe(ref_image, ref_pose, 1.0, 0), Keyframe(turned_image, _short(turned, 6.0), 1.0, 1),
            Keyframe(left_image, _short(left, 5.0), 1.0, 2), Keyframe(near_image, _short(near, 3.0), 1.0, 3),
            Keyframe(far_image, _short(far, 20.0), 1.0, 4), Keyframe(turned_image, _short(turned, 6.0), 1.0, 5)]
    given = [k.pose.copy() for k in keys]
    views = VideoViews(np.zeros(10), keys)
    figures = refine_keyframes(draft, views, tracked=5)
    # the keyframes turned past REFINE_MIN_YAW, on either side, land within 2 degrees of the truth
    assert [f["frame"] for f in figures] == [1, 2, 4]
    assert [f["at_bound"] for f in figures] == [False, False, True]
    # read 20 degrees short, beyond the search's reach: it stops at the far end, and says so
    assert abs(figures[2]["registered_deg"] - (40.0 + math.degrees(REFINE_BEYOND))) < 0.5
    for k, want in ((keys[1], 40.0), (keys[2], -35.0)):
        found = math.degrees(params_from_pose(k.outline_pose)[0])
        assert abs(found - want) < 2.0, (k.frame, found, want)
    assert abs(figures[0]["yaw_deg"] - 34.0) < 1e-6 and abs(figures[0]["registered_deg"] - 40.0) < 2.0
    # nothing else changes: the poses every other stage uses, the reference, a keyframe near the
    # front, and the rows past `tracked` (the frames registered at the turns' ends)
    for k, g in zip(keys, given):
        np.testing.assert_array_equal(k.pose, g)
    assert keys[0].outline_pose is None and keys[3].outline_pose is None and keys[5].outline_pose is None


def test_everywhere_replaces_the_pose_itself(scene):
    from avatarkit.track.video_build import refine_keyframes

    draft, camera, ref_pose, frame = scene
    turned, image = frame(40.0)
    keys = [Keyframe(frame(0.0)[1], ref_pose, 1.0, 0), Keyframe(image, _short(turned, 6.0), 1.0, 1)]
    refine_keyframes(draft, VideoViews(np.zeros(10), keys), tracked=2, everywhere=True)
    assert keys[1].outline_pose is None
    assert abs(math.degrees(params_from_pose(keys[1].pose)[0]) - 40.0) < 2.0


def test_everywhere_for_some_frames_replaces_only_their_poses(scene):
    """"registered-edge": the frames named (the tracking's edge) take the registered pose for every
    stage, the other turned keyframes for the outline alone."""
    from avatarkit.track.video_build import refine_keyframes

    draft, camera, ref_pose, frame = scene
    turned, image = frame(40.0)
    left, left_image = frame(-35.0)
    short_left = _short(left, 5.0)
    keys = [Keyframe(frame(0.0)[1], ref_pose, 1.0, 0), Keyframe(image, _short(turned, 6.0), 1.0, 7),
            Keyframe(left_image, short_left.copy(), 1.0, 8)]
    refine_keyframes(draft, VideoViews(np.zeros(10), keys), tracked=3, everywhere=frozenset({7, 99}))
    assert keys[1].outline_pose is None
    assert abs(math.degrees(params_from_pose(keys[1].pose)[0]) - 40.0) < 2.0
    np.testing.assert_array_equal(keys[2].pose, short_left)
    assert abs(math.degrees(params_from_pose(keys[2].outline_pose)[0]) + 35.0) < 2.0


def _outline_scene(size=64):
    """A fit whose rest head is a 6 cm ball in front of the yaw axis (a turn moves its
    silhouette), three keyframes as `VideoViews.register` makes them (the reference; one turned
    keyframe with an outline pose 0.1 rad further turned and 15 mm aside; one without), and the
    views with their heads."""
    from avatarkit.head.template import icosphere
    from avatarkit.recon.multiview import head_silhouette
    from avatarkit.synthetic.head_video import head_video_camera

    camera = head_video_camera(size, distance=0.5)
    rot, tra = np.array([0.02, -0.01, 0.0]), np.array([0.0, -0.05, -0.5])
    v, f = icosphere(2)
    fit = SimpleNamespace(camera=camera, rotation=rot, translation=tra,
                          rest_vertices=0.06 * v + np.array([0.0, 0.05, 0.08]), model=SimpleNamespace(faces=f))
    ref_pose = pose_from_params([0.01, 0.0, 0.0, 0.0, -0.05, -0.5])
    a = pose_from_params([0.5, 0.0, 0.0, 0.0, -0.05, -0.5])
    b = pose_from_params([0.6, 0.02, 0.0, 0.015, -0.05, -0.5])
    image = np.zeros((size, size, 3), np.uint8)
    keys = [Keyframe(image, ref_pose, 1.0, 0), Keyframe(image, a, 1.0, 1, outline_pose=b), Keyframe(image, a, 1.0, 2)]
    cams = keyframe_cameras(camera, pose_matrix(rot, tra), ref_pose, [k.pose for k in keys])
    views = [View(image, camera, None, 1.0, 0, True, head=head_silhouette(fit.rest_vertices, f, camera))]
    views += [View(image, c, None, 1.0, k.frame, head=head_silhouette(fit.rest_vertices, f, c))
              for k, c in zip(keys[1:], cams[1:])]
    return fit, VideoViews(np.zeros(10), keys), views, b


def test_outline_views_take_the_outline_pose_camera_and_keep_the_rest():
    from avatarkit.recon.multiview import head_silhouette

    fit, vv, views, b = _outline_scene()
    keys = vv.keyframes
    out = vv.outline_views(fit, views)
    assert out[0] is views[0] and out[2] is views[2]
    want = keyframe_cameras(fit.camera, pose_matrix(fit.rotation, fit.translation), keys[0].pose, [b])[0]
    np.testing.assert_allclose(out[1].camera.world_to_camera, want.world_to_camera, atol=1e-12)
    assert not np.allclose(out[1].camera.world_to_camera, views[1].camera.world_to_camera, atol=1e-3)
    assert out[1].frame == 1 and out[1].image is keys[1].image
    # the head the hull check joins to the person mask is seen by the registered camera, not the
    # joint fit's (the two differ by a few pixels' rim here)
    np.testing.assert_array_equal(out[1].head, head_silhouette(fit.rest_vertices, fit.model.faces, want))
    assert (out[1].head != views[1].head).sum() >= 20
    # the outline pose equal to the pose: the camera and head `register` made
    keys[1].outline_pose = keys[1].pose.copy()
    same = vv.outline_views(fit, views)[1]
    np.testing.assert_allclose(same.camera.world_to_camera, views[1].camera.world_to_camera, atol=1e-12)
    np.testing.assert_array_equal(same.head, views[1].head)


def test_the_hull_check_holds_hair_by_the_registered_head():
    """`silhouette_outside` on the outline views: with an empty person mask only the head holds
    points, and it is the head at the registered pose: a point on the ball's centre as the
    registered camera sees it is inside; one the joint fit's head covered but the registered one
    does not is outside."""
    from avatarkit.recon.multiview import silhouette_outside
    from avatarkit.recon.segment import BACKGROUND

    from avatarkit.recon.multiview import SILHOUETTE_MARGIN

    size = 256
    fit, vv, views, b = _outline_scene(size)
    views = [dataclasses.replace(v, labels=np.full(v.image.shape[:2], BACKGROUND, np.int32)) for v in views]
    out = vv.outline_views(fit, views)
    reg, tracked = out[1], views[1]
    centre = fit.rest_vertices.mean(axis=0)
    # points on the rays through the pixels only one of the two heads covers, at the ball's depth
    only_tracked = tracked.head & ~reg.head
    only_reg = reg.head & ~tracked.head
    assert only_tracked.sum() >= 20 and only_reg.sum() >= 20

    def on_rays(mask, cam):
        ys, xs = np.nonzero(mask)
        # well inside the band: the head is eroded by the margin before it is joined, and the
        # mask then dilated by it
        r = int(round(SILHOUETTE_MARGIN * size)) + 2
        keep = [i for i in range(len(xs)) if mask[max(ys[i] - r, 0):ys[i] + r + 1, max(xs[i] - r, 0):xs[i] + r + 1].all()]
        assert keep
        i = keep[len(keep) // 2]
        depth = cam.world_to_camera[:3] @ np.append(centre, 1.0)
        ray = np.array([(xs[i] + 0.5 - cam.cx) / cam.fx, (ys[i] + 0.5 - cam.cy) / cam.fy, 1.0]) * depth[2]
        return np.linalg.inv(cam.world_to_camera) @ np.append(ray, 1.0)

    p_reg = on_rays(only_reg, reg.camera)[:3]
    p_tracked = on_rays(only_tracked, reg.camera)[:3]
    assert silhouette_outside(np.stack([p_reg, p_tracked]), [reg]).tolist() == [0, 1]


def test_without_a_draft_the_turned_keyframes_are_not_trusted_by_the_outline():
    """No lost turn, no draft, no registration: a keyframe turned past REFINE_MIN_YAW keeps the
    joint fit's pose, which a fast turn reads short, so the outline stage skips it; registered
    ones and those near the front stay."""
    from avatarkit.track.video_build import REFINE_MIN_YAW, unregistered_turned

    deg = math.degrees(REFINE_MIN_YAW)
    ref = pose_from_params([0.1, 0.0, 0.0, 0.0, -0.05, -0.5])
    image = np.zeros((4, 4, 3), np.uint8)

    def key(yaw, frame):
        return Keyframe(image, pose_from_params([0.1 + math.radians(yaw), 0.0, 0.0, 0.0, -0.05, -0.5]), 1.0, frame)

    keys = [Keyframe(image, ref, 1.0, 0), key(deg - 3, 1), key(deg + 3, 2), key(-(deg + 10), 3), key(deg + 20, 4)]
    keys[4].outline_pose = keys[4].pose
    assert unregistered_turned(VideoViews(np.zeros(10), keys)) == [2, 3]


def _spied_turned(scene, monkeypatch, keyword, plate=None):
    """`register.register_frame` replaced by a spy that records the `keyword` argument of each
    call (and returns the guess), and one turned frame (clip index 2, video frame 9) of a
    one-keyframe view to register: (seen, image, call) where call() runs `register_turned`."""
    import avatarkit.track.keyframes as keyframes
    import avatarkit.track.register as register
    import avatarkit.track.video_build as vb

    draft, camera, ref_pose, frame = scene
    image = frame(0.0)[1]
    seen = []

    def spy(gaussians, image, reference_camera, reference_pose, guess, yaw_range, **kw):
        seen.append(kw.get(keyword))
        return register.Registration(np.asarray(guess), 0.0, 1)

    monkeypatch.setattr(register, "register_frame", spy)
    monkeypatch.setattr(keyframes, "read_frames", lambda video, frames: {int(f): image for f in frames})
    result = SimpleNamespace(frame_index=np.array([0, 7, 9]), raw={"rotation": np.zeros((3, 3))})
    views = VideoViews(np.zeros(10), [Keyframe(image, ref_pose, 1.0, 0)], {}, plate)
    turned = [vb.TurnedFrame(2, 1, math.radians(40.0), math.radians(100.0))]
    return seen, image, lambda: vb.register_turned(draft, result, turned, views, "unused.mp4", 1.0)


@pytest.mark.parametrize("shifted", [False, True])
def test_register_turned_hands_the_shifted_switch_to_the_registration(scene, monkeypatch, shifted):
    import avatarkit.track.video_build as vb

    seen, _, register_turned = _spied_turned(scene, monkeypatch, "shifted")
    monkeypatch.setattr(vb, "REGISTER_SHIFTED", shifted)
    added, figures = register_turned()
    assert seen == [shifted] and [k.frame for k in added] == [9]


@pytest.mark.parametrize("stages", [(), ("turned",), ("refine",), ("turned", "refine")])
def test_the_hair_discount_switch_reaches_the_registrations_it_names(scene, monkeypatch, stages):
    """`HAIR_DISCOUNT` (read at call time): "turned" for `register_turned`, "refine" for
    `refine_keyframes`; each asks `register_frame` to discount the draft's hair or not."""
    import avatarkit.track.video_build as vb

    draft, camera, ref_pose, frame = scene
    seen, image, register_turned = _spied_turned(scene, monkeypatch, "discount_hair")
    monkeypatch.setattr(vb, "HAIR_DISCOUNT", stages)
    monkeypatch.setattr(vb, "SKIN_POSE", ())
    register_turned()
    turned_pose = pose_from_params([math.radians(40.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    vb.refine_keyframes(draft, VideoViews(np.zeros(10), [Keyframe(image, ref_pose, 1.0, 0),
                                                         Keyframe(image, turned_pose, 1.0, 1)]), tracked=2)
    assert seen == ["turned" in stages, "refine" in stages]


def _sphere_views():
    """A sphere "fit" seen from the front and four keyframes at yaw 0, 30, -80 and 80 degrees
    (frames 10, 11, 55, 20), the last two registered at the turns' ends: (fit, image, views)."""
    import trimesh

    from avatarkit.render.camera import Camera

    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.08)
    camera = Camera.orbit(np.zeros(3), 0.0, 0.0, 0.5, 35.0, 32, 32)
    fit = SimpleNamespace(camera=camera, rotation=np.zeros(3), translation=np.zeros(3),
                          rest_vertices=np.asarray(mesh.vertices), model=SimpleNamespace(faces=np.asarray(mesh.faces)))
    image = np.zeros((32, 32, 3), np.uint8)
    poses = [pose_from_params([math.radians(y), 0, 0, 0, 0, -0.5]) for y in (0.0, 30.0, -80.0, 80.0)]
    keys = [Keyframe(image, p, 1.0, f) for p, f in zip(poses, (10, 11, 55, 20))]
    return fit, image, VideoViews(np.zeros(10), keys, {"registered": [{"frame": 55}, {"frame": 20}]})


def test_the_views_of_the_frames_registered_at_the_turns_ends_are_marked(monkeypatch):
    """`VideoViews.register` marks the views of the frames `register_turned` added
    (`View.info["turned_end"]`, read by `recon.hair_hull.TURNED_MARGIN`), and no other."""
    import avatarkit.recon.multiview as mv
    import avatarkit.recon.portrait as portrait
    from avatarkit.errors import AvatarKitError

    def no_face(*a, **k):
        raise AvatarKitError("no face")

    monkeypatch.setattr(portrait, "analyze_portrait", no_face)
    monkeypatch.setattr(mv, "RELABEL_KEYFRAMES", False)
    fit, image, views = _sphere_views()
    made = views.register(fit, image, np.zeros((32, 32), np.int32))
    assert [v.info.get("turned_end", False) for v in made] == [False, False, True, True]


def test_only_the_turned_end_frames_relabel_strands_beyond_the_reach(monkeypatch):
    """`VideoViews.register` hands `RELABEL_CONNECTED` to `relabel_head` for the views of the
    frames registered at the turns' ends alone (`RELABEL_CONNECTED_IN` "turned_end"), to every
    keyframe's with "all"."""
    import avatarkit.recon.multiview as mv
    import avatarkit.recon.portrait as portrait
    from avatarkit.errors import AvatarKitError

    def no_face(*a, **k):
        raise AvatarKitError("no face")

    calls = []

    def spy(labels, image, head, colours, reach=None, connected=None, wall=None):
        calls.append(connected)
        return labels

    monkeypatch.setattr(portrait, "analyze_portrait", no_face)
    monkeypatch.setattr(mv, "reference_colours", lambda image, labels: object())
    monkeypatch.setattr(mv, "relabel_head", spy)
    monkeypatch.setattr(mv, "RELABEL_CONNECTED", 0.15)
    fit, image, views = _sphere_views()
    views.register(fit, image, np.zeros((32, 32), np.int32))
    assert calls == [None, 0.15, 0.15]
    calls.clear()
    monkeypatch.setattr(mv, "RELABEL_CONNECTED_IN", "all")
    views.register(fit, image, np.zeros((32, 32), np.int32))
    assert calls == [0.15, 0.15, 0.15]


def test_skin_views_take_the_skin_pose_camera_outside_the_drafts(monkeypatch):
    """`VideoViews.skin_views`: a keyframe with a `skin_pose` is seen by that pose's camera (and
    head) for the bald layer, the rest are the same view objects; a registration draft keeps
    every view when `SKIN_POSE_IN_DRAFTS` is off."""
    import avatarkit.recon.multiview as mv
    from avatarkit.recon.multiview import head_silhouette

    monkeypatch.setattr(mv, "SKIN_POSE_IN_DRAFTS", False)
    fit, vv, views, b = _outline_scene()
    keys = vv.keyframes
    keys[2].skin_pose = b
    out = vv.skin_views(fit, views)
    assert out[0] is views[0] and out[1] is views[1]
    want = keyframe_cameras(fit.camera, pose_matrix(fit.rotation, fit.translation), keys[0].pose, [b])[0]
    np.testing.assert_allclose(out[2].camera.world_to_camera, want.world_to_camera, atol=1e-12)
    np.testing.assert_array_equal(out[2].head, head_silhouette(fit.rest_vertices, fit.model.faces, want))
    assert out[2].frame == 2 and out[2].image is keys[2].image
    draft = dataclasses.replace(vv, info={"draft": True})
    assert all(o is v for o, v in zip(draft.skin_views(fit, views), views))
    monkeypatch.setattr(mv, "SKIN_POSE_IN_DRAFTS", True)
    np.testing.assert_allclose(draft.skin_views(fit, views)[2].camera.world_to_camera, want.world_to_camera, atol=1e-12)


@pytest.mark.parametrize("discounted", [True, False])
def test_the_skin_pose_switch_keeps_the_plain_pose_and_hands_the_gated_one_to_the_bald_layer(scene, monkeypatch,
                                                                                           discounted):
    """`SKIN_POSE` (read at call time): its registrations discount the draft's hair and keep the
    plain search (`keep_plain`); the keyframe's pose (or outline pose) is the plain search's, its
    `skin_pose` the gated pose where the gate took the discounted one, else None."""
    import avatarkit.track.keyframes as keyframes
    import avatarkit.track.register as register
    import avatarkit.track.video_build as vb

    draft, camera, ref_pose, frame = scene
    image = frame(0.0)[1]
    plain = pose_from_params([math.radians(50.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    skin = pose_from_params([math.radians(58.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    seen = []

    def spy(gaussians, image, reference_camera, reference_pose, guess, yaw_range, **kw):
        seen.append((kw.get("discount_hair"), kw.get("keep_plain")))
        return register.Registration(skin if discounted else plain, 0.0, 1, plain_pose=plain, discounted=discounted)

    monkeypatch.setattr(register, "register_frame", spy)
    monkeypatch.setattr(keyframes, "read_frames", lambda video, frames: {int(f): image for f in frames})
    monkeypatch.setattr(vb, "SKIN_POSE", ("turned", "refine"))
    result = SimpleNamespace(frame_index=np.array([0, 7, 9]), raw={"rotation": np.zeros((3, 3))})
    views = VideoViews(np.zeros(10), [Keyframe(image, ref_pose, 1.0, 0)])
    added, figures = vb.register_turned(draft, result, [vb.TurnedFrame(2, 1, math.radians(40.0), math.radians(100.0))],
                                        views, "unused.mp4", 1.0)
    np.testing.assert_array_equal(added[0].pose, plain)
    assert (added[0].skin_pose is skin) if discounted else (added[0].skin_pose is None)
    turned_pose = pose_from_params([math.radians(40.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    keys = [Keyframe(image, ref_pose, 1.0, 0), Keyframe(image, turned_pose, 1.0, 1, skin_pose=turned_pose),
            Keyframe(image, turned_pose, 1.0, 2)]
    vb.refine_keyframes(draft, VideoViews(np.zeros(10), keys), tracked=3, everywhere=frozenset({2}))
    np.testing.assert_array_equal(keys[1].outline_pose, plain)
    np.testing.assert_array_equal(keys[1].pose, turned_pose)
    np.testing.assert_array_equal(keys[2].pose, plain)
    for k in keys[1:]:
        # this round decides: a skin pose from before is replaced (or dropped)
        assert (k.skin_pose is skin) if discounted else (k.skin_pose is None)
    assert seen == [(True, True)] * 3
    # off: no keep_plain, no skin pose
    monkeypatch.setattr(vb, "SKIN_POSE", ())
    seen.clear()
    added, _ = vb.register_turned(draft, result, [vb.TurnedFrame(2, 1, math.radians(40.0), math.radians(100.0))],
                                  views, "unused.mp4", 1.0)
    assert seen == [(False, False)] and added[0].skin_pose is None


@pytest.mark.parametrize("recede_skin", [False, True])
def test_the_colour_stage_samples_the_bald_layer_from_the_skin_views(monkeypatch, recede_skin):
    """`VideoViews.colour`: `colour_from_views` gets the views for every layer and the skin views
    for the bald rows (`bald_views`); `recede_outline` votes with the outline views, the skin
    views where a keyframe has a skin pose when `SKIN_POSE_RECEDE`."""
    import avatarkit.recon.multiview as mv
    from avatarkit.gaussians.gaussian_set import GaussianSet

    fit, vv, views, b = _outline_scene()
    fit.model.regions = {}
    vv.keyframes[2].skin_pose = b
    got = {}

    def colour_spy(bald, hair, views, normals, keep, body, scalp, drop_skin_hair=False, neck=None, bald_views=None,
                   hidden_bald=None, hair_facing=None):
        got["views"], got["bald_views"] = views, bald_views
        return bald, hair, {"_only_others": (np.zeros((0, 3)), np.zeros((0, 3), np.float32))}

    def recede_spy(bald, hair, views, fit):
        got["recede"] = views
        return bald, {}

    monkeypatch.setattr(mv, "colour_from_views", colour_spy)
    monkeypatch.setattr(mv, "recede_outline", recede_spy)
    monkeypatch.setattr(mv, "RECEDE_KEYFRAMES", True)
    monkeypatch.setattr(mv, "SKIN_POSE_RECEDE", recede_skin)
    g = GaussianSet.empty()
    sdf = SimpleNamespace(query=lambda p: (np.zeros(len(p)), np.zeros((len(p), 3))))
    vv.colour(g, g, views, fit, sdf)
    skin = vv.skin_views(fit, views)
    assert got["views"] is views
    assert [x is y for x, y in zip(got["bald_views"], views)] == [True, True, False]
    np.testing.assert_array_equal(got["bald_views"][2].camera.world_to_camera, skin[2].camera.world_to_camera)
    outline = vv.outline_views(fit, views)
    # the outline pose's view (no skin pose there)
    np.testing.assert_array_equal(got["recede"][1].camera.world_to_camera, outline[1].camera.world_to_camera)
    want = skin[2] if recede_skin else outline[2]
    np.testing.assert_array_equal(got["recede"][2].camera.world_to_camera, want.camera.world_to_camera)


@pytest.mark.parametrize("stages", [(), ("turned",), ("refine",), ("turned", "refine")])
def test_the_plate_switch_hands_the_videos_plate_to_the_registrations_it_names(scene, monkeypatch, stages):
    """`REGISTER_PLATE` (read at call time): "turned" for `register_turned`, "refine" for
    `refine_keyframes`; each hands the views' wall plate to `register_frame` or none."""
    import avatarkit.track.video_build as vb

    draft, camera, ref_pose, frame = scene
    plate = object()
    seen, image, register_turned = _spied_turned(scene, monkeypatch, "plate", plate)
    monkeypatch.setattr(vb, "REGISTER_PLATE", stages)
    register_turned()
    turned_pose = pose_from_params([math.radians(40.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    vb.refine_keyframes(draft, VideoViews(np.zeros(10), [Keyframe(image, ref_pose, 1.0, 0),
                                                         Keyframe(image, turned_pose, 1.0, 1)], {}, plate),
                        tracked=2)
    assert seen == [plate if "turned" in stages else None, plate if "refine" in stages else None]


@pytest.mark.parametrize("rule", ["keep", "far", "drop", "beyond"])
@pytest.mark.parametrize("window", [(40.0, 60.0), (76.0, 100.0)])
def test_a_turn_end_registered_at_its_searchs_end_is_no_minimum(scene, monkeypatch, rule, window):
    """A frame turned 70 degrees searched over 40..60 (its minimum beyond the far end) or 76..100
    (before the near end): the yaw found lies at the search's end (`at_bound`, against the range
    searched). "keep" keeps the keyframe there, "drop" drops it, "far" drops it at the far end
    only, "beyond" searches the next `SEARCH_BEYOND` past a far end (and finds the frame's yaw) and
    drops a near end's."""
    import avatarkit.track.keyframes as keyframes
    import avatarkit.track.video_build as vb

    draft, camera, ref_pose, frame = scene
    truth, image = frame(70.0)
    monkeypatch.setattr(keyframes, "read_frames", lambda video, frames: {int(f): image for f in frames})
    monkeypatch.setattr(vb, "TURNED_AT_BOUND", rule)
    monkeypatch.setattr(vb, "SKIN_POSE", ())
    result = SimpleNamespace(frame_index=np.array([0, 7, 9]), raw={"rotation": np.zeros((3, 3))})
    views = VideoViews(np.zeros(10), [Keyframe(frame(0.0)[1], ref_pose, 1.0, 0)])
    lo, hi = (math.radians(v) for v in window)
    added, figures = vb.register_turned(draft, result, [vb.TurnedFrame(2, 1, lo, hi)], views, "unused.mp4", 1.0)
    end = "far" if window[1] < 70 else "near"
    assert figures[0]["at_bound"] == (end if rule != "beyond" or end == "near" else None)
    if rule == "keep" or (rule == "far" and end == "near"):
        assert [k.frame for k in added] == [9]
        assert abs(figures[0]["yaw_deg"] - (window[1] if end == "far" else window[0])) < 0.3
    elif rule == "beyond" and end == "far":
        assert [k.frame for k in added] == [9] and abs(figures[0]["yaw_deg"] - 70.0) < 2.5
    else:
        assert added == [] and figures[0]["dropped"]
