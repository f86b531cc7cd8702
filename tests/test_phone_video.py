"""`synthetic.phone_video`: the benchmark's square clip at a phone's size and orientation."""
import numpy as np

from avatarkit.export.video import write_video
from avatarkit.synthetic.phone_video import phone_frame, phone_video
from avatarkit.video import open_video


def _square_clip(path, n=4, s=48):
    """n frames (s, s): a light wall, a dark square (the head) moving right, a bar at the bottom."""
    frames = []
    for i in range(n):
        f = np.full((s, s, 3), (220, 215, 205), np.uint8)
        f[12:30, 10 + 3 * i:28 + 3 * i] = (90, 60, 40)
        f[40:, 20:28] = (200, 150, 120)
        frames.append(f)
    write_video(path, frames, fps=24, crf=0)
    return frames


def test_phone_frame_centres_the_upscaled_square_and_repeats_the_border():
    f = np.zeros((4, 4, 3), np.uint8)
    f[:, :, 0] = np.arange(4) * 60
    out = phone_frame(f, 8, 16)                                  # portrait: 8 across, 16 down
    assert out.shape == (16, 8, 3)
    assert (out[:4] == out[4]).all() and (out[12:] == out[11]).all()   # the edge rows repeated
    assert out[8, 0, 0] < out[8, 7, 0]                           # the square's gradient kept, left to right
    land = phone_frame(f, 16, 8)
    assert land.shape == (8, 16, 3) and (land[:, :4] == land[:, 4:5]).all()


def test_phone_video_is_a_rotated_portrait_at_30_fps_that_reads_upright(tmp_path):
    src = str(tmp_path / "sq.mp4")
    frames = _square_clip(src)
    por, land = str(tmp_path / "p.mp4"), str(tmp_path / "l.mp4")
    assert phone_video(src, por, size=(48, 96)) == len(frames)
    assert phone_video(src, land, portrait=False, size=(48, 96)) == len(frames)
    with open_video(por) as v:
        assert (v.info.width, v.info.height, v.info.rotation, v.info.frame_count) == (48, 96, 90, 4)
        assert abs(v.info.fps - 30) < 1e-6
        got = [f.rgb for f in v.frames()]
    with open_video(land) as v:
        assert (v.info.width, v.info.height, v.info.rotation) == (96, 48, 0)
        wide = [f.rgb for f in v.frames()]
    for f, p, w in zip(frames, got, wide):
        want = phone_frame(f, 48, 96).astype(int)
        assert np.abs(p.astype(int) - want).mean() < 6          # upright: the display matrix applied
        assert np.abs(w.astype(int) - phone_frame(f, 96, 48)).mean() < 6
    # the head (dark) is near the top of the upright portrait, the neck's bar runs to the bottom
    dark = got[0].sum(axis=2) < 400
    rows = np.nonzero(dark.any(axis=1))[0]
    assert 24 + 12 - 2 <= rows.min() and rows.max() <= 24 + 30 + 2
