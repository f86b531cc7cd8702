"""Render outputs: PNG, contact sheet, MP4/GIF (read back with OpenCV / Pillow), previews and
the `avatarkit render` command."""
import json
import os

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.errors import InputError, OutputError
from avatarkit.export.images import contact_sheet, read_png, to_uint8, write_contact_sheet, write_png
from avatarkit.export.video import VideoWriter, read_video_frames, write_video
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.ply import write_ply
from avatarkit.render import Camera, render
from avatarkit.render.preview import PreviewOptions, parse_color, parse_vec3, render_preview


def head_like(n=400, seed=0):
    """A small blob of splats around (0, 1.6, 0), coloured by position."""
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(n, 3)) * [0.08, 0.11, 0.09] + [0, 1.6, 0]
    q = rng.normal(size=(n, 4))
    rgb = np.clip(0.5 + (means - [0, 1.6, 0]) * 4, 0, 1)
    return GaussianSet.from_colors(means, q, 0.012 * np.exp(0.3 * rng.normal(size=(n, 3))),
                                   rng.uniform(0.5, 1, n), rgb)


def no_partials(folder):
    return not [p for p in os.listdir(folder) if ".partial" in p]


def frames(n, w=40, h=30):
    return [np.full((h, w, 3), (i + 1) / (n + 1), np.float32) for i in range(n)]


# --- images -----------------------------------------------------------------------------------

def test_png_round_trip_rgb_and_rgba(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.uniform(size=(21, 34, 3)).astype(np.float32)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), to_uint8(img))
    alpha = rng.uniform(size=(21, 34))
    write_png(tmp_path / "b.png", img, alpha=alpha)
    back = read_png(tmp_path / "b.png")
    assert back.shape == (21, 34, 4)
    np.testing.assert_array_equal(back[..., 3], to_uint8(alpha))
    np.testing.assert_array_equal(back[..., :3], to_uint8(img))
    assert no_partials(tmp_path)


def test_to_uint8_clips_and_rounds():
    a = np.array([[-1.0, 0.0, 0.5, 1.0, 7.0, np.nan]])
    np.testing.assert_array_equal(to_uint8(a), [[0, 0, 128, 255, 255, 0]])


def test_contact_sheet_layout(tmp_path):
    imgs = [np.full((10, 20, 3), v, np.uint8) for v in (10, 20, 30, 40, 50)]
    sheet = contact_sheet(imgs, columns=3, pad=2, background=(0, 0, 0))
    assert sheet.shape == (2 * 10 + 3 * 2, 3 * 20 + 4 * 2, 3)
    assert (sheet[2:12, 2:22] == 10).all() and (sheet[2:12, 24:44] == 20).all()
    assert (sheet[14:24, 2:22] == 40).all() and (sheet[14:24, 46:66] == 0).all()  # empty cell
    labelled = contact_sheet(imgs, labels=list("abcde"))
    assert labelled.shape[:2] == contact_sheet(imgs).shape[:2] and (labelled != contact_sheet(imgs)).any()
    write_contact_sheet(tmp_path / "s.png", imgs, columns=2)
    assert read_png(tmp_path / "s.png").shape == (3 * 10 + 4 * 4, 2 * 20 + 3 * 4, 3)
    with pytest.raises(InputError, match="share one size"):
        contact_sheet([imgs[0], np.zeros((5, 5, 3))])
    with pytest.raises(InputError, match="labels"):
        contact_sheet(imgs, labels=["x"])


# --- video ------------------------------------------------------------------------------------

@pytest.mark.parametrize("ext", [".mp4", ".gif"])
def test_video_written_and_read_back(tmp_path, ext):
    src = frames(9)
    path = tmp_path / f"clip{ext}"
    assert write_video(path, iter(src), fps=12) == 9
    back = read_video_frames(path)
    assert len(back) == 9
    assert back[0].shape == (30, 40, 3)
    means = [f.mean() / 255 for f in back]
    np.testing.assert_allclose(means, [f.mean() for f in src], atol=0.03)
    assert no_partials(tmp_path)


def test_video_metadata(tmp_path):
    import cv2
    from PIL import Image

    with VideoWriter(tmp_path / "a.mp4", fps=10) as v:
        v.extend(frames(4))
    assert v.codec == "h264"
    cap = cv2.VideoCapture(str(tmp_path / "a.mp4"))
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(10)
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 4
    cap.release()
    write_video(tmp_path / "a.gif", frames(3), fps=20)
    with Image.open(tmp_path / "a.gif") as im:
        assert im.n_frames == 3 and im.info["duration"] == 50 and im.info["loop"] == 0


def test_video_failure_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with VideoWriter(tmp_path / "x.mp4") as v:
            v.append(frames(1)[0])
            raise RuntimeError("interrupted")
    with pytest.raises(InputError, match="frame 1 is 20x10"):
        write_video(tmp_path / "y.gif", [np.zeros((30, 40, 3)), np.zeros((10, 20, 3))])
    with pytest.raises(InputError, match="at least one frame"):
        write_video(tmp_path / "z.mp4", [])
    assert os.listdir(tmp_path) == []
    with pytest.raises(OutputError, match="unknown video extension"):
        VideoWriter(tmp_path / "clip.avi")
    with pytest.raises(OutputError, match="does not exist"):
        VideoWriter(tmp_path / "missing" / "clip.mp4")


# --- previews ---------------------------------------------------------------------------------

def test_preview_kinds(tmp_path):
    gs = head_like()
    r = render_preview(gs, tmp_path / "one.png", PreviewOptions(width=64, height=48))
    assert (r.kind, r.frames) == ("image", 1)
    img = read_png(tmp_path / "one.png")
    assert img.shape == (48, 64, 3)
    # the default camera frames the subject: it covers the centre, not the corners
    assert img[24, 32].max() > 50 and img[0, 0].max() == 0 and img[-1, -1].max() == 0
    seen = []
    r = render_preview(gs, tmp_path / "spin.gif", PreviewOptions(width=32, height=32, turntable=5),
                       progress=lambda done, total: seen.append((done, total)))
    assert r.frames == 5 and seen[-1] == (5, 5) and len(read_video_frames(tmp_path / "spin.gif")) == 5
    r = render_preview(gs, tmp_path / "sheet.png", PreviewOptions(width=32, height=24, contact_sheet=4,
                                                                  columns=4))
    assert read_png(tmp_path / "sheet.png").shape == (24 + 8, 4 * 32 + 5 * 4, 3)


def test_preview_with_camera_matches_render(tmp_path):
    gs = head_like()
    cam = Camera.orbit((0, 1.6, 0), 30, 10, 0.9, 35, 48, 40)
    render_preview(gs, tmp_path / "c.png", PreviewOptions(camera=cam, background=(1, 1, 1)))
    np.testing.assert_array_equal(read_png(tmp_path / "c.png"), to_uint8(render(gs, cam, (1, 1, 1)).rgb))


def test_preview_option_errors(tmp_path):
    gs = head_like(20)
    with pytest.raises(OutputError, match="unknown output extension"):
        render_preview(gs, tmp_path / "x.jpg")
    with pytest.raises(InputError, match="video"):
        render_preview(gs, tmp_path / "x.png", PreviewOptions(turntable=3))
    with pytest.raises(InputError, match="PNG"):
        render_preview(gs, tmp_path / "x.mp4", PreviewOptions(contact_sheet=3))
    with pytest.raises(InputError, match="one view"):
        render_preview(gs, tmp_path / "x.png", PreviewOptions(camera=Camera.from_fov(30, 8, 8),
                                                              contact_sheet=2))
    with pytest.raises(InputError, match="no splats"):
        render_preview(GaussianSet.empty(), tmp_path / "x.png")
    assert os.listdir(tmp_path) == []


def test_parse_helpers():
    assert parse_color("white") == (1, 1, 1)
    assert parse_color("#ff8000") == pytest.approx((1, 128 / 255, 0))
    assert parse_color("0.1, 0.2,0.3") == (0.1, 0.2, 0.3)
    assert parse_vec3("0,1.6,-2") == (0, 1.6, -2)
    for bad in ("1,2", "#12345", "1.5,0,0", "nan,0,0", "blue"):
        with pytest.raises(InputError, match="colour"):
            parse_color(bad)
    with pytest.raises(InputError, match="x,y,z"):
        parse_vec3("1,2,inf")


# --- CLI --------------------------------------------------------------------------------------

@pytest.fixture
def ply(tmp_path):
    path = tmp_path / "head.ply"
    write_ply(path, head_like())
    return path


def test_cli_renders_png_video_and_sheet(tmp_path, ply, capsys):
    assert main([ "render", str(ply), "-o", str(tmp_path / "a.png"), "--width", "64", "--height", "40",
                 "--azimuth", "30", "--background", "white", "-q"]) == 0
    img = read_png(tmp_path / "a.png")
    assert img.shape == (40, 64, 3) and (img[0, 0] == 255).all()
    assert main(["render", str(ply), "-o", str(tmp_path / "t.mp4"), "--turntable", "6", "--width", "32",
                 "--height", "32"]) == 0
    out = capsys.readouterr()
    assert "6-frame turntable" in out.out
    assert len(read_video_frames(tmp_path / "t.mp4")) == 6
    assert main(["render", str(ply), "-o", str(tmp_path / "s.png"), "--contact-sheet", "3", "--width", "16",
                 "--height", "16", "--columns", "3", "-q"]) == 0
    assert read_png(tmp_path / "s.png").shape == (16 + 8, 3 * 16 + 16, 3)


def test_cli_camera_file(tmp_path, ply):
    cam = Camera.orbit((0, 1.6, 0), -20, 5, 0.8, 30, 40, 30)
    cam.to_json(tmp_path / "cam.json")
    assert main(["render", str(ply), "-o", str(tmp_path / "c.png"), "--camera", str(tmp_path / "cam.json"),
                 "-q"]) == 0
    from avatarkit.gaussians.io import load_gaussians
    expected = to_uint8(render(load_gaussians(ply), cam).rgb)
    np.testing.assert_array_equal(read_png(tmp_path / "c.png"), expected)


@pytest.mark.parametrize("args, words", [
    (["-o", "{d}/x.jpg"], "unknown output extension"),
    (["-o", "{d}/x.png", "--turntable", "4"], "turntable is a video"),
    (["-o", "{d}/x.png", "--background", "2,0,0"], "colour"),
    (["-o", "{d}/x.png", "--target", "1,2"], "x,y,z"),
    (["-o", "{d}/x.png", "--camera", "{d}/nope.json"], "nope.json: camera file not found"),
    (["-o", "{d}/x.png", "--camera", "{d}/bad.json"], "bad.json: camera width must be a positive"),
    (["-o", "{d}/x.png", "--camera", "{d}/nan.json"], "nan.json: camera fx must be finite"),
])
def test_cli_bad_input_exit_2(tmp_path, ply, capsys, args, words):
    good = Camera.from_fov(30, 8, 8).to_dict()
    (tmp_path / "bad.json").write_text(json.dumps(dict(good, width=0)))
    (tmp_path / "nan.json").write_text(json.dumps(dict(good, fx=float("nan"))))
    code = main(["render", str(ply)] + [a.format(d=tmp_path) for a in args])
    err = capsys.readouterr().err
    assert code == 2
    assert words in err and err.startswith("error: ") and "Traceback" not in err
    assert not (tmp_path / "x.png").exists() and no_partials(tmp_path)


def test_cli_unreadable_splats(tmp_path, capsys):
    bad = tmp_path / "broken.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n")
    for path in (bad, tmp_path / "missing.ply"):
        assert main(["render", str(path), "-o", str(tmp_path / "x.png")]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {path}")
    assert main(["render", str(bad), "-o", str(tmp_path / "x.png"), "--width", "0"]) == 2
    assert not (tmp_path / "x.png").exists()
