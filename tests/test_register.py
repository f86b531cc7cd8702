"""`track.register`: a frame the face mesh lost, registered by analysis by synthesis against an
avatar, on a known case (the avatar itself rendered at a known, far-turned pose)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from avatarkit.track.register import (params_from_pose, photometric_error, pose_camera, pose_from_params,
                                      register_frame, register_frame_exhaustive)


@pytest.fixture(scope="module")
def scene():
    from avatarkit.render import render
    from avatarkit.synthetic.head_video import head_video_camera
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    avatar = make_sample_avatar(n_hair=1200, n_bald=4000, style="short", cage_vertices=200)
    gs = avatar.rest_gaussians()
    # the reference keyframe's camera and pose in the tracker's convention: the camera on +Z
    # 0.5 m from a point 5 cm above the neck joint, the head at rest (W_ref = C M_r)
    camera = head_video_camera(128, distance=0.5)
    ref_pose = pose_from_params([0.0, 0.0, 0.0, 0.0, -0.05, -0.5])
    truth = pose_from_params([math.radians(70.0), math.radians(4.0), math.radians(-2.0), 0.004, -0.052, -0.505])
    frame = render(gs, pose_camera(camera, ref_pose, truth), background=(1.0, 1.0, 1.0))
    image = (np.clip(frame.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    assert frame.alpha.mean() > 0.1                       # the head is in the picture
    return gs, camera, ref_pose, truth, image


def test_pose_params_round_trip_and_the_reference_pose_gives_the_reference_camera(scene):
    gs, camera, ref_pose, truth, _ = scene
    np.testing.assert_allclose(pose_from_params(params_from_pose(truth)), truth, atol=1e-12)
    np.testing.assert_allclose(pose_camera(camera, ref_pose, ref_pose).world_to_camera, camera.world_to_camera,
                               atol=1e-12)
    # the tracker's frame is the camera's: turning the head by P is C P in this set-up
    c = np.diag([1.0, -1.0, -1.0, 1.0])
    np.testing.assert_allclose(pose_camera(camera, ref_pose, truth).world_to_camera, c @ truth, atol=1e-12)


def test_a_scaled_camera_puts_every_splat_where_the_smaller_picture_has_it(scene):
    from avatarkit.render import render

    gs, camera, ref_pose, truth, _ = scene
    cam = pose_camera(camera, ref_pose, truth)
    full = render(gs, cam).meta["means2d"]
    half = render(gs, cam.with_size(64, 64)).meta["means2d"]
    both = (render(gs, cam).meta["radii"] > 0) & (render(gs, cam.with_size(64, 64)).meta["radii"] > 0)
    both = both.reshape(len(full), -1).all(axis=1)
    assert both.sum() > 100
    # pixel (i, j) covers [i, i+1) x [j, j+1) at both sizes: positions scale with the grid
    np.testing.assert_allclose(half[both], 0.5 * full[both], atol=1e-4)


def test_a_far_turned_frame_is_registered_from_a_guess_25_degrees_short(scene):
    gs, camera, ref_pose, truth, image = scene
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    reg = register_frame(gs, image, camera, ref_pose, guess, (math.radians(40.0), math.radians(100.0)))
    found, want = np.degrees(params_from_pose(reg.pose)[:3]), np.degrees(params_from_pose(truth)[:3])
    assert abs(found[0] - want[0]) < 2.0, (found, want)
    assert abs(found[1] - want[1]) < 2.0, (found, want)
    assert np.linalg.norm(reg.pose[:3, 3] - truth[:3, 3]) < 0.01
    # the coarse grid alone (pitch, roll and position the guess's) is further off: the local
    # refinement is what gets within 2 degrees
    assert reg.error < reg.coarse[:, 1].min()


def test_the_fast_registration_agrees_with_the_exhaustive_grid(scene):
    gs, camera, ref_pose, truth, image = scene
    guess = pose_from_params([math.radians(60.0), 0.0, math.radians(-2.0), 0.004, -0.052, -0.505])
    window = (math.radians(60.0), math.radians(80.0))
    fast = register_frame(gs, image, camera, ref_pose, guess, window)
    slow = register_frame_exhaustive(gs, image, camera, ref_pose, guess, window)
    assert abs(np.degrees(fast.yaw_pitch_roll[0] - slow.yaw_pitch_roll[0])) <= 2.0
    assert abs(np.degrees(fast.yaw_pitch_roll[1] - slow.yaw_pitch_roll[1])) <= 2.0
    # both at the truth's yaw (the grid holds it to its step) and scored by the same error
    assert abs(np.degrees(slow.yaw_pitch_roll[0]) - 70.0) <= 1.0
    target = image.astype(np.float64) / 255.0
    assert photometric_error(gs, pose_camera(camera, ref_pose, slow.pose), target, (1.0, 1.0, 1.0)) == \
        pytest.approx(slow.error, rel=1e-9)


def _scaled(gs, k: float, centre):
    """The Gaussians grown by k about centre (3,): a build whose head is k times too large."""
    import dataclasses

    c = np.asarray(centre, np.float32)
    return dataclasses.replace(gs, means=c + k * (gs.means - c), scales=gs.scales * k,
                               extras=dict(gs.extras))


def test_a_silhouette_moved_by_a_known_similarity_is_laid_back_exactly():
    import cv2

    from avatarkit.track.register import _similarity, align_silhouette

    yy, xx = np.mgrid[:96, :96]
    # an off-centre, lopsided blob (a disc and a bar), so neither scale nor shift is ambiguous
    blob = (((xx - 44) ** 2 + (yy - 40) ** 2 < 18 ** 2) | ((abs(xx - 60) < 4) & (abs(yy - 55) < 14))).astype(np.float32)
    mask = cv2.warpAffine(blob, _similarity(1.1, 3, -4, 96, 96), (96, 96)) > 0.5
    s, dx, dy, iou = align_silhouette(blob, mask, 96)
    assert (s, dx, dy) == (pytest.approx(1.1), 3, -4) and iou == pytest.approx(1.0)


def test_a_build_too_large_registers_at_the_frames_yaw_and_its_pose_lays_it_over_the_frame(scene):
    from avatarkit.render import render
    from avatarkit.track.register import SIZE, _target, background_colour, register_aligned, silhouette

    gs, camera, ref_pose, truth, image = scene
    centre = gs.means.mean(0)
    big = _scaled(gs, 1.08, centre)             # the one photo's guess of the head's size, 8 % off
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    reg = register_aligned(big, image, camera, ref_pose, guess, window, centre)
    found, want = np.degrees(params_from_pose(reg.pose)[:3]), np.degrees(params_from_pose(truth)[:3])
    assert abs(found[0] - want[0]) < 2.0, (found, want)
    assert abs(found[1] - want[1]) < 2.0, (found, want)
    # the pose found puts the large head where the frame's is, at the depth that makes it the
    # frame's size: its silhouette overlays the frame's
    target = _target(image, SIZE)
    cam = pose_camera(camera.with_size(target.shape[1], target.shape[0]), ref_pose, reg.pose)
    a = render(big, cam).alpha > 0.5
    m = silhouette(target, background_colour(target))
    assert (a & m).sum() / (a | m).sum() > 0.9


@pytest.fixture(scope="module")
def moved_scene(scene):
    """The scene's head turned 75 degrees and 3 cm to the side of where the guess has it (a
    person turns about the neck, not the head's origin)."""
    from avatarkit.render import render

    gs, camera, ref_pose, _, _ = scene
    truth = pose_from_params([math.radians(75.0), 0.0, 0.0, 0.03, -0.05, -0.5])
    frame = render(gs, pose_camera(camera, ref_pose, truth), background=(1.0, 1.0, 1.0))
    return truth, (np.clip(frame.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def test_the_shifted_grid_registers_a_head_moved_off_the_guess_and_never_ends_higher(scene, moved_scene):
    gs, camera, ref_pose, _, _ = scene
    truth, image = moved_scene
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    plain = register_frame(gs, image, camera, ref_pose, guess, window)
    shifted = register_frame(gs, image, camera, ref_pose, guess, window, shifted=True)
    found = np.degrees(params_from_pose(shifted.pose)[:3])
    assert abs(found[0] - 75.0) < 2.0 and abs(found[1]) < 2.0, found
    assert np.linalg.norm(shifted.pose[:3, 3] - truth[:3, 3]) < 0.01
    # the plain grid's refinement is one of the two the shifted search runs: it never ends lower
    assert shifted.error <= plain.error + 1e-12
    assert shifted.evaluations > plain.evaluations


def test_the_shifted_grid_finds_the_yaw_whose_minimum_lies_off_the_guess_position():
    """A known answer: two basins, a shallow one at the guess's position (yaw 55 degrees, tx 0)
    and the true one at yaw 80, tx 3 cm. At tx 0 every yaw near 80 costs more than 55 does, so
    the plain grid starts the refinement in the shallow basin, where it stays; moving each grid
    yaw's head to fit finds the true basin."""
    from avatarkit.track.register import yaw_then_pattern_search

    def cost(p) -> float:
        yaw, tx = math.degrees(p[0]), p[3]
        shallow = 0.5 + ((yaw - 55.0) / 10.0) ** 2 + (tx / 0.02) ** 2
        true = ((yaw - 80.0) / 5.0) ** 2 + ((tx - 0.03) / 0.02) ** 2
        return min(shallow, true)

    start = np.array([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    steps = (math.radians(2.0), math.radians(2.0), math.radians(2.0), 0.004, 0.004, 0.01)
    plain, e_plain, _ = yaw_then_pattern_search(cost, start, window, math.radians(4.0), steps, 3)
    shifted, e_shifted, _ = yaw_then_pattern_search(cost, start, window, math.radians(4.0), steps, 3,
                                                    shift_steps=(0.008, 0.008))
    assert abs(math.degrees(plain[0]) - 55.0) < 1.0 and e_plain == pytest.approx(0.5, abs=1e-3)
    assert abs(math.degrees(shifted[0]) - 80.0) < 0.5 and abs(shifted[3] - 0.03) < 0.001
    assert e_shifted < 1e-2


def _hair_turned(gs, degrees: float):
    """The Gaussians with their hair (`part` 1) turned `degrees` about the head's vertical axis
    through the bald layer's centre: a draft whose hair lies where the frame's does not (its
    outline and streaks off the face's), the bald layer as it was."""
    from scipy.spatial.transform import Rotation

    hair = np.asarray(gs.extras["part"]) == 1
    c = gs.means[~hair].mean(0)
    r = Rotation.from_euler("y", degrees, degrees=True)
    means = gs.means.copy()
    means[hair] = c + r.apply(gs.means[hair] - c)
    quats = gs.quats.copy()
    quats[hair] = (r * Rotation.from_quat(gs.quats[hair][:, [1, 2, 3, 0]])).as_quat()[:, [3, 0, 1, 2]]
    return gs.replace(means=means, quats=quats)


def test_a_draft_whose_hair_is_off_its_head_reads_short_unless_the_hair_is_discounted(scene):
    """The known case of the mesh subject's turned frames (docs/video-build.md, session 24): the
    frame is the avatar at 70 degrees; the draft is the same avatar with its hair turned 20
    degrees on the head. Every pixel counted, the pose splits the difference between the face
    and the hair (several degrees short); with the hair discounted the skin decides the yaw."""
    gs, camera, ref_pose, truth, image = scene
    draft = _hair_turned(gs, 20.0)
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    plain = register_frame(draft, image, camera, ref_pose, guess, window)
    found = register_frame(draft, image, camera, ref_pose, guess, window, discount_hair=True)
    want = np.degrees(params_from_pose(truth)[:3])
    plain_yaw, yaw = (float(np.degrees(params_from_pose(r.pose)[0])) for r in (plain, found))
    assert plain_yaw < want[0] - 5.0, plain_yaw
    assert abs(yaw - want[0]) < 2.0, yaw
    # the rest of the pose is searched again by every pixel at that yaw: the error returned is
    # the plain one there, and the position stays the frame's
    target = _target_of(image)
    assert found.error == pytest.approx(photometric_error(draft, pose_camera(camera.with_size(*target.shape[1::-1]),
                                                                             ref_pose, found.pose),
                                                          target, (1.0, 1.0, 1.0)), rel=1e-9)
    assert np.linalg.norm(found.pose[:3, 3] - truth[:3, 3]) < 0.01


def test_the_hair_discounted_yaw_replaces_the_plain_pose_only_when_turned_further_by_the_gate(scene, monkeypatch):
    """`HAIR_GATE`: the plain search's pose is kept unless the hair-discounted yaw is turned
    further from the reference than the plain one by more than the gate (the draft's hair turned
    20 degrees: the discount reads ~6 degrees further than every pixel; turned -12 degrees, the
    two agree)."""
    import avatarkit.track.register as register

    gs, camera, ref_pose, truth, image = scene
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    for degrees, gate, taken in ((20.0, 3.0, True), (20.0, 30.0, False), (-12.0, 3.0, False)):
        monkeypatch.setattr(register, "HAIR_GATE", math.radians(gate))
        draft = _hair_turned(gs, degrees)
        plain = register_frame(draft, image, camera, ref_pose, guess, window)
        found = register_frame(draft, image, camera, ref_pose, guess, window, discount_hair=True)
        assert found.evaluations > 2 * plain.evaluations     # both searches ran
        if taken:
            assert params_from_pose(found.pose)[0] > params_from_pose(plain.pose)[0] + math.radians(gate)
        else:
            np.testing.assert_array_equal(found.pose, plain.pose)
            assert found.error == plain.error


def _target_of(image):
    from avatarkit.track.register import _target

    return _target(image, None if max(image.shape[:2]) <= 96 else 96)


def test_the_hair_discount_weighs_each_pixel_by_the_share_that_is_not_hair(scene):
    from avatarkit.render import render
    from avatarkit.track.register import hair_marker, hair_share

    gs, camera, ref_pose, truth, image = scene
    cam = pose_camera(camera, ref_pose, truth).with_size(64, 64)
    target = np.full((64, 64, 3), 0.5)
    marker = hair_marker(gs)
    share = hair_share(marker, cam)
    part = np.asarray(gs.extras["part"])
    # the hair's weight in the composite: at most its own coverage (the bald layer in front of
    # it takes its share), none where no hair is drawn, all of a pixel where it is opaque in front
    alone = render(gs.subset(part == 1), cam).alpha
    assert (share <= alone + 1e-5).all()
    assert (share[alone < 1e-4] < 1e-4).all()
    assert share.max() > 0.5 and (share < 0.05).mean() > 0.5
    rgb = np.clip(render(gs, cam, background=(1.0, 1.0, 1.0)).rgb, 0, 1)
    err = np.mean((rgb - target) ** 2, axis=-1)
    w = 1.0 - share
    assert photometric_error(gs, cam, target, (1.0, 1.0, 1.0), hair=marker) == \
        pytest.approx(float((w * err).sum() / w.sum()), rel=1e-6)
    assert photometric_error(gs, cam, target, (1.0, 1.0, 1.0)) == pytest.approx(float(err.mean()), rel=1e-6)
    # a set without hair has no marker: the plain error
    assert hair_marker(gs.subset(part == 0)) is None
    assert hair_marker(gs.replace(extras={})) is None


@pytest.fixture(scope="module")
def split_registration(scene):
    """The frame at 70 degrees registered against the draft whose hair is turned 20 degrees on
    its head, with the hair discounted and the plain search kept (`keep_plain`, the video
    build's `SKIN_POSE`), and plainly: (draft, both, plain)."""
    gs, camera, ref_pose, truth, image = scene
    draft = _hair_turned(gs, 20.0)
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    both = register_frame(draft, image, camera, ref_pose, guess, window, discount_hair=True, keep_plain=True)
    plain = register_frame(draft, image, camera, ref_pose, guess, window)
    return draft, both, plain


def test_the_split_registration_returns_the_plain_pose_to_the_bit_and_the_skins(scene, split_registration):
    """keep_plain: the plain search's pose rides along (`plain_pose`, the same search as a plain
    registration's, to the bit) whichever pose the gate takes; here the discounted one (near
    the truth, `discounted`)."""
    gs, camera, ref_pose, truth, image = scene
    _, both, plain = split_registration
    np.testing.assert_array_equal(both.plain_pose, plain.pose)
    assert both.discounted and not plain.discounted and plain.plain_pose is None
    assert abs(math.degrees(params_from_pose(both.pose)[0] - params_from_pose(truth)[0])) < 2.0
    assert params_from_pose(plain.pose)[0] < params_from_pose(truth)[0] - math.radians(5.0)


@pytest.mark.parametrize("gate", [30.0, None])
def test_the_split_registration_keeps_the_plain_pose_when_the_gate_does(scene, split_registration, monkeypatch, gate):
    """A gate wider than the disagreement: `pose` is the plain search's, not discounted; no gate:
    the discounted pose, the plain search still run for `plain_pose`."""
    import avatarkit.track.register as register

    gs, camera, ref_pose, truth, image = scene
    monkeypatch.setattr(register, "HAIR_GATE", None if gate is None else math.radians(gate))
    draft, both, plain = split_registration
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    found = register_frame(draft, image, camera, ref_pose, guess, (math.radians(40.0), math.radians(100.0)),
                           discount_hair=True, keep_plain=True)
    np.testing.assert_array_equal(found.plain_pose, plain.pose)
    assert found.discounted == (gate is None)
    np.testing.assert_array_equal(found.pose, plain.pose if gate else both.pose)


def test_the_bald_layer_coloured_from_the_skin_pose_lands_where_the_truth_has_it(scene, split_registration):
    """The layer split (`multiview.colour_from_views(bald_views=)`, docs/video-build.md, session
    25): the frame is the avatar at 70 degrees, the draft's hair turned 20 degrees. The bald
    discs sampled from the frame with the skin's (hair-discounted) pose take nearly the colours
    the truth's pose samples, from the plain pose (several degrees short) they do not; the hair's samples are the
    plain pose's either way. The bald layer is striped about the head's vertical axis (a
    period of 40 degrees of azimuth) so that a pose a few degrees off reads other stripes."""
    from avatarkit.recon.multiview import View, colour_from_views
    from avatarkit.render import render

    gs, camera, ref_pose, truth, _ = scene
    _, both, plain = split_registration
    part = np.asarray(gs.extras["part"])
    centre = gs.means[part == 0].mean(0)
    rel = np.asarray(gs.means, np.float64) - centre
    stripes = 0.5 + 0.4 * np.sin(np.arctan2(rel[:, 0], rel[:, 2]) * 360.0 / 40.0)       # (N,)
    rgb = np.asarray(gs.colors, np.float32).copy()
    rgb[part == 0] = np.stack([stripes, 1.0 - stripes, np.full_like(stripes, 0.5)], 1)[part == 0]
    gs = gs.with_colors(rgb)
    frame = render(gs, pose_camera(camera, ref_pose, truth), background=(1.0, 1.0, 1.0))
    image = (np.clip(frame.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    bald, hair = gs.subset(part == 0), gs.subset(part == 1)
    normals = np.asarray(gs.means, np.float64)[np.r_[np.flatnonzero(part == 0), np.flatnonzero(part == 1)]] - centre
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    # the reference view: the frame itself at the reference pose would disagree; a blank view that
    # sees nothing keeps the test to the turned keyframe
    blank = View(np.full_like(image, 255), pose_camera(camera, ref_pose, ref_pose), None, 0.0, 0, True)
    at = {name: View(image, pose_camera(camera, ref_pose, p), None, 1.0, 1, False)
          for name, p in (("plain", plain.pose), ("skin", both.pose), ("truth", truth))}
    grey = [g.with_colors(np.full((len(g), 3), 0.5, np.float32)) for g in (bald, hair)]

    def coloured(views, bald_views=None):
        b, h, _ = colour_from_views(grey[0], grey[1], views, normals, bald_views=bald_views)
        return b.colors, h.colors

    b_truth, _ = coloured([blank, at["truth"]])
    b_plain, h_plain = coloured([blank, at["plain"]])
    b_split, h_split = coloured([blank, at["plain"]], [blank, at["skin"]])
    seen = (np.abs(b_truth - 0.5).sum(1) > 0) & (np.abs(b_plain - 0.5).sum(1) > 0) & (np.abs(b_split - 0.5).sum(1) > 0)
    assert seen.sum() > 300

    def off(c):
        """mean absolute difference from the colours the truth's pose samples (the same frame)"""
        return float(np.abs(np.asarray(c, np.float64)[seen] - np.asarray(b_truth, np.float64)[seen]).mean())

    # from the skin pose (within 2 degrees) the discs take nearly the truth pose's colours
    # (split 0.03), from the plain pose (6 or more degrees short) other stripes' (plain 0.10)
    assert off(b_split) < 0.05, off(b_split)
    assert off(b_plain) > 2.0 * off(b_split) + 0.03, (off(b_plain), off(b_split))
    # the hair's colours are the plain pose's to the bit
    np.testing.assert_array_equal(h_split, h_plain)


def _busy_wall_frame(gs, camera, ref_pose, pose):
    """A frame of the avatar at `pose` in front of a busy wall (blue stripes, a red poster beside
    the face, a dark post behind the head), and that wall's plate as a video would know it: every
    pixel but the head's own (support 10 of 10 frames there, none under the head)."""
    from avatarkit.render import render
    from avatarkit.track.background_plate import Plate

    H, W = camera.height, camera.width
    yy, xx = np.mgrid[:H, :W]
    wall = np.ones((H, W, 3)) * np.array([0.93, 0.9, 0.85])
    wall[(xx // 8) % 2 == 0] = [0.55, 0.7, 0.9]
    wall[(xx > 80) & (yy < 70)] = [0.8, 0.15, 0.1]
    wall[(xx < 40) & (xx > 28)] = [0.25, 0.15, 0.08]
    r = render(gs, pose_camera(camera, ref_pose, pose), background=(0.0, 0.0, 0.0))
    image = (np.clip(r.rgb + (1 - r.alpha[..., None]) * wall, 0, 1) * 255 + 0.5).astype(np.uint8)
    n = np.where(r.alpha > 0.02, 0, 10).astype(np.int32)
    return image, Plate((wall * 255 + 0.5).astype(np.uint8), n, n.copy(), 10)


def test_a_turned_frame_before_a_busy_wall_registers_over_the_plate_and_not_over_a_flat_colour(scene):
    """The render composited over the video's plate (`plate_background`): the wall explains
    itself and only the head is matched. Over the border's median colour the poster and the post
    are the head pose's to explain: the search runs off (the cluttered wall's turn ends, session
    26)."""
    gs, camera, ref_pose, truth, _ = scene
    image, plate = _busy_wall_frame(gs, camera, ref_pose, truth)
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(40.0), math.radians(100.0))
    want = np.degrees(params_from_pose(truth)[:3])
    over = register_frame(gs, image, camera, ref_pose, guess, window, shifted=True, plate=plate)
    found = np.degrees(params_from_pose(over.pose)[:3])
    assert abs(found[0] - want[0]) < 2.5 and abs(found[1] - want[1]) < 2.5, (found, want)
    flat = register_frame(gs, image, camera, ref_pose, guess, window, shifted=True)
    off = np.degrees(params_from_pose(flat.pose)[:3])
    assert abs(off[0] - want[0]) > 8.0 or abs(off[1] - want[1]) > 8.0, (off, want)


def test_a_plain_walls_plate_leaves_the_registration_as_the_flat_colours_to_the_bit(scene):
    from avatarkit.track.background_plate import AGREE, Plate
    from avatarkit.track.register import plate_background

    gs, camera, ref_pose, truth, image = scene
    H, W = image.shape[:2]
    n = np.full((H, W), 10, np.int32)
    # a white wall the plate knows a few levels off the border's white: nothing to add
    plain = Plate(np.full((H, W, 3), 255 - AGREE + 2, np.uint8), n, n.copy(), 10)
    assert plate_background(plain, (H, W), (96, 96), np.ones(3)).shape == (3,)
    guess = pose_from_params([math.radians(60.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    window = (math.radians(60.0), math.radians(80.0))
    a = register_frame(gs, image, camera, ref_pose, guess, window, plate=plain)
    b = register_frame(gs, image, camera, ref_pose, guess, window)
    np.testing.assert_array_equal(a.pose, b.pose)
    assert a.error == b.error
    # a wall the plate knows in another colour where it is known: the plate's colour there, scaled
    # by area as the frame is, the flat colour where it is not known
    grey = Plate(np.full((H, W, 3), 100, np.uint8), np.where(np.arange(W) < W // 2, 10, 0)[None].repeat(H, 0).astype(np.int32),
                 n.copy(), 10)
    bg = plate_background(grey, (H, W), (H // 2, W // 2), np.ones(3))
    assert bg.shape == (H // 2, W // 2, 3)
    np.testing.assert_allclose(bg[:, :W // 4 - 1], 100 / 255.0)
    np.testing.assert_allclose(bg[:, W // 4 + 1:], 1.0)


def test_the_plate_is_scaled_as_the_frame_is():
    """A wall of one-pixel stripes: at half the size the frame (`_target`, area averaging) is
    their mean, and so is the plate the registration composites over (not every other stripe)."""
    from avatarkit.track.background_plate import Plate
    from avatarkit.track.register import _target, plate_background

    H, W = 64, 64
    wall = np.zeros((H, W, 3), np.uint8)
    wall[:, ::2] = (200, 40, 30)
    n = np.full((H, W), 10, np.int32)
    target = _target(wall, 32)
    bg = plate_background(Plate(wall, n, n.copy(), 10), (H, W), target.shape[:2], np.ones(3))
    np.testing.assert_allclose(bg, target, atol=1.0 / 255)


@pytest.fixture(scope="module")
def wide_scene(scene):
    """The scene's 128 px picture as the window (x 400..528, y 200..328) of a 640x360 landscape
    frame: the same head and pose, small and off-centre in a wider picture."""
    from avatarkit.render import render
    from avatarkit.render.camera import Camera

    gs, camera, ref_pose, truth, _ = scene
    big = Camera(camera.fx, camera.fy, camera.cx + 400, camera.cy + 200, 640, 360, camera.world_to_camera)
    frame = render(gs, pose_camera(big, ref_pose, truth), background=(1.0, 1.0, 1.0))
    return big, (np.clip(frame.rgb, 0, 1) * 255 + 0.5).astype(np.uint8)


def test_a_head_small_in_a_wide_frame_is_registered_in_a_window_around_it(scene, wide_scene, monkeypatch):
    from avatarkit.track import register
    from avatarkit.track.register import head_window

    gs, camera, ref_pose, truth, _ = scene
    big, image = wide_scene
    # the scene's own frame is all head: compared whole, as before the window
    assert head_window(gs, camera, (128, 128)) is None
    x0, y0, x1, y1 = head_window(gs, big, image.shape[:2])
    assert 300 < x0 < 420 and 510 < x1 < 640 and y1 == 360 and 100 < y0 < 220, (x0, y0, x1, y1)
    guess = pose_from_params([math.radians(45.0), 0.0, 0.0, 0.0, -0.05, -0.5])
    yaws = (math.radians(40.0), math.radians(100.0))
    want = np.degrees(params_from_pose(truth)[:3])
    found = np.degrees(params_from_pose(register_frame(gs, image, big, ref_pose, guess, yaws).pose)[:3])
    assert abs(found[0] - want[0]) < 2.0 and abs(found[1] - want[1]) < 2.0, (found, want)
    # the whole 640x360 frame at 96 px leaves the head ~20 px across: the pose is lost
    monkeypatch.setattr(register, "WINDOW_MARGIN", None)
    whole = np.degrees(params_from_pose(register_frame(gs, image, big, ref_pose, guess, yaws).pose)[:3])
    assert abs(whole[0] - want[0]) > 2.0 or abs(whole[1] - want[1]) > 2.0, (whole, want)
