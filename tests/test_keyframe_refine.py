"""`track.video_build.refine_keyframes` (a tracked keyframe's pose registered against the draft
build, for the hair's outline stage) and `multiview.VideoViews.outline_views` (the cameras that
stage measures with), on a known case: the avatar itself rendered at known poses, the keyframes
handed over with their yaw read short."""
from __future__ import annotations

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


def test_outline_views_take_the_outline_pose_camera_and_keep_the_rest():
    from avatarkit.synthetic.head_video import head_video_camera

    camera = head_video_camera(64, distance=0.5)
    rot, tra = np.array([0.02, -0.01, 0.0]), np.array([0.0, -0.05, -0.5])
    fit = SimpleNamespace(camera=camera, rotation=rot, translation=tra)
    ref_pose = pose_from_params([0.01, 0.0, 0.0, 0.0, -0.05, -0.5])
    a = pose_from_params([0.5, 0.0, 0.0, 0.0, -0.05, -0.5])
    b = pose_from_params([0.6, 0.02, 0.0, 0.001, -0.05, -0.5])
    image = np.zeros((64, 64, 3), np.uint8)
    keys = [Keyframe(image, ref_pose, 1.0, 0), Keyframe(image, a, 1.0, 1, outline_pose=b), Keyframe(image, a, 1.0, 2)]
    vv = VideoViews(np.zeros(10), keys)
    cams = keyframe_cameras(camera, pose_matrix(rot, tra), ref_pose, [k.pose for k in keys])
    views = [View(image, camera, None, 1.0, 0, True)] + [View(image, c, None, 1.0, k.frame) for k, c in
                                                           zip(keys[1:], cams[1:])]
    out = vv.outline_views(fit, views)
    assert out[0] is views[0] and out[2] is views[2]
    want = keyframe_cameras(camera, pose_matrix(rot, tra), ref_pose, [b])[0]
    np.testing.assert_allclose(out[1].camera.world_to_camera, want.world_to_camera, atol=1e-12)
    assert not np.allclose(out[1].camera.world_to_camera, views[1].camera.world_to_camera, atol=1e-3)
    assert out[1].frame == 1 and out[1].image is image
    # the outline pose equal to the pose: the camera `register` made
    keys[1].outline_pose = a.copy()
    np.testing.assert_allclose(vv.outline_views(fit, views)[1].camera.world_to_camera,
                               views[1].camera.world_to_camera, atol=1e-12)


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
