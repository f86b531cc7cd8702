"""MP4 previews are H.264 that PyAV, OpenCV and Chromium play; the mp4v fallback warns once;
a full disk (injected, or a real tiny tmpfs) ends with exit 2 and nothing under the name."""
from __future__ import annotations

import errno
import io
import os
import re
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

from avatarkit.cli.main import main
from avatarkit.errors import InputError, OutputError
from avatarkit.export import video as video_mod
from avatarkit.export.images import to_uint8
from avatarkit.export.video import (DEFAULT_CRF, Mp4vFallbackWarning, VideoWriter, pad_to_even,
                                    read_video_frames, write_video)
from avatarkit.gaussians.ply import write_ply
from avatarkit.render import Camera, render
from test_render_outputs import head_like

# PSNR (dB) of our H.264 at the default crf (20) against the rendered frames (8 views, 128x128,
# of the test splats on white), measured 34.9 dB with PyAV and with OpenCV (crf 12: 37.4,
# crf 0: 39.1 — the rest is 4:2:0 chroma subsampling of a small colourful picture). 32 leaves
# ~3 dB for other x264 / FFmpeg builds; an RGB/YUV or size mix-up lands far below (< 20 dB).
MIN_PSNR_DEFAULT_CRF = 32.0


def psnr(got: list[np.ndarray], want: list[np.ndarray]) -> float:
    mse = np.mean([(g.astype(np.float64) - w) ** 2 for g, w in zip(got, want)])
    return float(10 * np.log10(255.0 ** 2 / max(mse, 1e-12)))


@pytest.fixture(scope="module")
def rendered():
    """8 rendered turntable views, (128, 128, 3) uint8."""
    gs = head_like(1500)
    return [to_uint8(render(gs, Camera.orbit((0, 1.6, 0), az, 5, 0.8, 30, 128, 128), (1, 1, 1)).rgb)
            for az in range(0, 360, 45)]


@pytest.fixture(scope="module")
def mp4(rendered, tmp_path_factory):
    path = tmp_path_factory.mktemp("mp4") / "turn.mp4"
    write_video(path, rendered, fps=12)
    return path


def decode_pyav(path) -> tuple[list[np.ndarray], "object"]:
    import av

    with av.open(str(path)) as c:
        s = c.streams.video[0]
        info = dict(codec=s.codec_context.name, pix_fmt=s.codec_context.pix_fmt, rate=s.average_rate,
                    profile=s.codec_context.profile, colorspace=s.codec_context.colorspace)
        return [f.to_ndarray(format="rgb24") for f in c.decode(s)], info


def decode_cv2(path) -> tuple[list[np.ndarray], str]:
    import cv2

    cap = cv2.VideoCapture(str(path))
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode("latin-1")
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(bgr[..., ::-1])
    cap.release()
    return frames, fourcc


# --- what we write ------------------------------------------------------------------------------

def test_mp4_is_h264_and_decodes_with_pyav_and_opencv(mp4, rendered):
    frames, info = decode_pyav(mp4)
    assert info["codec"] == "h264" and info["pix_fmt"] == "yuv420p"
    assert info["rate"] == 12 and info["colorspace"] == 1  # BT.709 tagged
    assert len(frames) == len(rendered)
    assert psnr(frames, rendered) > MIN_PSNR_DEFAULT_CRF
    cv_frames, fourcc = decode_cv2(mp4)
    assert fourcc.lower() in ("h264", "avc1") and len(cv_frames) == len(rendered)
    assert psnr(cv_frames, rendered) > MIN_PSNR_DEFAULT_CRF
    # web playback starts before the whole file is in: the index (moov) comes before the data
    data = mp4.read_bytes()
    assert 0 < data.find(b"moov") < data.find(b"mdat")


def test_colours_survive_both_decoders(tmp_path):
    """Saturated flat colours come back within a few levels: the RGB->YUV matrix we use is the
    one the stream says (a BT.601/709 mix-up shifts them by 10-20 levels)."""
    colours = [(220, 40, 60), (30, 200, 90), (40, 60, 230), (250, 240, 30)]
    frames = [np.full((64, 64, 3), c, np.uint8) for c in colours]
    path = tmp_path / "flat.mp4"
    write_video(path, frames, fps=4, crf=10)
    for got in (decode_pyav(path)[0], decode_cv2(path)[0]):
        centres = np.array([f[32, 32] for f in got], np.int32)
        assert np.abs(centres - np.array(colours)).max() <= 4


def test_odd_size_is_padded_by_repeating_the_edge(tmp_path, rendered):
    frames = [f[:95, :77] for f in rendered[:3]]
    path = tmp_path / "odd.mp4"
    with VideoWriter(path, fps=10) as v:
        v.extend(frames)
    assert v.size == (77, 95) and v.stored_size == (78, 96)
    back, _ = decode_pyav(path)
    assert back[0].shape == (96, 78, 3)
    assert psnr([b[:95, :77] for b in back], frames) > MIN_PSNR_DEFAULT_CRF
    # the padded column / row repeat the last ones (up to coding noise), no black seam
    assert np.abs(back[0][:95, 77].astype(int) - back[0][:95, 76]).mean() < 6
    assert np.abs(back[0][95, :77].astype(int) - back[0][94, :77]).mean() < 6
    padded = pad_to_even(frames[0])
    np.testing.assert_array_equal(padded[:95, :77], frames[0])
    np.testing.assert_array_equal(padded[95, :77], frames[0][94])
    np.testing.assert_array_equal(padded[:95, 77], frames[0][:, 76])


def test_crf_trades_size_for_quality(tmp_path, rendered):
    sizes, quality = [], []
    for crf in (12, DEFAULT_CRF, 32):
        path = tmp_path / f"q{crf}.mp4"
        write_video(path, rendered, fps=12, crf=crf)
        sizes.append(path.stat().st_size)
        quality.append(psnr(decode_pyav(path)[0], rendered))
    assert sizes[0] > sizes[1] > sizes[2]
    assert quality[0] > quality[1] > quality[2]


def test_bad_writer_options(tmp_path):
    for crf in (-1, 52, 2.5, True, "20"):
        with pytest.raises(InputError, match="crf"):
            VideoWriter(tmp_path / "a.mp4", crf=crf)
    with pytest.raises(InputError, match="preset"):
        VideoWriter(tmp_path / "a.mp4", preset="ludicrous")
    with pytest.raises(InputError, match="fps"):
        VideoWriter(tmp_path / "a.mp4", fps=1e300)
    assert os.listdir(tmp_path) == []


# --- fallback without PyAV -----------------------------------------------------------------------

def test_without_pyav_mp4v_with_one_warning(tmp_path, rendered, monkeypatch):
    monkeypatch.setitem(sys.modules, "av", None)  # `import av` raises ImportError
    path = tmp_path / "old.mp4"
    with pytest.warns(Mp4vFallbackWarning) as caught:
        with VideoWriter(path, fps=12) as v:
            v.extend(rendered[:4])
    assert len(caught) == 1 and "browsers" in str(caught[0].message)
    assert v.codec == "mp4v"
    frames, fourcc = decode_cv2(path)
    assert fourcc.lower() in ("mp4v", "fmp4") and len(frames) == 4  # FFmpeg names MPEG-4 Part 2 FMP4
    assert len(read_video_frames(path)) == 4  # read back through OpenCV too


def test_cli_prints_the_fallback_warning_once(tmp_path, monkeypatch, capsys):
    ply = tmp_path / "h.ply"
    write_ply(ply, head_like(200))
    monkeypatch.setitem(sys.modules, "av", None)
    out = tmp_path / "t.mp4"
    assert main(["render", str(ply), "-o", str(out), "--turntable", "3", "--width", "32", "--height", "32"]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "mp4v" in warnings[0]
    assert out.is_file()


# --- a full disk ---------------------------------------------------------------------------------

class FillingFile:
    """A real output file that fails like a full disk once `limit` bytes were written."""

    written: list[int] = []

    def __init__(self, path, limit):
        self._f = open(path, "w+b")
        self._limit = limit
        self._n = 0

    def write(self, data) -> int:
        n = len(memoryview(data).cast("B"))
        if self._n + n > self._limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._n += n
        FillingFile.written.append(self._n)
        return self._f.write(data)

    def fileno(self):
        # no descriptor: Pillow would write to it directly, around `write`
        raise io.UnsupportedOperation("fileno")

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()
        return False


def fill_after(monkeypatch, limit):
    FillingFile.written = []
    monkeypatch.setattr(video_mod, "_open_output", lambda path: FillingFile(path, limit))


@pytest.mark.parametrize("fmt", ["mp4", "gif"])
@pytest.mark.parametrize("fraction", [0.3, 0.95])
def test_injected_enospc_leaves_nothing(tmp_path, rendered, monkeypatch, fmt, fraction):
    frames = rendered[:4]  # GIF quantisation of rendered frames is slow
    full = tmp_path / f"full.{fmt}"
    write_video(full, frames, fps=12)
    size = full.stat().st_size
    out = tmp_path / "sub"
    out.mkdir()
    fill_after(monkeypatch, int(size * fraction))
    with pytest.raises(OutputError, match="disk full") as e:
        write_video(out / f"clip.{fmt}", frames, fps=12)
    assert e.value.path == str(out / f"clip.{fmt}")
    assert FillingFile.written and FillingFile.written[-1] > 0  # it failed after bytes were out
    assert os.listdir(out) == []


def test_cli_render_enospc_exit_2(tmp_path, monkeypatch, capsys):
    ply = tmp_path / "h.ply"
    write_ply(ply, head_like(300))
    fill_after(monkeypatch, 3000)
    out = tmp_path / "spin.mp4"
    code = main(["render", str(ply), "-o", str(out), "--turntable", "6", "--width", "64", "--height", "64", "-q"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip().splitlines() == [f"error: {out}: disk full while writing the video (nothing was written)"]
    assert sorted(os.listdir(tmp_path)) == ["h.ply"]


@pytest.fixture
def tiny_fs(tmp_path):
    """A 96 KiB tmpfs (root only; skipped where mounting is not allowed)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=96k", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def noise(n, size=200, seed=0):
    """Frames of 8-colour noise: ~110 KB as GIF, ~180 KB as MP4, either way more than the tiny
    file system holds (few colours keep GIF quantisation fast)."""
    rng = np.random.default_rng(seed)
    palette = np.array([[0, 0, 0], [255, 255, 255], [255, 0, 0], [0, 0, 255], [0, 255, 0],
                        [255, 255, 0], [0, 255, 255], [128, 128, 128]], np.uint8)
    return [palette[rng.integers(0, 8, (size, size))] for _ in range(n)]


@pytest.mark.parametrize("fmt", ["mp4", "gif"])
def test_real_full_filesystem_leaves_nothing(tiny_fs, fmt):
    with pytest.raises(OutputError, match="disk full"):
        write_video(tiny_fs / f"clip.{fmt}", noise(6), fps=12)
    assert os.listdir(tiny_fs) == []
    # and the same writer succeeds where there is room
    write_video(tiny_fs / f"small.{fmt}", [np.zeros((16, 16, 3))] * 2, fps=12)
    assert os.listdir(tiny_fs) == [f"small.{fmt}"]


def test_real_full_filesystem_mp4v_fallback_leaves_nothing(tiny_fs, monkeypatch, capfd):
    monkeypatch.setitem(sys.modules, "av", None)
    with pytest.warns(Mp4vFallbackWarning), pytest.raises(OutputError, match="not completely written"):
        write_video(tiny_fs / "clip.mp4", noise(6), fps=12)
    assert os.listdir(tiny_fs) == []
    assert capfd.readouterr().err == ""  # OpenCV's FFmpeg complaints are kept off the terminal


def test_real_full_filesystem_cli_exit_2(tiny_fs, tmp_path, capfd):
    ply = tmp_path / "h.ply"
    write_ply(ply, head_like(3000))
    out = tiny_fs / "spin.mp4"
    code = main(["render", str(ply), "-o", str(out), "--turntable", "24", "--width", "256", "--height",
                 "256", "--crf", "0", "-q"])
    err = capfd.readouterr().err
    assert code == 2, err
    assert err.strip().splitlines() == [f"error: {out}: disk full while writing the video (nothing was written)"]
    assert os.listdir(tiny_fs) == []


# --- browsers ------------------------------------------------------------------------------------

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--autoplay-policy=no-user-gesture-required"]


def chromium_reads(exe: str, folder: Path, video: Path) -> str:
    """What a <video> element in headless Chromium says of `video` once it has loaded a frame:
    "WxH duration readyState", or "error CODE MESSAGE"."""
    shutil.copy(video, folder / "clip.mp4")
    token = uuid.uuid4().hex
    (folder / "page.html").write_text(f"""<!doctype html><html><body>
<video id="v" src="clip.mp4" muted preload="auto"></video><pre id="out">pending</pre>
<script>
const v = document.getElementById('v'), out = document.getElementById('out');
v.addEventListener('loadeddata', () => {{
  out.textContent = '{token} ' + v.videoWidth + 'x' + v.videoHeight + ' ' + v.duration + ' ' + v.readyState;
}});
v.addEventListener('error', () => {{
  out.textContent = '{token} error ' + (v.error ? v.error.code + ' ' + v.error.message : '');
}});
</script></body></html>""")
    profile = folder / f"profile-{token}"
    r = subprocess.run([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=10000",
                        "--allow-file-access-from-files", "--dump-dom", (folder / "page.html").as_uri()],
                       capture_output=True, text=True, timeout=120)
    m = re.search(f'<pre id="out">{token} ([^<]*)</pre>', r.stdout)
    assert m, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    return m.group(1)


@pytest.mark.slow
def test_headless_chromium_plays_our_mp4(mp4, rendered, tmp_path, monkeypatch):
    exe = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                if shutil.which(n)), None)
    if exe is None:
        pytest.skip("Chromium is not installed (Debian: apt-get install chromium)")
    size, duration, ready = chromium_reads(exe, tmp_path, mp4).split()
    assert size == "128x128"
    assert float(duration) == pytest.approx(8 / 12, abs=0.05)
    assert int(ready) >= 2  # HAVE_CURRENT_DATA: a frame was decoded
    # the check tells players apart: the mp4v fallback's file is refused
    monkeypatch.setitem(sys.modules, "av", None)
    with pytest.warns(Mp4vFallbackWarning):
        write_video(tmp_path / "old.mp4", rendered, fps=12)
    assert chromium_reads(exe, tmp_path, tmp_path / "old.mp4").startswith("error")


@pytest.mark.slow  # builds and bakes an avatar: ~2 min on a loaded 2-core machine
def test_cli_bake_preview_enospc_exit_2(tmp_path_factory, tmp_path, monkeypatch, capsys):
    from avatarkit.motion import make_clip, save_clip
    from test_avatar import saved_avatar

    folder = saved_avatar(tmp_path_factory)
    clip = tmp_path / "nod.npz"
    save_clip(clip, make_clip("nod", frames=4, fps=25))
    fill_after(monkeypatch, 2000)
    out = tmp_path / "out"
    out.mkdir()
    preview = out / "preview.mp4"
    code = main(["bake", str(folder), str(clip), "--preview", str(preview), "--preview-size", "48",
                 "--substeps", "2", "--iterations", "4", "--preroll", "0", "-q"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.strip().splitlines() == [f"error: {preview}: disk full while writing the video (nothing was written)"]
    assert os.listdir(out) == []
