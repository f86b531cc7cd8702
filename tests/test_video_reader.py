"""The video reader: containers and codecs, phones' rotation flags, variable frame rate, seeking,
image folders, and bad inputs (exit 2, one line naming the file)."""
from __future__ import annotations

import os
import struct
import tracemalloc
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.errors import AvatarKitError, FormatError, InputError
from avatarkit.video import (Frame, TruncatedVideoWarning, display_transform, open_video,
                             read_frame, resample, resample_indices)

av = pytest.importorskip("av")

SHARED_VIDEOS = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "videos"
if not SHARED_VIDEOS.is_dir():  # worktrees sit one level deeper than a plain clone
    SHARED_VIDEOS = Path(__file__).resolve().parents[3] / "shared" / "data" / "videos"

CONTAINERS = {".mp4": ("mp4", "libx264", "h264"), ".mov": ("mov", "libx264", "h264"),
              ".mkv": ("matroska", "libx264", "h264"), ".avi": ("avi", "mpeg4", "mpeg4"),
              ".webm": ("webm", "libvpx-vp9", "vp9")}


def level(i: int) -> int:
    """The grey level that identifies frame i (0..19) in a coded video."""
    return 16 + 12 * i


def which_frame(rgb: np.ndarray) -> int:
    """The index whose `level` the centre of a decoded frame is nearest to."""
    h, w = rgb.shape[:2]
    v = rgb[h // 2 - 4:h // 2 + 4, w // 2 - 4:w // 2 + 4].mean()
    return int(round((v - 16) / 12))


def grey_frames(n: int, w: int = 64, h: int = 48) -> list[np.ndarray]:
    return [np.full((h, w, 3), level(i % 20), np.uint8) for i in range(n)]


def make_video(path: Path, frames, times=None, fps=30, rotation=None, hflip=False, options=None,
               metadata=None) -> Path:
    """Encode `frames` ((H, W, 3) uint8) into `path` (container and codec from its extension).
    times: seconds of each frame (variable frame rate) or None for i / fps. rotation: a display
    matrix (side data) of that many degrees counter-clockwise, as `VideoFrame.rotation` reads."""
    fmt, codec, _ = CONTAINERS[path.suffix]
    tb = Fraction(1, 1000) if times is not None else Fraction(1, fps)
    with av.open(str(path), "w", format=fmt) as c:
        s = c.add_stream(codec, rate=fps)
        s.height, s.width = frames[0].shape[:2]
        s.pix_fmt = "yuv420p"
        s.codec_context.time_base = tb
        if codec == "libx264":
            s.options = {"crf": "12", **(options or {})}
        elif options:
            s.options = dict(options)
        if rotation is not None or hflip:
            s.set_display_rotation(rotation or 0, hflip=hflip)
        for key, value in (metadata or {}).items():
            s.metadata[key] = value
        for i, img in enumerate(frames):
            f = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            f.pts = round(times[i] * 1000) if times is not None else i
            f.time_base = tb
            c.mux(s.encode(f))
        c.mux(s.encode())
    return path


def cv2_frames(path, limit: int | None = None) -> list[np.ndarray]:
    """OpenCV's decode (its own FFmpeg; applies the display rotation by default)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    out = []
    while limit is None or len(out) < limit:
        ok, bgr = cap.read()
        if not ok:
            break
        out.append(bgr[..., ::-1])
    cap.release()
    return out


def upright_marker(w: int = 64, h: int = 32) -> np.ndarray:
    """A picture whose orientation is unmistakable: red top-left, green top-right, blue
    bottom-left, grey elsewhere; wider than tall."""
    img = np.full((h, w, 3), 128, np.uint8)
    img[:10, :10] = (230, 30, 30)
    img[:10, -10:] = (30, 230, 30)
    img[-10:, :10] = (30, 30, 230)
    return img


def assert_same_picture(got: np.ndarray, want: np.ndarray, tol: float = 6.0):
    assert got.shape == want.shape
    assert np.abs(got.astype(float) - want).mean() < tol


# --- containers, codecs, timing ----------------------------------------------------------------

@pytest.mark.parametrize("ext", list(CONTAINERS))
def test_reads_containers_and_codecs(tmp_path, ext):
    path = make_video(tmp_path / f"clip{ext}", grey_frames(12), fps=30)
    with open_video(path) as video:
        info = video.info
        frames = list(video)
    assert (info.kind, info.codec, info.width, info.height) == ("video", CONTAINERS[ext][2], 64, 48)
    assert info.frame_count == 12 and len(frames) == 12
    assert info.fps == pytest.approx(30) and not info.variable_frame_rate
    assert info.duration == pytest.approx(12 / 30, abs=2e-3)  # Matroska keeps milliseconds
    assert [f.index for f in frames] == list(range(12))
    assert [which_frame(f.rgb) for f in frames] == list(range(12))
    np.testing.assert_allclose([f.time for f in frames], np.arange(12) / 30, atol=1e-3)
    f = frames[0].rgb
    assert f.dtype == np.uint8 and f.shape == (48, 64, 3) and f.flags.c_contiguous


@pytest.mark.skipif(not SHARED_VIDEOS.is_dir(), reason="../shared/data/videos is not here")
def test_real_video_matches_opencv():
    import cv2

    path = SHARED_VIDEOS / "talking_man_grey.mp4"
    with open_video(path) as video:
        assert (video.info.frame_count, video.info.fps, video.info.width) == (216, 30, 480)
        ours = [f.rgb for f in video.frames(0, 12)]
        tail = video.frame(215)
        np.testing.assert_array_equal(tail.rgb, next(video.frames_from_start(215)).rgb)
    cap = cv2.VideoCapture(str(path))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) == 216
    cap.release()
    for a, b in zip(ours, cv2_frames(path, limit=12)):
        # same bitstream decode; YUV->RGB rounding may differ by a level
        assert np.abs(a.astype(int) - b).max() <= 3


@pytest.mark.parametrize("ext", [".mp4", ".mkv"])
def test_variable_frame_rate_keeps_timing(tmp_path, ext):
    # a phone clip slowing down in low light: 30 fps, then gaps of 100 and 167 ms
    times = [0.0, 0.033, 0.067, 0.1, 0.2, 0.233, 0.4, 0.433, 0.467]
    path = make_video(tmp_path / f"vfr{ext}", grey_frames(len(times)), times=times)
    with open_video(path) as video:
        assert video.info.variable_frame_rate
        np.testing.assert_allclose(video.times, times, atol=1.5e-3)
        frames = list(video)
        assert video.info.fps == pytest.approx(8 / 0.467, rel=0.01)  # (N - 1) / span
    assert [which_frame(f.rgb) for f in frames] == list(range(len(times)))
    np.testing.assert_allclose([f.time for f in frames], times, atol=1.5e-3)
    # to a constant 30 fps: the nearest frame in time, repeated across the gaps
    want = [0, 1, 2, 3, 3, 4, 4, 5, 5, 5, 6, 6, 6, 7, 8]
    assert resample_indices(video.times, 30).tolist() == want
    out = list(resample(iter(frames), 30))
    assert [f.source_index for f in out] == want and [f.index for f in out] == list(range(15))
    np.testing.assert_allclose([f.time for f in out], np.arange(15) / 30)
    assert [which_frame(f.rgb) for f in out] == want


def test_resample_streaming_matches_the_index_reference():
    rng = np.random.default_rng(3)
    for _ in range(60):
        n = int(rng.integers(1, 40))
        times = np.cumsum(np.concatenate([[rng.uniform(0, 2)], rng.choice([1 / 30, 1 / 60, 0.1, 0.013], n - 1)]))
        fps = float(rng.choice([5, 12.5, 24, 30, 29.97, 60, 120]))
        idx = resample_indices(times, fps)
        grid = times[0] + np.arange(len(idx)) / fps
        # nearest frame in time, and the grid spans the source
        assert np.allclose(np.abs(grid - times[idx]), np.abs(grid[:, None] - times[None]).min(1))
        assert grid[-1] <= times[-1] + 1e-6 and grid[-1] + 1 / fps > times[-1]
        src = [Frame(index=i, time=float(t), rgb=np.zeros((1, 1, 3), np.uint8)) for i, t in enumerate(times)]
        assert [f.source_index for f in resample(src, fps)] == idx.tolist()
    # a constant rate resampled to itself is the identity
    same = np.arange(50) / 30
    assert resample_indices(same, 30).tolist() == list(range(50))
    assert resample_indices(same, 15).tolist() == list(range(0, 50, 2))


def test_seeking_matches_decoding_from_the_start(tmp_path):
    # keyframes every 8 frames with B-frames: seeks land on a keyframe before the target
    n = 40
    path = make_video(tmp_path / "gop.mp4", grey_frames(n), options={"g": "8", "bf": "2", "keyint_min": "8"})
    with open_video(path) as video:
        calls = []
        decode = video._frames
        video._frames = lambda start, end, seek: (calls.append(seek), decode(start, end, seek))[1]
        for start in (1, 7, 8, 9, 20, 37, 39):
            end = min(start + 3, n)
            calls.clear()
            fast = list(video.frames(start, end))
            assert calls == [True]  # the seek landed; no fallback to decoding from the start
            slow = list(video.frames_from_start(start, end))
            assert [f.index for f in fast] == [f.index for f in slow] == list(range(start, end))
            for a, b in zip(fast, slow):
                np.testing.assert_array_equal(a.rgb, b.rgb)
                assert a.time == b.time
            assert [which_frame(f.rgb) for f in fast] == [i % 20 for i in range(start, end)]
        assert which_frame(video.frame(25).rgb) == 5
    assert read_frame(path, 33).index == 33


def test_frames_are_streamed(tmp_path):
    """Memory stays flat in the video's length: iterating keeps no frame alive."""
    path = make_video(tmp_path / "long.mp4", grey_frames(150, 128, 128))
    with open_video(path) as video:
        tracemalloc.start()
        try:
            count = 0
            for frame in video:
                count += 1
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    frame_bytes = 128 * 128 * 3
    assert count == 150
    assert peak < 20 * frame_bytes  # all 150 would be 150x


# --- rotation ---------------------------------------------------------------------------------

def set_tkhd_matrix(path: Path, a: float, b: float, c: float, d: float) -> None:
    """Rewrite the track header's display matrix as a phone camera writes it (ISO 14496-12
    tkhd: a b u / c d v / x y w, 16.16 fixed point, u v w 2.30; big endian)."""
    data = bytearray(path.read_bytes())
    i = data.find(b"tkhd")
    assert i > 0 and data.find(b"tkhd", i + 4) == -1
    version = data[i + 4]
    at = i + 4 + 4 + (32 if version == 1 else 20) + 16
    height = struct.unpack(">I", data[at + 40:at + 44])[0]  # tkhd height (16.16) follows the matrix
    fixed = [round(v * 65536) for v in (a, b)] + [0] + [round(v * 65536) for v in (c, d)] + [0]
    fixed += [height if b > 0 else 0, 0, 1 << 30]
    data[at:at + 36] = struct.pack(">9i", *fixed)
    path.write_bytes(bytes(data))


def test_phone_portrait_video_reads_upright(tmp_path):
    """An iPhone held upright records landscape pictures turned a quarter counter-clockwise and
    a tkhd matrix (0 1 / -1 0) that players turn a quarter clockwise."""
    up = upright_marker()  # (32, 64): the upright scene
    coded = np.rot90(up, 1)  # (64, 32) as the sensor stores it
    path = make_video(tmp_path / "IMG_0001.mov", [coded] * 3)
    set_tkhd_matrix(path, 0, 1, -1, 0)
    with open_video(path) as video:
        assert (video.info.width, video.info.height) == (64, 32)
        assert (video.info.rotation, video.info.mirrored) == (90, False)
        for f in video:
            assert_same_picture(f.rgb, up)
    assert_same_picture(cv2_frames(path)[0], up)  # OpenCV's autorotation agrees


@pytest.mark.parametrize("ccw", [90, 180, -90])
def test_display_matrix_side_data_is_applied(tmp_path, ccw):
    up = upright_marker()
    coded = np.rot90(up, -ccw // 90)  # stored turned the other way
    path = make_video(tmp_path / f"rot{ccw}.mp4", [coded] * 2, rotation=ccw)
    with open_video(path) as video:
        frames = list(video)
        assert (video.info.width, video.info.height) == (64, 32)
        assert video.info.rotation == (-ccw) % 360
    for f in frames:
        assert_same_picture(f.rgb, up)
    assert_same_picture(cv2_frames(path)[0], up)


def test_mirrored_display_matrix(tmp_path):
    up = upright_marker()
    path = make_video(tmp_path / "selfie.mp4", [up[:, ::-1]] * 2, hflip=True)
    with open_video(path) as video:
        assert video.info.mirrored and video.info.rotation == 0
        assert_same_picture(video.frame(1).rgb, up)


def test_legacy_rotate_tag(tmp_path):
    up = upright_marker()
    path = make_video(tmp_path / "old.mkv", [np.rot90(up, 1)] * 2, metadata={"rotate": "90"})
    with open_video(path) as video:
        assert video.info.rotation == 90
        assert_same_picture(video.frame(0).rgb, up)


def test_display_transform_names():
    one = 1 << 16
    assert display_transform([one, 0, 0, 0, one, 0, 0, 0, 1 << 30]) == ("none", 0, False)
    assert display_transform([0, one, 0, -one, 0, 0, 0, 0, 1 << 30]) == ("clock", 90, False)
    assert display_transform([0, -one, 0, one, 0, 0, 0, 0, 1 << 30]) == ("cclock", 270, False)
    assert display_transform([-one, 0, 0, 0, -one, 0, 0, 0, 1 << 30]) == ("hvflip", 180, False)
    assert display_transform([-one, 0, 0, 0, one, 0, 0, 0, 1 << 30]) == ("hflip", 0, True)
    assert display_transform([0] * 9) == ("none", 0, False)


# --- image folders ----------------------------------------------------------------------------

def write_pngs(folder: Path, names, w=40, h=30):
    from PIL import Image

    folder.mkdir(exist_ok=True)
    for i, name in enumerate(names):
        Image.fromarray(np.full((h, w, 3), level(i), np.uint8)).save(folder / name)


def test_image_folder(tmp_path):
    folder = tmp_path / "frames"
    names = [f"f{i}.png" for i in range(1, 12)]  # f1 .. f11: f10 sorts after f9
    write_pngs(folder, names)
    (folder / "notes.txt").write_text("not an image")
    (folder / ".f0.png").write_bytes(b"hidden")
    with open_video(folder, fps=25) as video:
        assert (video.info.kind, video.info.frame_count, video.info.fps) == ("images", 11, 25)
        assert (video.info.width, video.info.height) == (40, 30)
        frames = list(video)
        assert [which_frame(f.rgb) for f in frames] == list(range(11))
        np.testing.assert_allclose([f.time for f in frames], np.arange(11) / 25)
        assert which_frame(video.frame(9).rgb) == 9
        assert [f.index for f in video.frames(3, 5)] == [3, 4]


def test_image_folder_errors(tmp_path):
    folder = tmp_path / "frames"
    write_pngs(folder, ["a.png", "b.png"])
    with pytest.raises(InputError, match="frame rate"):
        open_video(folder)
    with pytest.raises(InputError, match="fps"):
        open_video(folder, fps=0)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FormatError, match="no image files"):
        open_video(empty, fps=30)
    write_pngs(folder, ["c.png"], w=20)
    with open_video(folder, fps=30) as video:
        with pytest.raises(FormatError, match="c.png: is 20x30"):
            list(video)
    (folder / "d.png").write_bytes(b"\x89PNG broken")
    with open_video(folder, fps=30) as video:
        with pytest.raises(FormatError, match="d.png"):
            video.frame(3)


# --- bad input ---------------------------------------------------------------------------------

def audio_only(path: Path) -> Path:
    with av.open(str(path), "w") as c:
        s = c.add_stream("aac", rate=44100)
        f = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        f.sample_rate, f.pts = 44100, 0
        c.mux(s.encode(f))
        c.mux(s.encode())
    return path


def no_frames(path: Path) -> Path:
    """A Matroska file with a video track that holds no frame (beside a short audio track)."""
    with av.open(str(path), "w", format="matroska") as c:
        v = c.add_stream("libx264", rate=30)
        v.width = v.height = 64
        v.pix_fmt = "yuv420p"
        audio = c.add_stream("aac", rate=44100)
        f = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        f.sample_rate, f.pts = 44100, 0
        c.mux(audio.encode(f))
        c.mux(audio.encode())
        c.mux(v.encode())
    return path


def cut_before_index(path: Path) -> Path:
    """An MP4 whose moov atom (written last without faststart) is cut off."""
    make_video(path, grey_frames(20))
    data = path.read_bytes()
    path.write_bytes(data[:data.find(b"moov") - 8])
    return path


BAD = {
    "missing.mp4": (lambda p: p, InputError, "not found"),
    "empty.mp4": (lambda p: (p.write_bytes(b""), p)[1], FormatError, "not a video FFmpeg can read"),
    "notes.mp4": (lambda p: (p.write_text("these are my notes\n" * 50), p)[1], FormatError,
                  "not a video FFmpeg can read"),
    "voice.m4a": (audio_only, FormatError, "has no video stream"),
    "blank.mkv": (no_frames, FormatError, "has no frames"),
    "cut.mp4": (cut_before_index, FormatError, "without its index"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_videos_are_clear_errors(tmp_path, name, capfd):
    make, kind, message = BAD[name]
    path = make(tmp_path / name)
    with pytest.raises(kind, match=message) as e:
        open_video(path)
    assert isinstance(e.value, AvatarKitError) and e.value.path == str(path)
    if path.suffix in (".mp4", ".mkv"):  # through the CLI: exit 2, one line naming the file
        assert main(["inspect", str(path)]) == 2
        err = capfd.readouterr().err.strip().splitlines()  # FFmpeg's own log included
        assert len(err) == 1 and err[0].startswith(f"error: {path}: ")


def test_truncated_video_warns_and_reads_what_is_there(tmp_path):
    from avatarkit.export.video import write_video

    rng = np.random.default_rng(0)
    path = tmp_path / "cut.mp4"
    write_video(path, [rng.integers(0, 256, (64, 64, 3), dtype=np.uint8) for _ in range(30)], fps=30)
    data = path.read_bytes()  # faststart: the index is first, the data is cut
    path.write_bytes(data[:int(len(data) * 0.6)])
    with pytest.warns(TruncatedVideoWarning, match="cut short"):
        video = open_video(path)
    assert 0 < video.info.frame_count < 30
    assert 0 < sum(1 for _ in video) <= video.info.frame_count


def test_frame_range_errors(tmp_path):
    path = make_video(tmp_path / "c.mp4", grey_frames(5))
    with open_video(path) as video:
        for start, end in ((5, None), (-1, None), (2, 2), (0, 6), (3, 1)):
            with pytest.raises(InputError, match=f"{path}: frame") as e:
                list(video.frames(start, end))
            assert e.value.path == str(path)
        with pytest.raises(InputError, match="outside the video's 5 frames"):
            video.frame(7)
        with pytest.raises(InputError, match="integer"):
            video.frame(1.5)
    with pytest.raises(InputError, match="only for image folders"):
        open_video(path, fps=30)


def test_inspect_video(tmp_path, capsys):
    times = [0.0, 0.033, 0.067, 0.2]
    path = make_video(tmp_path / "v.mp4", grey_frames(4), times=times, rotation=-90)
    assert main(["inspect", str(path), "--json"]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert out["kind"] == "video" and out["codec"] == "h264" and out["frames"] == 4
    assert out["size"] == "48x64" and out["rotation_applied"].startswith("90 degrees clockwise")
    assert out["frame_rate"].startswith("variable")


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root reads files whatever their permissions")
def test_unreadable_file(tmp_path):
    path = make_video(tmp_path / "locked.mp4", grey_frames(2))
    path.chmod(0)
    try:
        with pytest.raises(InputError, match="permission denied"):
            open_video(path)
    finally:
        path.chmod(0o644)


def test_apply_transform_turns_as_numpy_does():
    """`apply_transform`'s OpenCV quarter / half turns (uint8 RGB(A)) give numpy's rot90 / flips
    pixel for pixel, on odd-sized pictures; other dtypes and channel counts take numpy's path."""
    from avatarkit.video import apply_transform

    rng = np.random.default_rng(2)
    want = {"clock": lambda a: np.rot90(a, -1), "cclock": lambda a: np.rot90(a, 1),
            "hvflip": lambda a: a[::-1, ::-1], "cclock_flip": lambda a: a.transpose(1, 0, 2),
            "clock_flip": lambda a: np.rot90(a, -1)[::-1], "hflip": lambda a: a[:, ::-1], "vflip": lambda a: a[::-1]}
    for shape, dtype in (((37, 61, 3), np.uint8), ((8, 5, 4), np.uint8), ((9, 6, 1), np.uint8), ((7, 4, 3), np.float32)):
        img = (rng.random(shape) * 255).astype(dtype)
        for name, turn in want.items():
            got = apply_transform(img, name)
            assert got.shape == turn(img).shape and got.dtype == img.dtype and got.flags.c_contiguous
            np.testing.assert_array_equal(got, turn(img))


def test_max_side_reads_large_frames_area_downscaled(tmp_path, monkeypatch):
    """Frames larger than `video.MAX_SIDE` come out area-averaged to it (cv2.INTER_AREA of the
    upright full frame), `info` giving the size read and the scale, for a plain file, a phone's
    rotated portrait file and an image folder; at or under it they are the file's own pixels."""
    import cv2

    import avatarkit.video as V

    rng = np.random.default_rng(4)
    up = [cv2.resize(rng.integers(0, 256, (8, 5, 3), dtype=np.uint8), (40, 64)) for _ in range(3)]  # upright 40x64
    plain = make_video(tmp_path / "plain.mp4", up)
    turned = make_video(tmp_path / "turned.mp4", [np.ascontiguousarray(np.rot90(u, 1)) for u in up], rotation=-90)
    folder = tmp_path / "pngs"
    write_pngs(folder, [f"f{i}.png" for i in range(3)], w=40, h=64)
    monkeypatch.setattr(V, "MAX_SIDE", None)
    full = {p: [f.rgb for f in open_video(p, fps=10 if p == folder else None).frames()] for p in (plain, turned, folder)}
    monkeypatch.setattr(V, "MAX_SIDE", 32)
    for p in (plain, turned, folder):
        with open_video(p, fps=10 if p == folder else None) as v:
            assert (v.info.width, v.info.height, v.info.scale) == (20, 32, 0.5)
            got = [f.rgb for f in v.frames()]
            assert v.frame(1).rgb.shape == (32, 20, 3)
        for g, f in zip(got, full[p]):
            np.testing.assert_array_equal(g, cv2.resize(f, (20, 32), interpolation=cv2.INTER_AREA))
    monkeypatch.setattr(V, "MAX_SIDE", 64)                        # at the limit: untouched
    with open_video(plain) as v:
        assert (v.info.width, v.info.height, v.info.scale) == (40, 64, 1.0)
        np.testing.assert_array_equal(v.frame(2).rgb, full[plain][2])
    assert V.read_size(1080, 1920, 1280) == (720, 1280) and V.read_size(1920, 1080, 1280) == (1280, 720)
    assert V.read_size(480, 480, 1280) == (480, 480) and V.read_size(4000, 3000, 0) == (4000, 3000)
