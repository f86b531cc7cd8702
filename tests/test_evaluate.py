"""`avatarkit evaluate`: metric helpers on hand-computed cases, the build-frame choice, a
synthetic end-to-end run (a known avatar rendered with a known clip and camera: the only error
left is tracking) and bad input."""
import csv
import json
import math

import numpy as np
import pytest
from helpers import one_error_line

from avatarkit.cli.main import main
from avatarkit.track import metrics


# ---- helpers against hand-computed cases -------------------------------------------------

def test_person_mask_thresholds_alpha():
    alpha = np.array([[0.2, 0.5], [0.51, 1.0]])
    assert metrics.person_mask(alpha).tolist() == [[False, False], [True, True]]
    assert metrics.person_mask(alpha[..., None], 0.1).all()


def test_composite_sets_the_outside_to_one_colour():
    img = np.full((2, 2, 3), 255, np.uint8)
    mask = np.array([[True, False], [False, True]])
    out = metrics.composite(img, mask, (0.0, 0.5, 1.0))
    assert out[0, 0].tolist() == [1, 1, 1] and out[0, 1].tolist() == [0, 0.5, 1]


def test_masked_psnr_by_hand():
    a = np.zeros((4, 4, 3))
    b = np.zeros((4, 4, 3))
    b[0, 0] = 0.1          # inside the mask: MSE = 0.01 over the mask's pixels
    b[3, 3] = 1.0          # outside: ignored
    mask = np.zeros((4, 4), bool)
    mask[0, 0] = True
    assert metrics.masked_psnr(a, b, mask) == pytest.approx(20.0)
    mask[0, 1] = True      # two pixels, one wrong: MSE = 0.005
    assert metrics.masked_psnr(a, b, mask) == pytest.approx(10 * math.log10(200))
    assert metrics.masked_psnr(a, a, mask) == math.inf
    assert math.isnan(metrics.masked_psnr(a, b, np.zeros((4, 4), bool)))
    # agrees with skimage on a full mask
    from skimage.metrics import peak_signal_noise_ratio

    rng = np.random.default_rng(0)
    x, y = rng.random((8, 8, 3)), rng.random((8, 8, 3))
    assert metrics.masked_psnr(x, y, np.ones((8, 8), bool)) == pytest.approx(
        peak_signal_noise_ratio(x, y, data_range=1.0))


def test_ssim_cases():
    rng = np.random.default_rng(1)
    x = rng.random((32, 32, 3))
    mask = np.zeros((32, 32), bool)
    mask[8:24, 8:24] = True
    assert metrics.masked_ssim(x, x, mask) == pytest.approx(1.0)
    # a constant offset c on images with no variance: SSIM = luminance term (2ab+C1)/(a^2+b^2+C1)
    a, b = np.full((32, 32, 3), 0.4), np.full((32, 32, 3), 0.6)
    C1 = (0.01 * 1.0) ** 2
    want = (2 * 0.4 * 0.6 + C1) / (0.4 ** 2 + 0.6 ** 2 + C1)
    assert metrics.masked_ssim(a, b, mask) == pytest.approx(want, rel=1e-6)
    # the whole-image value is skimage's own
    from skimage.metrics import structural_similarity

    y = np.clip(x + rng.normal(0, 0.1, x.shape), 0, 1)
    whole, smap = metrics.ssim_map(x, y)
    assert whole == pytest.approx(structural_similarity(x, y, channel_axis=2, **metrics.SSIM_SETTINGS))
    assert smap.shape == (32, 32)
    assert metrics.masked_ssim(x, y, mask) == pytest.approx(smap[mask].mean())


@pytest.mark.parametrize("case", ["blob", "border", "corner", "empty", "whole", "small_frame"])
def test_metrics_on_the_mask_box_equal_the_whole_frame_ones(case):
    rng = np.random.default_rng(len(case))
    h, w = (18, 23) if case == "small_frame" else (70, 90)
    yy, xx = np.mgrid[0:h, 0:w]
    mask = {"blob": (yy - 35) ** 2 + (xx - 50) ** 2 < 15 ** 2,
            "border": (xx < 12) & (yy > 20) & (yy < 50),
            "corner": (xx > w - 9) & (yy > h - 7),
            "empty": np.zeros((h, w), bool),
            "whole": np.ones((h, w), bool),
            "small_frame": (yy - 9) ** 2 + (xx - 11) ** 2 < 16}[case]
    bg = (1.0, 1.0, 1.0)
    a = metrics.composite(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), mask, bg)
    b = metrics.composite(np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1), mask, bg)
    got = metrics.region_metrics(a, b, mask)
    ssim_full, smap = metrics.ssim_map(a, b)
    want = {"psnr": metrics.masked_psnr(a, b, mask), "psnr_full": metrics.masked_psnr(a, b, np.ones_like(mask)),
            "ssim": float(smap[mask].mean()) if mask.any() else float("nan"), "ssim_full": ssim_full}
    for k, v in want.items():
        if math.isnan(v):
            assert math.isnan(got[k]), k
        else:
            assert got[k] == pytest.approx(v, rel=1e-10, abs=1e-10), k
    if case == "blob":
        assert 0.5 < got["ssim"] < 0.99 and got["ssim_full"] > got["ssim"]  # a real difference
    # the images before compositing, composited inside the box only: the same numbers
    raw_a = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    raw_b = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    bg = (0.2, 0.5, 1.0)
    want = metrics.region_metrics(metrics.composite(raw_a, mask, bg), metrics.composite(raw_b, mask, bg), mask)
    got = metrics.region_metrics(raw_a, raw_b, mask, bg)
    for k, v in want.items():
        assert got[k] == pytest.approx(v, rel=1e-12, abs=1e-12) or (math.isnan(v) and math.isnan(got[k])), k
    # the heat map on the box is the whole frame's
    np.testing.assert_array_equal(metrics.error_heat_map(raw_a, raw_b, mask, margin=0),
                                  metrics.error_heat_map(raw_a, raw_b, mask))


def test_fast_ssim_map_equals_skimage():
    rng = np.random.default_rng(3)
    a = rng.uniform(size=(37, 52, 3))
    b = np.clip(a + rng.normal(0, 0.2, a.shape), 0, 1)
    b[:10, :10] = a[:10, :10]                    # a patch where the images agree
    value, smap = metrics.ssim_map(a, b)
    fast_value, fast_map = metrics.ssim_map_fast(a, b)
    assert fast_value == pytest.approx(value, abs=1e-12)
    np.testing.assert_allclose(fast_map, smap, atol=1e-11)
    assert 0.2 < value < 0.9


def test_landmark_error_and_eye_distance():
    pts = np.zeros((468, 2))
    pts[33], pts[133], pts[362], pts[263] = (0, 0), (2, 0), (10, 0), (12, 0)
    assert metrics.interocular(pts) == pytest.approx(10.0)
    moved = pts + np.array([3.0, 4.0])
    assert metrics.landmark_error(moved, pts) == pytest.approx(5.0)
    assert math.isnan(metrics.landmark_error(None, pts))
    assert math.isnan(metrics.landmark_error(np.full((468, 2), np.nan), pts))


def test_heat_map_is_black_outside_the_mask():
    a, b = np.zeros((4, 4, 3)), np.ones((4, 4, 3))
    mask = np.zeros((4, 4), bool)
    mask[1, 1] = True
    h = metrics.error_heat_map(a, b, mask)
    assert h.dtype == np.uint8 and h.shape == (4, 4, 3)
    assert h[0, 0].tolist() == [0, 0, 0] and h[1, 1].sum() > 600   # inferno's top is near white


def test_build_frame_choice_prefers_frontal_neutral_confident():
    from types import SimpleNamespace

    from avatarkit.track.build_frame import choose_build_frame

    T = 5
    rot = np.zeros((T, 3))
    rot[:, 1] = [0.3, 0.01, 0.0, 0.2, 0.0]
    jaw = np.zeros((T, 3))
    jaw[1, 0] = 0.3                      # frame 1: frontal but mouth open
    clip = SimpleNamespace(rotation=rot, jaw=jaw, expr=np.zeros((T, 10)))
    conf = np.array([0.9, 0.9, 0.5, 0.9, 0.9])   # frame 2 frontal but unsure
    found = np.array([True, True, True, True, False])   # frame 4 interpolated
    r = SimpleNamespace(clip=clip, confidence=conf, found=found, frame_index=np.arange(10, 15),
                        landmarks=face_marks(T))
    assert choose_build_frame(r) == 13


def face_marks(T: int, gap=0.0, width=None) -> np.ndarray:
    """(T, 468, 2) face meshes with only the points the build frame's mouth term reads: eye
    corners 60 px apart, inner lips `gap` (T,) eye distances apart, mouth corners `width`
    (T,) eye distances apart (default 0.8); the rest at the origin."""
    p = np.zeros((T, 468, 2))
    p[:, [33, 133, 362, 263], 0] = [-40, -20, 20, 40]          # eye centres at -30 and +30
    w = 0.8 * np.ones(T) if width is None else np.asarray(width, float)
    p[:, 61, 0], p[:, 291, 0] = -30 * w, 30 * w
    p[:, 13, 1], p[:, 14, 1] = 50, 50 + 60 * np.asarray(gap, float)
    return p


def test_build_frame_choice_reads_the_mouth_from_the_face_mesh():
    """The tracked jaw and expression miss a smile (calibrated tracking fits every frame well):
    the face mesh's lip gap and widening rule it out; a few degrees of turn do not."""
    from types import SimpleNamespace

    from avatarkit.track.build_frame import choose_build_frame, mouth_cost

    T = 4
    rot = np.zeros((T, 3))
    rot[:, 1] = [0.0, 0.05, 0.1, 0.06]
    clip = SimpleNamespace(rotation=rot, jaw=np.zeros((T, 3)), expr=np.zeros((T, 10)))
    gap = np.array([0.12, 0.0, 0.0, 0.0])            # frame 0: frontal, lips apart
    width = np.array([0.8, 1.0, 0.8, 0.8])           # frame 1: nearly frontal, a wide smile
    marks = face_marks(T, gap, width)
    np.testing.assert_allclose(mouth_cost(marks), [0.12, 0.2, 0.0, 0.0], atol=1e-12)
    r = SimpleNamespace(clip=clip, confidence=np.full(T, 0.9), found=np.ones(T, bool),
                        frame_index=np.arange(T), landmarks=marks)
    assert choose_build_frame(r) == 3
    marks[3] = np.nan                                 # no face there: never chosen
    assert choose_build_frame(r) == 2


# ---- end to end on a synthetic video ---------------------------------------------------------

def synthetic_clip(T: int = 12):
    """A nod-and-turn with the jaw opening: 12 frames at 24 fps."""
    from avatarkit.motion.clip import MotionClip

    rot = np.stack([0.1 * np.sin(np.linspace(0, 2, T)), np.linspace(-0.25, 0.25, T), np.zeros(T)], axis=1)
    jaw = np.zeros((T, 3))
    jaw[:, 0] = 0.15 * np.clip(np.sin(np.linspace(0, 3, T)), 0, None)
    return MotionClip(fps=24, rotation=rot, translation=np.zeros((T, 3)), neck=np.zeros((T, 3)),
                      jaw=jaw, eyes=np.zeros((T, 6)), expr=np.zeros((T, 10)))


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A small sample avatar, and a video of it driven by a known clip, rendered by our renderer
    from the camera a tracker reports (the avatar's world is the clip's)."""
    from avatarkit.export.video import write_video
    from avatarkit.synthetic.head_video import avatar_video, head_video_camera
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    root = tmp_path_factory.mktemp("eval")
    avatar = make_sample_avatar(n_hair=3000, n_bald=12000, style="short", cage_vertices=200)
    avatar.save(root / "avatar", preview=False)
    clip = synthetic_clip()
    from avatarkit.avatar import load_avatar

    camera = head_video_camera(160, distance=0.5)
    frames = [f.rgb for f in avatar_video(load_avatar(root / "avatar"), clip, camera)]
    write_video(root / "head.mp4", frames, fps=24, crf=12)
    return root


def test_evaluate_synthetic_video_end_to_end(synthetic, tmp_path, capsys):
    out = tmp_path / "report"
    code = main(["evaluate", str(synthetic / "head.mp4"), "-o", str(out), "--avatar",
                 str(synthetic / "avatar"), "--build-frame", "0", "--exclude", "2"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    doc = json.loads((out / "metrics.json").read_text())
    s = doc["summary"]
    assert s["frames"] == 12 and s["frames_evaluated"] == 9      # frames 0..2 excluded
    # the only error is tracking (and H.264): the render lands on the video
    # what is left is tracking error: 1-2 px of pose at 160 px shows at every silhouette edge
    # against the white background (measured: PSNR 20.8, SSIM 0.76, whole frame 25.3 / 0.88,
    # landmark error 1.3 px; thresholds ~2 dB / 0.05 below)
    assert s["psnr"] > 19.0 and s["ssim"] > 0.70, s
    assert s["psnr_full"] > s["psnr"] + 2            # constant background matches exactly
    assert s["landmark_error_px"] is not None and s["landmark_error_px"] < 3.0, s
    assert doc["summary"]["lpips"] is None and "LPIPS" in doc["lpips"]
    # the head turns on the neck, the body held at the build frame's pose (`track.neck`)
    assert doc["settings"]["head_on"] == "neck (the body held at frame 0's pose)"
    rows = list(csv.DictReader((out / "frames.csv").open()))
    assert len(rows) == 12 and [r["excluded"] for r in rows[:4]] == ["1", "1", "1", "0"]
    assert np.mean([float(r["psnr"]) for r in rows if r["excluded"] == "0"]) == pytest.approx(s["psnr"], rel=1e-4)
    from avatarkit.video import open_video

    with open_video(out / "side_by_side.mp4") as v:
        assert v.info.frame_count == 12 and v.info.width == 3 * 160 and v.info.height == 160
    assert "PSNR" in cap.err and not list(tmp_path.glob(".report*"))


def test_exact_motion_and_camera_reproduce_the_video(synthetic, tmp_path):
    """With the clip and camera that made the video (no tracking), the render is the video up
    to H.264: the comparison chain (bake, camera, frame matching, mask, metrics) adds nothing."""
    from avatarkit.synthetic.head_video import head_video_camera
    from avatarkit.track.evaluate import EvalOptions, render_and_compare
    from avatarkit.track.tracker import TrackResult

    clip = synthetic_clip()
    T = clip.n_frames
    result = TrackResult(clip, head_video_camera(160, distance=0.5), np.arange(T), np.zeros(T, bool),
                         np.ones(T), np.full((T, 468, 2), np.nan, np.float32), np.full(T, np.nan))
    rows, _ = render_and_compare(synthetic / "head.mp4", synthetic / "avatar", result, None,
                                 EvalOptions(side_by_side=False), tmp_path)
    assert len(rows) == T and not any(r.excluded for r in rows)
    psnr = [r.psnr for r in rows]
    assert min(psnr) > 33.0, psnr          # measured 36.5-38.3 dB (H.264 at crf 12)
    assert min(r.ssim for r in rows) > 0.95      # measured 0.967-0.977


def test_second_tracking_from_the_first_ones_meshes_is_the_same(synthetic):
    """evaluate tracks twice (the template, to choose the build frame; then the avatar): the
    second run reuses the first one's face meshes and must equal a tracking from scratch."""
    from avatarkit.track.video import track_video

    video, avatar = synthetic / "head.mp4", synthetic / "avatar"
    template = track_video(video, end=4)
    scratch = track_video(video, avatar=avatar, end=4)
    replay = track_video(video, avatar=avatar, end=4, meshes=template.meshes)
    assert len(template.meshes) == 4 and template.found.all()
    for k in ("rotation", "translation", "jaw", "expr", "eyes"):
        np.testing.assert_array_equal(getattr(replay.clip, k), getattr(scratch.clip, k), err_msg=k)
    np.testing.assert_array_equal(replay.landmarks, scratch.landmarks)
    np.testing.assert_array_equal(replay.confidence, scratch.confidence)
    assert not np.array_equal(replay.clip.translation, template.clip.translation)  # another model
    with pytest.raises(ValueError, match="meshes"):
        track_video(video, avatar=avatar, end=4, meshes=template.meshes[:2])


# ---- bad input -------------------------------------------------------------------------------


def test_not_a_video(tmp_path, capsys):
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    code = main(["evaluate", str(bad), "-o", str(tmp_path / "r")])
    assert code == 2 and str(bad) in one_error_line(capsys.readouterr())
    assert not (tmp_path / "r").exists()


def test_missing_video(tmp_path, capsys):
    code = main(["evaluate", str(tmp_path / "none.mp4"), "-o", str(tmp_path / "r")])
    assert code == 2 and "not found" in one_error_line(capsys.readouterr())


def test_video_without_faces(tmp_path, capsys):
    from avatarkit.export.video import write_video

    path = tmp_path / "grey.mp4"
    write_video(path, [np.full((64, 64, 3), 100, np.uint8)] * 3, fps=10)
    code = main(["evaluate", str(path), "-o", str(tmp_path / "r"), "-q"])
    line = one_error_line(capsys.readouterr())
    assert code == 2 and "no face" in line and str(path) in line
    assert not (tmp_path / "r").exists() and not list(tmp_path.glob(".r.*"))


def test_unwritable_or_foreign_report_folder(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code = main(["evaluate", str(blocker), "-o", str(blocker / "r")])
    assert code == 2 and "output folder" in one_error_line(capsys.readouterr())
    other = tmp_path / "mine"
    other.mkdir()
    (other / "thesis.tex").write_text("keep")
    code = main(["evaluate", str(blocker), "-o", str(other)])
    assert code == 2 and "not empty" in one_error_line(capsys.readouterr())
    assert (other / "thesis.tex").read_text() == "keep"


def test_build_frame_outside_the_video(synthetic, tmp_path, capsys):
    code = main(["build", str(synthetic / "head.mp4"), "-o", str(tmp_path / "a"), "--frame", "40", "-q"])
    line = one_error_line(capsys.readouterr())
    assert code == 2 and "outside the video" in line and not (tmp_path / "a").exists()


def test_build_frame_of_something_not_a_video(tmp_path, capsys):
    bad = tmp_path / "clip.mov"
    bad.write_text("not a video")
    code = main(["build", str(bad), "-o", str(tmp_path / "a"), "-q"])
    line = one_error_line(capsys.readouterr())
    assert code == 2 and str(bad) in line and not (tmp_path / "a").exists()


@pytest.mark.slow
def test_build_from_a_video_frame_records_it(synthetic, tmp_path, capsys):
    from avatarkit.avatar import read_manifest

    code = main(["build", str(synthetic / "head.mp4"), "-o", str(tmp_path / "a"), "--frame", "3",
                 "--n-bald", "3000", "--n-hair", "3000", "--no-preview", "-q"])
    assert code == 0, capsys.readouterr().err
    src = read_manifest(tmp_path / "a")["provenance"]["source_video"]
    assert src["frame"] == 3 and src["video"].endswith("head.mp4")


VIDEOS = __import__("pathlib").Path(__file__).resolve().parents[1].parent / "shared" / "data" / "videos"


@pytest.mark.slow
@pytest.mark.skipif(not (VIDEOS / "talking_man_grey.mp4").exists(), reason="../shared/data/videos absent")
def test_evaluate_a_real_clip_builds_tracks_and_reports(tmp_path):
    from avatarkit.track.evaluate import EvalOptions, evaluate

    r = evaluate(VIDEOS / "talking_man_grey.mp4", tmp_path / "r", options=EvalOptions(side_by_side=False))
    s = r.summary
    # the video build's frame_colours stage colours from the clip's first half only (108 of 216
    # frames); those frames +-5 and the build frame's are left out: the second half is held out
    colour = r.settings["colour_frames"]
    kept = [f.video_frame for f in r.frames if not f.excluded]
    assert s["frames"] == 216 and 0 < len(colour) <= 24 and max(colour) < 108
    assert s["frames_evaluated"] == len(kept) >= 216 - 108 - 11 and min(kept) > max(colour) + 5
    # measured 21.55 dB, 0.747, 6.4 px (build frame 59): ~2 dB / 0.05 / 50 % margins
    assert s["psnr"] > 19.5 and s["ssim"] > 0.70 and s["landmark_error_px"] < 9.5, s
    assert (tmp_path / "r" / "avatar" / "avatar.json").is_file()


def test_recorded_build_frame_is_read_from_the_avatar(synthetic, tmp_path):
    import shutil

    from avatarkit.track.build_pose import recorded_build_frame

    video = str(synthetic / "head.mp4")
    assert recorded_build_frame(synthetic / "avatar", video) is None
    copy = tmp_path / "avatar"
    shutil.copytree(synthetic / "avatar", copy)
    doc = json.loads((copy / "avatar.json").read_text())
    doc["provenance"]["source_video"] = {"video": video, "frame": 4}
    (copy / "avatar.json").write_text(json.dumps(doc))
    assert recorded_build_frame(copy, video) == 4
    assert recorded_build_frame(copy, str(tmp_path / "other.mp4")) is None


def _built_from(synthetic, tmp_path, frame: int, w2c: np.ndarray):
    """A copy of the synthetic avatar whose provenance says it was built from `frame` of the
    synthetic video, with the build's camera `w2c` (as `build VIDEO --frame` records them)."""
    import shutil

    copy = tmp_path / "avatar"
    shutil.copytree(synthetic / "avatar", copy)
    doc = json.loads((copy / "avatar.json").read_text())
    doc["provenance"]["source_video"] = {"video": str(synthetic / "head.mp4"), "frame": frame}
    doc["provenance"].setdefault("build", {})["camera"] = {"convention": "opencv",
                                                          "world_to_camera": w2c.tolist()}
    (copy / "avatar.json").write_text(json.dumps(doc))
    return copy


def test_track_with_the_avatar_built_from_the_video_aligns_to_its_build_frame(synthetic, tmp_path, capsys):
    """`track --avatar` on the avatar's own source video: the saved clip shows the build frame as
    the build's camera saw the head and looks from there with the build frame's gaze (what
    `evaluate` does); the motion between frames is the tracked one. --no-align-to-build: as tracked."""
    from avatarkit.avatar import load_avatar_head
    from avatarkit.head.model import HeadParams
    from avatarkit.rotations import axis_angle_to_matrix
    from avatarkit.track.build_pose import view_transforms
    from avatarkit.track.io import load_tracking

    video, b = str(synthetic / "head.mp4"), 4
    model, shape, _, _ = load_avatar_head(synthetic / "avatar")
    J0 = model.rest_joints(HeadParams(shape=np.asarray(shape, np.float32),
                                      expr=np.zeros((1, model.num_expr), np.float32)))[0][0]
    C = np.diag([1.0, -1.0, -1.0])
    # the build's fit: 3 degrees of pitch and 2 cm of depth away from the tracked one (unknown yet:
    # any pose near it will do, so take the true camera's view of the true clip's frame b)
    R_f = axis_angle_to_matrix(np.array([[0.05, 0.0, 0.0]]))[0].astype(np.float64) @ \
        axis_angle_to_matrix(synthetic_clip().rotation[b:b + 1])[0].astype(np.float64)
    t_f = np.array([0.004, -0.003, 0.52])
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = C @ R_f, C @ t_f
    avatar = _built_from(synthetic, tmp_path, b, w2c)
    raw_out, out = tmp_path / "raw.npz", tmp_path / "aligned.npz"
    args = ["track", video, "--avatar", str(avatar), "--end", "8"]
    assert main([*args, "-o", str(raw_out), "--no-align-to-build"]) == 0
    assert "aligned" not in capsys.readouterr().err
    assert main([*args, "-o", str(out)]) == 0
    assert f"aligned to the avatar's build frame {b} (eyes and head pose)" in capsys.readouterr().err
    raw, got = load_tracking(raw_out), load_tracking(out)
    # both carry the head on the neck, the body at the build frame's pose: the head back on the
    # global rotation (neck 0) for the view transforms
    from avatarkit.track.neck import clip_joints, head_on_neck, head_rotation

    np.testing.assert_allclose(got.clip.rotation, np.broadcast_to(got.clip.rotation[b], (8, 3)), atol=1e-7)
    np.testing.assert_allclose(got.clip.neck[b], 0.0, atol=1e-6)
    for r in (raw, got):
        head = head_rotation(r.clip.rotation, r.clip.neck)
        r.clip.rotation, r.clip.neck, r.clip.translation = head_on_neck(
            r.clip.rotation, r.clip.translation, r.clip.neck, clip_joints(model, r.clip), head)
    R, t = view_transforms(got.clip.rotation, got.clip.translation, got.camera.world_to_camera, J0)
    np.testing.assert_allclose(R[b], R_f, atol=2e-5)
    np.testing.assert_allclose(t[b], t_f, atol=2e-5)
    np.testing.assert_allclose(got.clip.eyes[b], 0.0, atol=1e-6)
    R0, _ = view_transforms(raw.clip.rotation, raw.clip.translation, raw.camera.world_to_camera, J0)
    assert np.abs(R0[b] - R_f).max() > 0.01                    # it did move
    # the motion between frames is unchanged (R_s R_b^T; `track.build_pose`)
    for s in (0, 7):
        np.testing.assert_allclose(R[s] @ R[b].T, R0[s] @ R0[b].T, atol=2e-5)
    np.testing.assert_array_equal(got.clip.jaw, raw.clip.jaw)
    # outside the tracked frames: nothing aligned, and the user is told
    assert main(["track", video, "--avatar", str(_built_from(synthetic, tmp_path / "b", 10, w2c)),
                 "--end", "8", "-o", str(tmp_path / "late.npz")]) == 0
    assert "outside the tracked frames" in capsys.readouterr().err
    late = load_tracking(tmp_path / "late.npz").clip
    np.testing.assert_allclose(head_rotation(late.rotation, late.neck), raw.clip.rotation, atol=1e-6)


def test_refined_tracking_redraws_the_synthetic_video_closer(synthetic, tmp_path, capsys):
    """`evaluate --refine photometric`: the avatar that made the video, tracked with each frame's
    pose refined against the frame by rendering it, redraws the video closer than the landmark
    fit's pose does (the known motion's residual is tracking error, `test_evaluate_synthetic_
    video_end_to_end`)."""
    scores = {}
    for label, extra in (("landmarks", ["--refine", "none"]), ("refined", ["--refine", "photometric"])):
        out = tmp_path / label
        code = main(["evaluate", str(synthetic / "head.mp4"), "-o", str(out), "--avatar", str(synthetic / "avatar"),
                     "--build-frame", "0", "--exclude", "2", "--no-side-by-side", "-q", *extra])
        assert code == 0, capsys.readouterr().err
        doc = json.loads((out / "metrics.json").read_text())
        scores[label] = doc["summary"]
    assert doc["settings"]["refine"] == "photometric, every 1 frame(s)" and doc["settings"]["refinement"]["frames"] == 12
    assert scores["refined"]["psnr"] > scores["landmarks"]["psnr"] + 1.0, scores
    assert scores["refined"]["ssim"] > scores["landmarks"]["ssim"], scores


@pytest.mark.parametrize("flag, expected", [([], "photometric-fast"), (["--refine", "photometric"], "photometric"),
                                           (["--refine", "none"], None)])
def test_refined_evaluation_registers_the_video_builds_colour_frames_too(tmp_path, monkeypatch, flag, expected):
    """`evaluate`'s refinement (default photometric-fast; no --avatar, no --build-frame: the video
    build) is handed to the build's frame_colours stage (`build_video_avatar(colour_refine=)`);
    with `--refine none` the stage keeps `frame_colours.REFINE`, as `avatarkit build` does."""
    from types import SimpleNamespace

    import avatarkit.track.video_build as video_build
    from avatarkit.export.video import write_video

    seen = {}

    def fake(video, options, **kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt   # stop before anything is written

    monkeypatch.setattr(video_build, "build_tracking", lambda *a, **k: SimpleNamespace(frame_index=np.arange(4)))
    monkeypatch.setattr(video_build, "build_video_avatar", fake)
    write_video(tmp_path / "v.mp4", [np.full((32, 32, 3), 128, np.uint8)] * 2, fps=10)
    try:
        main(["evaluate", str(tmp_path / "v.mp4"), "-o", str(tmp_path / "r"), "-q", *flag])
    except KeyboardInterrupt:
        pass
    assert seen["colour_refine"] == expected and not (tmp_path / "r").exists()


def test_both_builds_are_tracked_alike_with_evaluates_default_refinement(tmp_path, monkeypatch):
    """`evaluate --compare-single` with no --refine: the video build and the single-frame build
    are each tracked with their own avatar and the same options, the default refinement
    (photometric-fast at its own spacing), and the report says so."""
    from types import SimpleNamespace

    import avatarkit.track.evaluate as ev
    import avatarkit.track.video as video
    from avatarkit.export.video import write_video
    from avatarkit.track.evaluate import EvalOptions, evaluate
    from avatarkit.track.tracker import REFINE_EVERY

    assert EvalOptions().refine == "photometric-fast" and EvalOptions().refine_every is None
    seen = []

    def fake_track(path, avatar=None, progress=None, options=None, meshes=None, **kw):
        seen.append((str(avatar), options, meshes))
        return SimpleNamespace(clip=SimpleNamespace(fps=10.0), subject_calibration=None, refinement=None,
                               landmark_error=np.zeros(2))

    monkeypatch.setattr(video, "track_video", fake_track)
    monkeypatch.setattr(ev, "_build_video", lambda v, staged, o, p, t: (staged / "avatar", 1, [1], [0], SimpleNamespace(meshes="M")))
    monkeypatch.setattr(ev, "_build", lambda v, staged, f, o, p, t, name: (staged / name, f, None))
    monkeypatch.setattr(ev, "align_to_build", lambda *a: {"eyes": True, "head_pose": True})
    monkeypatch.setattr(ev, "place_head", lambda *a: "neck")
    monkeypatch.setattr(ev, "describe", str)
    monkeypatch.setattr(ev, "render_and_compare", lambda *a: ([], {}))
    write_video(tmp_path / "v.mp4", [np.full((32, 32, 3), 128, np.uint8)] * 2, fps=10)
    report = evaluate(tmp_path / "v.mp4", tmp_path / "r", options=EvalOptions(compare_single=True))
    (a, first, m1), (b, second, m2) = seen
    assert a.endswith("avatar") and b.endswith("avatar_single_frame") and m1 == m2 == "M"
    assert first == second and first.refine == "photometric-fast"
    assert report.settings["refine"] == f"photometric-fast, every {REFINE_EVERY['photometric-fast']} frame(s)"
