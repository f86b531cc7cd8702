"""Reading portrait images (recon/image_io.py) and portrait analysis (recon/portrait.py)."""
import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.recon.image_io import load_image, read_image, read_mask, write_image
from avatarkit.recon.portrait import (BOX_RATIOS, FACE_PROPORTIONS, LANDMARK_NAMES, analysis_from_box,
                                      analyze_portrait)

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"


def smooth_image(h=48, w=64, seed=0):
    """A smooth colour image: JPEG keeps it close, so lossy round trips can be compared."""
    y, x = np.mgrid[0:h, 0:w]
    rgb = np.stack([x * 255 / (w - 1), y * 255 / (h - 1), 128 + 60 * np.sin(x / 7.0)], axis=2)
    return np.clip(rgb, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def sample():
    return read_image(SAMPLE)


@pytest.fixture(scope="module")
def sample_analysis(sample):
    # the cascade detectors' own path (the library's default is "auto": MediaPipe)
    return analyze_portrait(sample, path=SAMPLE, detector="cascade")


@pytest.fixture(scope="module")
def analyses(sample):
    """detector -> the sample's analysis with it ("auto": the default, MediaPipe here)."""
    return {d: analyze_portrait(sample, path=SAMPLE, detector=d) for d in ("cascade", "auto")}


# ---------------------------------------------------------------------------------- image_io

@pytest.mark.parametrize("ext,lossless", [(".png", True), (".bmp", True), (".tif", True),
                                          (".jpg", False), (".webp", False)])
def test_read_image_formats(tmp_path, ext, lossless):
    rgb = smooth_image()
    path = tmp_path / f"img{ext}"
    Image.fromarray(rgb).save(path, **({} if lossless else {"quality": 95}))
    got = read_image(path)
    assert got.shape == rgb.shape and got.dtype == np.uint8
    diff = np.abs(got.astype(int) - rgb)
    assert diff.max() == 0 if lossless else diff.mean() < 3


def test_grey_becomes_rgb(tmp_path):
    grey = smooth_image()[:, :, 0]
    Image.fromarray(grey, "L").save(tmp_path / "g.png")
    got = read_image(tmp_path / "g.png")
    assert got.shape == grey.shape + (3,)
    assert (got == grey[:, :, None]).all()


def test_16bit_grey_is_scaled(tmp_path):
    g16 = (np.arange(64 * 48, dtype=np.uint32).reshape(48, 64) * 21).astype(np.uint16)
    Image.fromarray(g16).save(tmp_path / "g16.png")
    got = read_image(tmp_path / "g16.png")
    np.testing.assert_allclose(got[:, :, 1], np.round(g16 / 257.0), atol=1)


def test_rgba_composited_on_white_and_alpha_kept(tmp_path):
    rgb = np.zeros((10, 12, 3), np.uint8)
    rgb[:] = (200, 40, 10)
    alpha = np.zeros((10, 12), np.uint8)
    alpha[:, 4:8] = 255
    alpha[:, 8:] = 128
    Image.fromarray(np.dstack([rgb, alpha]), "RGBA").save(tmp_path / "a.png")
    loaded = load_image(tmp_path / "a.png")
    assert (loaded.rgb[:, :4] == 255).all()                 # transparent -> white
    assert (loaded.rgb[:, 4:8] == (200, 40, 10)).all()       # opaque -> unchanged
    np.testing.assert_allclose(loaded.rgb[0, 9], 0.5 * np.array([200, 40, 10]) + 0.5 * 255, atol=1.5)
    assert (loaded.alpha == alpha).all()
    # a fully opaque alpha channel carries nothing: reported as None
    Image.fromarray(np.dstack([rgb, np.full((10, 12), 255, np.uint8)]), "RGBA").save(tmp_path / "o.png")
    assert load_image(tmp_path / "o.png").alpha is None


@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_exif_orientation_is_honoured(tmp_path, ext):
    stored = smooth_image(30, 50)
    stored[:6, :6] = (255, 0, 0)  # a red marker in the stored top-left corner
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 CW to display" (what phones write for portrait shots)
    path = tmp_path / f"rot{ext}"
    Image.fromarray(stored).save(path, exif=exif, **({"quality": 95} if ext == ".jpg" else {}))
    loaded = load_image(path)
    want = np.rot90(stored, k=-1)  # clockwise
    assert loaded.rgb.shape == want.shape == (50, 30, 3)
    assert np.abs(loaded.rgb.astype(int) - want).mean() < (0.01 if ext == ".png" else 4)
    # the marker moved to the displayed top-right corner
    assert loaded.rgb[2, -3, 0] > 200 and loaded.rgb[2, -3, 1] < 60
    assert loaded.original_size == (30, 50)


def test_huge_images_are_downscaled(tmp_path):
    rgb = cv2.resize(smooth_image(), (600, 300), interpolation=cv2.INTER_LINEAR)
    Image.fromarray(rgb).save(tmp_path / "big.jpg", quality=90)
    Image.fromarray(rgb).save(tmp_path / "big.png")
    for name in ("big.jpg", "big.png"):  # JPEG takes Pillow's draft (DCT-scaled) path
        loaded = load_image(tmp_path / name, max_side=200)
        assert loaded.rgb.shape == (100, 200, 3)
        assert loaded.original_size == (600, 300) and loaded.scale == pytest.approx(1 / 3)
        small = cv2.resize(rgb, (200, 100), interpolation=cv2.INTER_AREA)
        assert np.abs(loaded.rgb.astype(int) - small).mean() < 4
    assert read_image(tmp_path / "big.png", max_side=0).shape == (300, 600, 3)


def test_bad_files_raise_errors_naming_the_file(tmp_path):
    junk = tmp_path / "junk.jpg"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 2000, dtype=np.uint8).tobytes())
    text = tmp_path / "notes.png"
    text.write_text("this is not an image\n")
    good = tmp_path / "good.jpg"
    Image.fromarray(cv2.resize(smooth_image(), (256, 192))).save(good, quality=95)
    truncated = tmp_path / "truncated.jpg"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    for path in (junk, text, truncated):
        with pytest.raises(FormatError) as e:
            read_image(path)
        assert str(path) in str(e.value)
    with pytest.raises(InputError, match="not found") as e:
        read_image(tmp_path / "missing.png")
    assert "missing.png" in str(e.value)
    with pytest.raises(InputError, match="folder"):
        read_image(tmp_path)


def test_read_mask_resizes_and_rejects_other_aspect(tmp_path):
    m = np.zeros((20, 30), np.uint8)
    m[5:10, 6:18] = 255
    Image.fromarray(m).save(tmp_path / "m.png")
    assert (read_mask(tmp_path / "m.png") == (m > 0)).all()
    big = read_mask(tmp_path / "m.png", (40, 60))
    assert big.shape == (40, 60) and big.sum() == 4 * (m > 0).sum()
    with pytest.raises(FormatError, match="aspect") as e:
        read_mask(tmp_path / "m.png", (40, 40))
    assert "m.png" in str(e.value)


def test_write_image_round_trip_and_bad_extension(tmp_path):
    rgb = smooth_image()
    write_image(tmp_path / "out.png", rgb)
    assert (read_image(tmp_path / "out.png") == rgb).all()
    with pytest.raises(OutputError):
        write_image(tmp_path / "out.xyz", rgb)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]  # nothing half-written


# ---------------------------------------------------------------------------------- portrait

def test_sample_portrait_has_one_frontal_face(sample, sample_analysis):
    a = sample_analysis
    h, w = sample.shape[:2]
    assert a.image_size == (w, h) and len(a.faces) == 1 and a.face_index == 0
    assert a.detector.startswith("haar")
    x, y, bw, bh = a.face_box
    assert bw >= 100 and 0.25 * w < x + bw / 2 < 0.75 * w
    assert set(a.landmarks) == set(LANDMARK_NAMES)
    for name in ("right_eye", "left_eye"):
        eye = a.landmarks[name]
        assert eye.detected and eye.source.startswith("haar")
        assert x < eye.x < x + bw and y < eye.y < y + bh / 2  # upper half of the face box
    assert a.landmarks["right_eye"].x < a.landmarks["left_eye"].x  # subject's right = image left
    assert not a.landmarks["nose_tip"].detected
    mouth = a.point("mouth_center")
    assert a.eye_mid[1] + 0.5 * a.eye_distance < mouth[1] < y + bh
    assert abs(a.roll_deg) < 6
    assert a.frontality > 0.6 and a.warnings == []


def test_canonical_crop_is_square_contains_face_and_levels_eyes(sample, sample_analysis):
    a = sample_analysis
    cx, cy, side, side2 = a.crop_box
    assert side == side2
    x, y, bw, bh = a.face_box
    assert cx <= x and cy <= y and x + bw <= cx + side and y + bh <= cy + side
    crop, m = a.crop(sample, size=256)
    assert crop.shape == (256, 256, 3) and m.shape == (2, 3)
    eyes = a.points(["right_eye", "left_eye"]) @ m[:, :2].T + m[:, 2]
    assert abs(eyes[0, 1] - eyes[1, 1]) < 0.5  # upright: roll undone
    assert 0.3 * 256 < eyes.mean(axis=0)[0] < 0.7 * 256
    # the matrix is the one the crop was sampled with: pixel values agree where the image is smooth
    rng = np.random.default_rng(1)
    pts = np.stack([rng.uniform(x, x + bw, 40), rng.uniform(y, y + bh, 40)], axis=1)
    q = pts @ m[:, :2].T + m[:, 2]
    blur_src = cv2.GaussianBlur(sample, (0, 0), 3).astype(float)
    blur_crop = cv2.GaussianBlur(crop, (0, 0), 3 * 256 / a.crop_side).astype(float)
    src_vals = blur_src[pts[:, 1].astype(int), pts[:, 0].astype(int)]  # the pixel containing the point
    crop_vals = blur_crop[q[:, 1].astype(int), q[:, 0].astype(int)]
    assert np.median(np.abs(src_vals - crop_vals)) < 10


@pytest.mark.parametrize("detector", ["cascade", "auto"])
def test_roll_follows_image_rotation(sample, analyses, detector):
    h, w = sample.shape[:2]
    rot = cv2.getRotationMatrix2D((w / 2, h / 2), 10, 1.0)  # +10 deg = counter-clockwise on screen
    turned = cv2.warpAffine(sample, rot, (w, h), borderMode=cv2.BORDER_REPLICATE)
    b = analyze_portrait(turned, detector=detector)
    assert b.detector == analyses[detector].detector
    assert b.roll_deg == pytest.approx(analyses[detector].roll_deg - 10, abs=2.5)
    crop, m = b.crop(turned)
    eyes = b.points(["right_eye", "left_eye"]) @ m[:, :2].T + m[:, 2]
    assert abs(eyes[0, 1] - eyes[1, 1]) < 0.5


@pytest.mark.parametrize("detector", ["cascade", "auto"])
def test_mirrored_portrait_mirrors_the_analysis(sample, analyses, detector):
    a = analyses[detector]
    w = sample.shape[1]
    b = analyze_portrait(np.ascontiguousarray(sample[:, ::-1]), detector=detector)
    assert b.detector == a.detector
    assert b.roll_deg == pytest.approx(-a.roll_deg, abs=1.5)
    # the subject's right eye of the mirror image is the mirrored left eye of the original
    # (Haar hits are quantised to the cascade's scale steps: agree to a tenth of the eye distance)
    assert b.point("right_eye") == pytest.approx([w - a.landmarks["left_eye"].x, a.landmarks["left_eye"].y],
                                                 abs=0.1 * a.eye_distance)
    assert abs(b.frontality - a.frontality) < 0.2


def test_lbp_fallback_when_haar_finds_nothing(sample, monkeypatch):
    import avatarkit.recon.portrait as portrait

    class Blind:
        def detectMultiScale(self, *args, **kwargs):
            return ()

    haar = portrait._haar
    monkeypatch.setattr(portrait, "_haar", lambda name: Blind() if "frontalface" in name else haar(name))
    a = analyze_portrait(sample, detector="cascade")
    assert a.detector == "lbp_skimage" and len(a.faces) == 1
    assert a.landmarks["left_eye"].detected and a.landmarks["right_eye"].detected
    x, y, w, h = a.face_box
    assert x < a.eye_mid[0] < x + w and y < a.eye_mid[1] < y + h / 2


def test_no_face_is_an_input_error():
    rng = np.random.default_rng(0)
    for img in (rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), np.full((200, 200, 3), 127, np.uint8)):
        with pytest.raises(InputError, match="no face") as e:
            analyze_portrait(img, path="holiday.jpg")
        assert str(e.value).startswith("holiday.jpg: ")


def test_two_faces_are_listed_and_face_index_selects(sample):
    two = np.concatenate([sample, sample], axis=1)
    with pytest.raises(InputError) as e:
        analyze_portrait(two, path="pair.jpg")
    msg = str(e.value)
    assert "found 2 faces" in msg and "[0]" in msg and "[1]" in msg and "--face-index" in msg
    second = analyze_portrait(two, face_index=1)
    assert second.face_index == 1 and second.face_box[0] > sample.shape[1]
    assert second.point("left_eye")[0] > sample.shape[1]
    first = analyze_portrait(two, face_index=0)
    assert first.face_box[0] + first.face_box[2] < sample.shape[1]
    with pytest.raises(InputError, match="out of range"):
        analyze_portrait(two, face_index=2)


def test_small_face_is_refused(sample):
    canvas = np.full((480, 480, 3), 200, np.uint8)
    canvas[150:310, 150:310] = cv2.resize(sample, (160, 160), interpolation=cv2.INTER_AREA)
    with pytest.raises(InputError, match="too small"):
        analyze_portrait(canvas, path="tiny.png")


@pytest.mark.parametrize("detector", ["cascade", "auto"])
def test_strongly_turned_face_warns(sample, analyses, detector):
    # Squeeze the image half on the subject's left side (a crude stand-in for yaw): symmetry and
    # eye placement break, detection still works, and the result must say so.
    h, w = sample.shape[:2]
    a = analyses[detector]
    cx = a.eye_mid[0]
    xs = np.arange(w, dtype=np.float32)
    mapx = np.tile(np.where(xs < cx, xs, cx + (xs - cx) / 0.3).astype(np.float32), (h, 1))
    mapy = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    turned = cv2.remap(sample, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    b = analyze_portrait(turned, detector=detector)
    assert b.frontality < a.frontality - 0.3
    assert any("non-frontal" in warning for warning in b.warnings)


def test_path_input_names_the_file(tmp_path):
    a = analyze_portrait(SAMPLE)
    assert len(a.faces) == 1
    flat = tmp_path / "flat.png"
    Image.fromarray(np.full((100, 100, 3), 90, np.uint8)).save(flat)
    with pytest.raises(InputError) as e:
        analyze_portrait(flat)
    assert str(flat) in str(e.value)


def test_analysis_from_box_uses_proportions():
    a = analysis_from_box((200, 160), (50, 40, 100, 100))
    assert a.point("right_eye") == pytest.approx([50 + 100 * BOX_RATIOS["right_eye"][0], 40 + 100 * BOX_RATIOS["right_eye"][1]])
    assert not any(l.detected for l in a.landmarks.values())
    assert a.to_face(a.points(["right_eye", "left_eye"])) == pytest.approx(np.array([[-0.5, 0], [0.5, 0]]))
    assert a.to_face(a.point("mouth_center")) == pytest.approx(FACE_PROPORTIONS["mouth_center"])
    # the eye frame follows the roll: rotate the eyes and the frame rotates with them
    t = math.radians(20)
    lms = dict(a.landmarks)
    mid, d = a.eye_mid, a.eye_distance / 2
    for name, sgn in (("right_eye", -1), ("left_eye", 1)):
        lms[name] = dataclasses.replace(lms[name], x=mid[0] + sgn * d * math.cos(t), y=mid[1] + sgn * d * math.sin(t))
    b = dataclasses.replace(a, landmarks=lms, roll_deg=20.0)
    uv = np.random.default_rng(0).normal(size=(10, 2))
    assert b.to_face(b.from_face(uv)) == pytest.approx(uv)
    assert b.from_face([0.0, 1.0]) == pytest.approx(mid + a.eye_distance * np.array([-math.sin(t), math.cos(t)]))
    u, v = b.face_grid()
    px = np.array([37.5, 91.5])  # the centre of pixel (row 91, column 37)
    assert (u[91, 37], v[91, 37]) == pytest.approx(tuple(b.to_face(px)), abs=1e-4)


def test_scaled_analysis_matches_resized_image(sample, sample_analysis):
    half = cv2.resize(sample, (256, 256), interpolation=cv2.INTER_AREA)
    s = sample_analysis.scaled(0.5)
    crop_a, _ = sample_analysis.crop(sample, 128)
    crop_b, _ = s.crop(half, 128)
    assert np.abs(crop_a.astype(int) - crop_b).mean() < 6
