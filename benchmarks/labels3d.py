#!/usr/bin/env python3
"""3D hair segmentation speed and quality.

1. `accumulate_weights` on the standard bench scene (benchmarks/make_scene.py), 512x512,
   N = 100k (and --sizes): a 4-label blob image and a worst case (every pixel a random label),
   median of --repeats after a warm-up, beside `render` of the same scene (ratio) and, at
   --reference-n Gaussians, the numpy float64 reference (ratio and largest difference).
2. `split_hair` on the synthetic head of the tests (skin sphere + red hair cap) scaled up:
   K views at 512x512 with exact label images, and with hair spilling 8 px over the skin in
   every label image; seconds per stage and label accuracy.

Usage: benchmarks/labels3d.py [--sizes 100000] [--repeats 3] [--reference-n 20000] [--views 8]
Timings on a shared 2-core machine are noisy; compare the ratios measured side by side.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

REPO = Path(__file__).resolve().parents[1]


def timed(fn, repeats):
    fn()  # warm-up (kernel compilation, caches)
    wall = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        wall.append(time.perf_counter() - t)
    return statistics.median(wall), out


def blob_labels(h, w, seed=0):
    import numpy as np
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    noise = ndimage.gaussian_filter(rng.normal(size=(h, w)), 24)
    return np.digitize(noise, np.quantile(noise, [0.25, 0.5, 0.75])).astype(np.int32)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100_000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--reference-n", type=int, default=20_000)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--head-n", type=int, default=60_000)
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args()
    if args.quick:
        args.sizes, args.repeats, args.reference_n, args.views, args.head_n = [5000], 1, 1000, 2, 5000

    sys.path.insert(0, str(REPO / "benchmarks"))
    sys.path.insert(0, str(REPO / "tests"))
    import make_scene  # noqa: E402  (the standard scene generator, beside this script)
    import numpy as np

    from avatarkit.gaussians import GaussianSet
    from avatarkit.recon.label_lifting import (accumulate_weights, accumulate_weights_reference,
                                               default_label_cameras, render_label_images)
    from avatarkit.recon.labels3d import split_hair
    from avatarkit.render import Camera, render
    from test_recon_labels3d import dilate_hair, head_scene  # the tests' synthetic head

    print(f"labels3d benchmark: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} "
          "at start (timings on a shared machine are noisy)")

    def scene(n):
        means, scales, quats, opacity, rgb, cam = make_scene.make_scene(n, 512, 512)
        return (GaussianSet.from_colors(means, quats, scales, opacity, rgb),
                Camera.from_dict(cam))

    blobs = blob_labels(512, 512)
    noise = np.random.default_rng(1).integers(0, 4, (512, 512)).astype(np.int32)
    for n in args.sizes:
        gs, cam = scene(n)
        t_render, _ = timed(lambda: render(gs, cam), args.repeats)
        t_blob, w = timed(lambda: accumulate_weights(gs, cam, blobs, 4), args.repeats)
        t_noise, _ = timed(lambda: accumulate_weights(gs, cam, noise, 4), args.repeats)
        print(f"N={n:>7,} 512x512: accumulate_weights {t_blob:.3f} s (blob labels), "
              f"{t_noise:.3f} s (random label per pixel); render {t_render:.3f} s "
              f"-> {t_blob / t_render:.2f}x / {t_noise / t_render:.2f}x a render; "
              f"weight sum {w.sum():.0f} px")
    if args.reference_n:
        gs, cam = scene(args.reference_n)
        t_fast, fast = timed(lambda: accumulate_weights(gs, cam, blobs, 4), args.repeats)
        t = time.perf_counter()
        ref = accumulate_weights_reference(gs, cam, blobs, 4)
        t_ref = time.perf_counter() - t
        print(f"N={args.reference_n:>7,} 512x512: numpy reference {t_ref:.2f} s (once), fast "
              f"{t_fast:.3f} s -> {t_ref / t_fast:.0f}x faster; max |diff| "
              f"{np.abs(fast - ref).max():.2e} (largest weight {ref.max():.1f})")

    # split_hair on a scaled-up synthetic head
    n_skin = int(args.head_n * 0.75)
    gs, truth = head_scene(n_skin=n_skin, n_hair=args.head_n - n_skin, seed=0,
                           skin_sigma=0.012 * np.sqrt(3000 / n_skin))
    cams = default_label_cameras((0, 0, 0), 0.12, args.views, size=512)
    t = time.perf_counter()
    images = render_label_images(gs, truth, cams, 4)
    t_images = time.perf_counter() - t
    print(f"head scene: {len(gs):,} Gaussians, {args.views} views 512x512; exact label images "
          f"rendered in {t_images:.2f} s")
    for name, imgs in (("exact labels", images), ("hair spilled 8 px", dilate_hair(images, 8))):
        t = time.perf_counter()
        bald, hair, report = split_hair(gs, cams, imgs)
        total = time.perf_counter() - t
        lift_acc = (report.lift.labels == truth).mean()
        final_acc = (report.labels == truth).mean()
        s = report.summary()
        print(f"  {name:>17}: split_hair {total:.2f} s (lift {report.timings['lift']:.2f}, "
              f"reassign {report.timings['reassign']:.2f}); labels right after lifting "
              f"{100 * lift_acc:.2f}%, after reassignment {100 * final_acc:.2f}%; "
              f"{s['boundary']:,} boundary, {s['reclassified']:,} reclassified, "
              f"{s['changed']:,} changed, {s['unseen']:,} unseen")
    t = time.perf_counter()
    bald, hair, report = split_hair(gs, cams[:1], images[:1])
    total = time.perf_counter() - t
    unseen = ~report.lift.seen
    print(f"  {'front view only':>17}: split_hair {total:.2f} s; {100 * unseen.mean():.1f}% unseen, "
          f"{100 * (report.labels[unseen] == truth[unseen]).mean():.2f}% of them right after k-NN; "
          f"all labels {100 * (report.labels == truth).mean():.2f}% right")
    return 0


if __name__ == "__main__":
    sys.exit(main())
