"""Keyframe choice (`track.keyframes`) on hand-made trackings whose answer is known."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from avatarkit.track.keyframes import choose_keyframes, face_sharpness, yaw_pitch


def _tracking(yaw, pitch=None, jaw=None, conf=None):
    T = len(yaw)
    from scipy.spatial.transform import Rotation

    pitch = np.zeros(T) if pitch is None else np.asarray(pitch, float)
    rot = Rotation.from_euler("YXZ", np.stack([yaw, pitch, np.zeros(T)], 1)).as_rotvec()
    j = np.zeros((T, 3))
    if jaw is not None:
        j[:, 0] = jaw
    clip = SimpleNamespace(rotation=rot, jaw=j, expr=np.zeros((T, 10)))
    conf = np.full(T, 0.9) if conf is None else np.asarray(conf, float)
    # face meshes with closed lips and a still mouth: the build frame's mouth term is 0
    marks = np.zeros((T, 468, 2))
    marks[:, [33, 133, 362, 263], 0] = [-40, -20, 20, 40]
    return SimpleNamespace(clip=clip, confidence=conf, found=np.ones(T, bool),
                           frame_index=np.arange(100, 100 + T), num_frames=T, landmarks=marks, raw={"rotation": rot})


def test_yaw_pitch_reads_back_euler_angles():
    r = _tracking(np.array([0.3, -0.5]), np.array([0.1, -0.2]))
    np.testing.assert_allclose(yaw_pitch(r.clip.rotation), [[0.3, 0.1], [-0.5, -0.2]], atol=1e-9)


def test_turn_left_right_up_gives_the_extremes_and_the_frontal_reference():
    # 0..20: frontal -> 40 deg left; 20..40: back and -> 40 deg right; 40..60: back, nod up 25 deg
    yaw = np.concatenate([np.linspace(0, 0.7, 21), np.linspace(0.7, -0.7, 20), np.linspace(-0.7, 0, 10),
                          np.zeros(10)])
    pitch = np.concatenate([np.zeros(51), np.linspace(0, 0.45, 10)])
    jaw = np.zeros(61)
    jaw[19:22] = 0.4          # the mouth opens at the left extreme: its neighbours should win
    r = _tracking(yaw, pitch, jaw)
    k = choose_keyframes(r, count=4)
    assert k.clip_index[0] == 0                      # frontal, neutral
    assert k.reference == 0 and k.frame_index[0] == 100
    got = {tuple(np.round(np.degrees(p)).astype(int)) for p in k.yaw_pitch[1:]}
    yaws = sorted(p[0] for p in got)
    assert yaws[0] <= -38 and yaws[-1] >= 30          # both extremes (left one next to the open jaw)
    assert max(p[1] for p in got) >= 24               # the nod
    assert not set(k.clip_index.tolist()) & {19, 20, 21}   # open mouth avoided
    assert len(k.summary()) == 4


def test_blurred_frames_lose_to_sharp_neighbours():
    yaw = np.linspace(0, 0.6, 31)
    sharp = np.ones(31)
    sharp[28:] = 0.05                                  # the last frames are blurred
    k = choose_keyframes(_tracking(yaw), sharpness=sharp, count=2)
    assert k.clip_index[1] == 27


def test_a_head_that_never_turns_gives_the_reference_alone():
    yaw = 0.02 * np.sin(np.linspace(0, 6, 40))
    k = choose_keyframes(_tracking(yaw))
    assert len(k) == 1


def test_unconfident_frames_are_never_keyframes():
    yaw = np.linspace(-0.6, 0.6, 25)
    conf = np.full(25, 0.9)
    conf[:3] = 0.3
    k = choose_keyframes(_tracking(yaw, conf=conf), count=3)
    assert min(k.clip_index) >= 3


def test_face_sharpness_falls_with_blur():
    import cv2

    rng = np.random.default_rng(0)
    img = (rng.random((96, 96, 3)) * 255).astype(np.uint8)
    marks = np.array([[10.0, 10.0], [80.0, 85.0]])
    blurred = cv2.GaussianBlur(img, (0, 0), 2.0)
    assert face_sharpness(img, marks) > 10 * face_sharpness(blurred, marks)
    assert face_sharpness(img, None) == 0.0


def test_frames_the_tracker_lost_at_a_turns_ends_are_the_ones_registered():
    # the head turns to 80 degrees each way; the tracking follows to 45 and loses the rest (no
    # face found past 50, a collapsed confidence at 45-50); a short dropout near the front must
    # not be registered (its neighbours have not turned)
    from avatarkit.track.keyframes import TURNED_EDGE, eligible_frames
    from avatarkit.track.video_build import turned_frames

    true = np.radians(np.concatenate([np.linspace(0, 80, 20), np.full(6, 80.0), np.linspace(80, -80, 30),
                                      np.full(6, -80.0), np.linspace(-80, 0, 20), np.zeros(14)]))
    T = len(true)
    tracked = np.clip(true, -np.radians(45), np.radians(45))
    conf = np.where(np.abs(true) > np.radians(45), 0.4, 0.9)
    found = np.abs(true) <= np.radians(50)
    conf[90:92] = 0.1                                            # a dropout at the front
    # on the way to the right the tracker under-reads beside the lost stretch (-30 where the
    # head is at -45), and a 2-frame dropout before it has edges turned more (-42): the long
    # stretch is still the one registered
    neg = np.flatnonzero(true < -np.radians(45))
    a, b = neg[0], neg[-1]
    tracked[a - 1] = tracked[b + 1] = -np.radians(30)
    conf[a - 4:a - 2] = 0.1
    tracked[a - 5] = tracked[a - 2] = -np.radians(42)
    r = _tracking(tracked, conf=conf)
    r.found = found
    ok = eligible_frames(r)
    assert not ok[90:92].any() and ok[:9].all()
    got = turned_frames(r, tracked)
    assert len(got) == 2                                         # one per side, none at the front
    for t in got:
        assert not ok[t.clip_index] and abs(true[t.clip_index]) >= np.radians(75)   # the middle of the stretch
        assert ok[t.edge] and abs(tracked[t.edge]) >= TURNED_EDGE
        assert t.lo < true[t.clip_index] < t.hi                  # the search reaches the true yaw
    assert {np.sign(true[t.clip_index]) for t in got} == {-1.0, 1.0}


def test_a_tracking_that_loses_the_face_only_near_the_front_registers_nothing():
    # a blink of lost frames with the head near the front is no turn beyond the tracking
    from avatarkit.track.video_build import turned_frames

    yaw = np.radians(np.linspace(-40, 40, 50))
    assert turned_frames(_tracking(yaw), yaw) == []
    conf = np.full(50, 0.9)
    conf[23:27] = 0.1                                            # around yaw 0
    assert turned_frames(_tracking(yaw, conf=conf), yaw) == []


def _saturating_turn():
    """An eased turn to 80 degrees and back as the tracker reads it (the mesh subject's eased
    turn at 192 px, docs/video-build.md): the read yaw follows the head to ~45 degrees, then
    saturates at 46-49 while the head turns on to ~62 at a confidence that stays 0.75, and the
    face is lost beyond. Returns (true yaw (T,) radians, the tracking)."""
    true = np.radians(np.concatenate([np.linspace(0, 80, 14), np.full(8, 80.0), np.linspace(80, 0, 14),
                                      np.zeros(10)]))
    deg = np.degrees(true)
    read = np.where(deg <= 44, deg, 44 + 5.0 * np.tanh((deg - 44) / 10.0))     # saturates below 49
    conf = np.where(deg <= 44, 0.9, 0.75)
    found = deg <= 62
    r = _tracking(np.radians(read), conf=np.where(found, conf, 0.0))
    r.found = found
    return true, r


def test_the_edge_of_the_tracking_holds_the_frames_whose_yaw_is_under_read():
    from avatarkit.track.keyframes import eligible_frames, tracking_edge

    true, r = _saturating_turn()
    read = yaw_pitch(r.raw["rotation"])[:, 0]
    ok, edge = eligible_frames(r), tracking_edge(r)
    wrong = ok & (np.abs(true - read) > np.radians(4.0))
    assert wrong.sum() >= 4                              # the case has under-read eligible frames
    assert edge[wrong].all()                             # and every one is at the edge
    assert not edge[np.abs(true) < np.radians(35)].any()   # well-read frames are not


def test_no_edge_without_a_lost_face():
    # a confidence dip at the turn's end with the face still found (the 46-degree whip clip):
    # the frames beside it are read well and stay keyframes
    from avatarkit.track.keyframes import tracking_edge

    yaw = np.radians(np.concatenate([np.linspace(0, 46, 8), np.linspace(46, -46, 15), np.linspace(-46, 0, 8)]))
    conf = np.where(np.abs(yaw) > np.radians(40), 0.3, 0.9)
    r = _tracking(yaw, conf=conf)
    assert not tracking_edge(r).any()
    # the same dip with the face lost there is a turn past the tracking
    r.found = np.abs(yaw) <= np.radians(40)
    assert tracking_edge(r).any()
    # a face lost near the front is no turn past the tracking
    r = _tracking(np.radians(np.linspace(-20, 20, 30)))
    r.found[14:16] = False
    assert not tracking_edge(r).any()


def test_ineligible_stretches_match_a_plain_walk():
    from avatarkit.track.keyframes import ineligible_stretches

    def walk(ok):
        out, t = [], 0
        while t < len(ok):
            if ok[t]:
                t += 1
                continue
            a = t
            while t < len(ok) and not ok[t]:
                t += 1
            out.append((a, t))
        return out

    assert ineligible_stretches(np.array([1, 1, 0, 0, 1, 0], bool)) == [(2, 4), (5, 6)]
    rng = np.random.default_rng(0)
    for _ in range(500):
        ok = rng.random(rng.integers(0, 30)) < rng.random()
        assert ineligible_stretches(ok) == walk(ok)


def _whip(n=32):
    """The whip clip's yaw (`synthetic.turning_video.turning_clip(32)`): 0 -> 0.8 rad in 4 frames,
    -> -0.8 in 8, back to 0 in 12 (slower), then still; and that yaw smoothed over 5 frames, as a
    tracker's temporal filter rounds off a turn that reverses at full speed."""
    a, b = n * 3 // 8, n * 3 // 4
    y = np.concatenate([np.linspace(0, 0.8, n // 8 + 1)[:-1], np.linspace(0.8, -0.8, a - n // 8 + 1)[:-1],
                        np.linspace(-0.8, 0, b - a + 1)[:-1], np.zeros(n - b)])
    smooth = np.convolve(np.pad(y, 2, mode="edge"), np.full(5, 0.2), mode="valid")
    return y, smooth


def test_raw_keyframe_pose_takes_the_whips_turn_end_the_smoothed_pose_rounds_off(monkeypatch):
    from scipy.spatial.transform import Rotation

    from avatarkit.track import keyframes

    y, smooth = _whip()
    assert np.argmin(y) == 12 and np.argmin(smooth) == 13      # the smoother moves the end a frame on
    r = _tracking(smooth)
    r.raw = {"rotation": Rotation.from_euler("YXZ", np.stack([y, 0 * y, 0 * y], 1)).as_rotvec()}
    monkeypatch.setattr(keyframes, "KEYFRAME_POSE", "clip")
    k = choose_keyframes(r, count=3)
    assert 13 in k.clip_index.tolist() and 12 not in k.clip_index.tolist()
    monkeypatch.setattr(keyframes, "KEYFRAME_POSE", "raw")
    k = choose_keyframes(r, count=3)
    assert 12 in k.clip_index.tolist() and 4 in k.clip_index.tolist()
    np.testing.assert_allclose(sorted(k.yaw_pitch[1:, 0]), [-0.8, 0.8], atol=1e-9)   # the frames' own fits
    # a frame without its own fit falls back to the clip's pose (never a NaN in the choice)
    r.raw["rotation"][12] = np.nan
    k = choose_keyframes(r, count=3)
    assert np.isfinite(k.yaw_pitch).all() and len(k) == 3
    assert 13 in k.clip_index.tolist() and 12 not in k.clip_index.tolist()
    monkeypatch.setattr(keyframes, "KEYFRAME_POSE", "smoothed")
    with pytest.raises(ValueError):
        choose_keyframes(r, count=3)
