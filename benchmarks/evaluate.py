#!/usr/bin/env python3
"""`avatarkit evaluate` end to end on a real clip: seconds per stage, total wall and CPU time.

Run: `.venv/bin/python benchmarks/evaluate.py [--video PATH] [--keep DIR] [--quick]`
(default video: ../shared/data/videos/talking_man_glasses.mp4 beside the checkout, 250 frames
at 480x480; the report goes to a temporary folder unless --keep).

Prints the CPU model, the load average, a table of the pipeline's stages (wall seconds and
share: choosing the build frame = a tracking with the template head, the portrait build, the
second tracking with the avatar (reusing the first one's face meshes), and per frame bake,
render, metrics, face mesh on the render, side-by-side writing), the total wall and CPU time
against the target (issue 17: <= 120 s on 2 cores), and two baselines run in the same
process: decoding the video alone, and the metrics of one frame on the whole frame (the old
way) against the mask's bounding box (what evaluate does).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
VIDEO = HERE.parent.parent / "shared" / "data" / "videos" / "talking_man_glasses.mp4"
TARGET_S = 120.0
STAGES = ("choose_frame", "build", "track", "bake", "render", "metrics", "landmarks", "write")


from _timing import cpu_model  # noqa: E402  (run as benchmarks/NAME.py: its folder is on sys.path)


def metrics_baseline(mask_fraction: float, size: int, repeats: int = 5) -> tuple[float, float]:
    """Seconds per frame of the metrics on the whole frame and on the mask's box, for a
    size x size frame whose mask (a disc) covers `mask_fraction` of it."""
    from avatarkit.track import metrics

    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:size, 0:size]
    r = size * np.sqrt(max(mask_fraction, 1e-3) / np.pi)
    mask = (yy - size / 2) ** 2 + (xx - size / 2) ** 2 < r * r
    a = metrics.composite(rng.integers(0, 256, (size, size, 3), dtype=np.uint8), mask, (1, 1, 1))
    b = metrics.composite(np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1), mask, (1, 1, 1))

    def whole():
        _, smap = metrics.ssim_map(a, b)
        return metrics.masked_psnr(a, b, mask), metrics.masked_psnr(a, b, np.ones_like(mask)), smap[mask].mean()

    def box():
        return metrics.region_metrics(a, b, mask)

    out = []
    for fn in (whole, box):
        fn()
        t = time.perf_counter()
        for _ in range(repeats):
            fn()
        out.append((time.perf_counter() - t) / repeats)
    return out[0], out[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default=str(VIDEO))
    ap.add_argument("--keep", help="write the report here instead of a temporary folder")
    ap.add_argument("--quick", action="store_true",
                    help="only the metrics baseline on one synthetic frame: checks that the script runs")
    args = ap.parse_args()
    if args.quick:
        whole_s, box_s = metrics_baseline(0.3, 160, repeats=1)
        print(f"quick: metrics of one 160x160 frame, whole frame {1000 * whole_s:.1f} ms, mask box "
              f"{1000 * box_s:.1f} ms ({whole_s / box_s:.1f}x)")
        return 0
    if not os.path.exists(args.video):
        print(f"no video at {args.video} (the shared clips live in ../shared beside the checkout)")
        return 0
    from avatarkit.track.evaluate import evaluate
    from avatarkit.video import open_video

    print(f"evaluate benchmark: {cpu_model()}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.2f} at start; video {args.video}")
    t = time.perf_counter()
    with open_video(args.video) as v:
        info = v.info
        n = sum(1 for _ in v.frames())
    decode_s = time.perf_counter() - t
    print(f"video: {n} frames {info.width}x{info.height}; decoding alone {decode_s:.2f} s")

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "report"
        c0, w0 = time.process_time(), time.perf_counter()
        report = evaluate(args.video, out)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    timings = report.timings
    accounted = sum(timings.get(k, 0.0) for k in STAGES)
    print(f"\n{'stage':<14}{'wall s':>9}{'share':>8}")
    for k in STAGES:
        if k in timings:
            print(f"{k:<14}{timings[k]:>9.1f}{timings[k] / wall:>8.1%}")
    print(f"{'other':<14}{wall - accounted:>9.1f}{(wall - accounted) / wall:>8.1%}")
    print(f"{'total':<14}{wall:>9.1f}{1:>8.0%}   CPU {cpu:.1f} s (all threads; "
          f"/{os.cpu_count()} = {cpu / (os.cpu_count() or 1):.1f} s); load average "
          f"{os.getloadavg()[0]:.2f} at the end")
    print(f"target <= {TARGET_S:.0f} s end to end on 2 cores: {'met' if wall <= TARGET_S else 'NOT met'} "
          f"(wall {wall:.1f} s = {wall / TARGET_S:.2f}x the target; {wall / max(decode_s, 1e-9):.0f}x "
          "decoding alone)")
    s = report.summary
    print(f"quality: PSNR {s['psnr']:.2f} dB / SSIM {s['ssim']:.3f} (person region), whole frame "
          f"{s['psnr_full']:.2f} / {s['ssim_full']:.3f}; landmark error {s['landmark_error_px']:.2f} px")
    whole_s, box_s = metrics_baseline(s["mask_fraction"] or 0.2, info.width)
    print(f"metrics per frame at mask share {s['mask_fraction']:.2f}: whole frame {1000 * whole_s:.0f} ms, "
          f"mask box {1000 * box_s:.0f} ms ({whole_s / box_s:.1f}x faster, same numbers)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
