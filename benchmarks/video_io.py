"""Video I/O speed: our H.264 writer against OpenCV's mp4v (the old writer, the baseline), and
our reader against OpenCV's VideoCapture on the same file.

Writes N frames of WxW (default 60 at 512x512, a smooth moving picture like a render) with
`export.video.write_video` (PyAV, libx264, default crf/preset) and with cv2.VideoWriter('mp4v'),
then decodes a talking-head clip (../shared/data/videos, or the file just written) with
`avatarkit.video` and with cv2.VideoCapture. Prints best-of-3 seconds, frames/s, file sizes,
PSNR against the source frames, and the ratios ours / OpenCV.

    python benchmarks/video_io.py [--frames 60] [--size 512] [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from avatarkit.export.video import DEFAULT_CRF, DEFAULT_PRESET, write_video
from avatarkit.video import open_video


def frames(n: int, size: int) -> list[np.ndarray]:
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    out = []
    for i in range(n):
        cx = 0.5 + 0.2 * np.sin(i / 9)
        blob = np.exp(-((xx - cx) ** 2 + (yy - 0.5) ** 2) / 0.03)
        img = np.stack([blob, blob * (0.5 + 0.5 * np.sin(xx * 20)), 0.3 + 0.4 * yy], -1)
        out.append((np.clip(img, 0, 1) * 255).astype(np.uint8))
    return out


def best(repeat, fn) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def write_cv2(path, imgs, fps=24):
    import cv2

    h, w = imgs[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for img in imgs:
        vw.write(np.ascontiguousarray(img[..., ::-1]))
    vw.release()


def read_cv2(path) -> list[np.ndarray]:
    import cv2

    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        out.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    cap.release()
    return out


def read_ours(path) -> list[np.ndarray]:
    with open_video(path) as v:
        return [f.rgb for f in v]


def psnr(a, b) -> float:
    mse = np.mean([(x.astype(np.float64) - y) ** 2 for x, y in zip(a, b)])
    return float(10 * np.log10(255 ** 2 / mse))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.size, args.repeat = 8, 128, 1
    imgs = frames(args.frames, args.size)
    with tempfile.TemporaryDirectory() as tmp:
        ours, theirs = Path(tmp) / "h264.mp4", Path(tmp) / "mp4v.mp4"
        t_ours = best(args.repeat, lambda: write_video(ours, imgs, 24))
        t_cv = best(args.repeat, lambda: write_cv2(theirs, imgs))
        print(f"write {args.frames} frames {args.size}x{args.size}:")
        print(f"  H.264 (PyAV, crf {DEFAULT_CRF}, {DEFAULT_PRESET}) {t_ours:.3f} s "
              f"({args.frames / t_ours:.0f} frames/s), {os.path.getsize(ours) / 1e3:.0f} kB, "
              f"PSNR {psnr(read_ours(ours), imgs):.1f} dB")
        print(f"  mp4v (OpenCV, baseline)        {t_cv:.3f} s ({args.frames / t_cv:.0f} frames/s), "
              f"{os.path.getsize(theirs) / 1e3:.0f} kB, PSNR {psnr(read_cv2(theirs), imgs):.1f} dB")
        print(f"  ratio time ours/OpenCV {t_ours / t_cv:.2f}, size {os.path.getsize(ours) / os.path.getsize(theirs):.2f}")
        here = Path(__file__).resolve()
        candidates = [root / "shared" / "data" / "videos" / "talking_man_grey.mp4"
                      for root in (here.parents[2], here.parents[3])]  # a clone, a worktree
        clip = next((c for c in candidates if c.is_file()), ours)
        n = len(read_cv2(clip))
        r_ours = best(args.repeat, lambda: read_ours(clip))
        r_cv = best(args.repeat, lambda: read_cv2(clip))
        print(f"read {clip.name} ({n} frames), open included:")
        print(f"  avatarkit.video  {r_ours:.3f} s ({n / r_ours:.0f} frames/s)")
        print(f"  cv2.VideoCapture {r_cv:.3f} s ({n / r_cv:.0f} frames/s)")
        print(f"  ratio ours/OpenCV {r_ours / r_cv:.2f}")


if __name__ == "__main__":
    main()
