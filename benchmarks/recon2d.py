"""Time and quality of the 2D reconstruction stages (read, analyse, segment, bald) on the sample.

Prints, per image size: seconds per stage (median of `--repeat` runs) next to a simple
baseline run in the same process (a bare Haar detection; one plain rect-initialised GrabCut;
OpenCV's Telea inpainting of the hair), the share of filled scalp pixels whose colour is closer
to the skin model than to the hair model (ours vs Telea), the exact-vs-two-level harmonic fill
time and error, and segmentation IoU and the person outline's mean outward / inward offset (px)
on synthetic portraits and the video benchmarks' mesh subject with known labels, with the
outline step and without it (GrabCut's own outline, the baseline).

    .venv/bin/python benchmarks/recon2d.py [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
from avatarkit.recon.bald import make_bald_image  # noqa: E402
from avatarkit.recon.fill import harmonic_fill, harmonic_fill_fast  # noqa: E402
from avatarkit.recon.image_io import read_image  # noqa: E402
from avatarkit.recon.portrait import analysis_from_box, analyze_portrait  # noqa: E402
from avatarkit.recon.segment import HAIR, SKIN, rgb_to_lab, segment_portrait  # noqa: E402
from avatarkit.recon.synthetic import synthetic_portrait  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "portrait.jpg"


def timed(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def skin_share(image, mask, seg):
    lab = rgb_to_lab(image[mask])
    return float((seg.skin_model.log_likelihood(lab) > seg.hair_model.log_likelihood(lab)).mean())


def bench_size(base: np.ndarray, size: int, repeat: int) -> None:
    image = base if size == base.shape[0] else cv2.resize(base, (size, size), interpolation=cv2.INTER_CUBIC)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.jpg"
        cv2.imwrite(str(path), image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])
        t_read, _ = timed(lambda: read_image(path), repeat)
    t_an, a = timed(lambda: analyze_portrait(image, detector="cascade"), repeat)
    t_seg, seg = timed(lambda: segment_portrait(image, a), repeat)
    t_bald, bald = timed(lambda: make_bald_image(image, seg, a), repeat)

    grey = cv2.equalizeHist(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
    haar = cv2.CascadeClassifier(os.path.join(cv2.data.haarcascades, "haarcascade_frontalface_alt2.xml"))
    t_haar, _ = timed(lambda: haar.detectMultiScale(grey, 1.1, 5, minSize=(24, 24)), repeat)

    def plain_grabcut():
        m = np.zeros(image.shape[:2], np.uint8)
        x, y, w, h = a.face_box
        rect = (max(0, x - w), max(0, y - h), min(image.shape[1], x + 2 * w) - max(0, x - w),
                image.shape[0] - max(0, y - h))
        cv2.grabCut(image, m, rect, np.zeros((1, 65)), np.zeros((1, 65)), 5, cv2.GC_INIT_WITH_RECT)
        return m
    # Plain GrabCut grows ~linearly with pixels (~20 s at 1024 px here): skip it beyond that.
    t_gc = timed(plain_grabcut, 1 if size > 512 else repeat)[0] if size <= 1024 else None
    hair8 = seg.hair.astype(np.uint8)
    t_telea, telea = timed(lambda: cv2.inpaint(image, hair8, 3, cv2.INPAINT_TELEA), repeat)

    print(f"\n== sample portrait at {size}x{size}  (face {a.face_box[2]} px, IOD {a.eye_distance:.0f} px)")
    print(f"read_image          {t_read * 1e3:8.1f} ms")
    print(f"analyze_portrait    {t_an * 1e3:8.1f} ms   (bare Haar alt2 detection {t_haar * 1e3:.1f} ms: x{t_an / t_haar:.1f})")
    gc = f"one plain rect GrabCut, 5 it {t_gc * 1e3:.1f} ms: x{t_seg / t_gc:.2f}" if t_gc else "plain GrabCut skipped"
    print(f"segment_portrait    {t_seg * 1e3:8.1f} ms   ({gc})")
    print(f"make_bald_image     {t_bald * 1e3:8.1f} ms   (cv2.inpaint Telea of the hair {t_telea * 1e3:.1f} ms: x{t_bald / t_telea:.2f})")
    print(f"total               {(t_read + t_an + t_seg + t_bald):8.2f} s")
    print(f"labels: " + ", ".join(f"{k} {v:.1%}" for k, v in seg.fractions().items()))
    print(f"filled scalp closer to skin than hair: ours {skin_share(bald.image, bald.scalp_mask, seg):.1%}, "
          f"Telea {skin_share(telea, bald.scalp_mask, seg):.1%}")


def bench_fill(repeat: int) -> None:
    H = W = 1024
    y, x = np.mgrid[0:H, 0:W].astype(float)
    values = np.stack([128 + 60 * np.sin(x / 80) * np.cos(y / 110), 0.2 * x, 0.25 * y + 15 * np.sin(x / 20)], axis=2)
    region = ((x - 512) / 380) ** 2 + ((y - 430) / 280) ** 2 <= 1
    known = ~region
    t_direct, direct = timed(lambda: harmonic_fill(values, region, known), 1)
    t_fast, fast = timed(lambda: harmonic_fill_fast(values, region, known), repeat)
    err = np.abs(direct - fast)[region]
    print(f"\n== harmonic fill, {int(region.sum())} unknown pixels (1024x1024 ellipse)")
    print(f"direct sparse LU  {t_direct:7.2f} s;  two-level {t_fast:7.3f} s: x{t_direct / t_fast:.1f} faster; "
          f"error mean {err.mean():.3f}, max {err.max():.2f} (of 255)")


def jpeg(image: np.ndarray, quality: int = 90) -> np.ndarray:
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(image[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1].copy()


def outline(person: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(wall pixels taken per true outline pixel, person pixels lost per outline pixel): mean
    outward / inward offsets of the person outline in px."""
    from scipy import ndimage

    perimeter = max(1, (truth & ~ndimage.binary_erosion(truth)).sum())
    return (person & ~truth).sum() / perimeter, (truth & ~person).sum() / perimeter


def mesh_subject_front(size: int = 192):
    """The video benchmarks' mesh subject at rest on white, as a JPEG: (image, person, hair)."""
    from avatarkit.synthetic.head_video import head_video_camera
    from avatarkit.synthetic.mesh_head import MeshHead

    subject = MeshHead.make()
    camera = head_video_camera(size, distance=0.5)
    rgb, alpha = subject.render(camera)
    hair = subject.hair_coverage(camera)
    return jpeg(np.round(rgb * 255).astype(np.uint8)), alpha > 0.5, hair > 0.5


def bench_synthetic() -> None:
    """Labels and the person outline on subjects with known labels, with the outline step
    (re-noised flat pixels + the boundary peel) and without it (GrabCut's own outline, the
    baseline: `segment_portrait(boundary=False)`), in the same process."""
    print("\n== segmentation on synthetic portraits (known labels): with the outline step | GrabCut's own outline")
    print(f"{'':30s} {'hair IoU':>8s} {'skin IoU':>8s} {'out px':>6s} {'in px':>6s} | "
          f"{'hair IoU':>8s} {'skin IoU':>8s} {'out px':>6s} {'in px':>6s}")
    cases = {"brown hair": dict(blur=1.0, noise=4), "blond hair": dict(blur=1.5, noise=6, hair_rgb=(196, 164, 108)),
             "dark background": dict(blur=1.0, noise=4, background_rgb=(62, 50, 44)),
             "soft edges (blur 2)": dict(blur=2.0, noise=4),
             "JPEG, white wall": dict(blur=1.0, noise=0, background_rgb=(255, 255, 255)),
             "JPEG, light grey wall": dict(blur=1.5, noise=2, background_rgb=(245, 245, 245)),
             "JPEG, black hair, black wall": dict(blur=1.0, noise=0, background_rgb=(20, 20, 20), hair_rgb=(35, 28, 25)),
             # session 18: flat dark walls (a JPEG, a video codec or a render leaves them flat)
             "JPEG, blonde, near-black wall": dict(blur=1.0, noise=0, background_rgb=(25, 23, 20),
                                                   hair_rgb=(196, 164, 108)),
             "JPEG, brown, dark grey wall": dict(blur=1.0, noise=0, background_rgb=(55, 55, 55)),
             "JPEG, brown, near-black wall": dict(blur=1.0, noise=0, background_rgb=(25, 23, 20)),
             "dark hair, near-black wall": dict(blur=1.0, noise=4, background_rgb=(25, 23, 20), hair_rgb=(35, 28, 25))}
    for name, kw in cases.items():
        sp = synthetic_portrait(**kw)
        a = analysis_from_box(sp.image.shape[1::-1], sp.face_box)
        image = jpeg(sp.image) if name.startswith("JPEG") else sp.image
        row = []
        for boundary in (True, False):
            seg = segment_portrait(image, a, boundary=boundary)
            ious = [((seg.labels == c) & (sp.labels == c)).sum() / max(1, ((seg.labels == c) | (sp.labels == c)).sum())
                    for c in (HAIR, SKIN)]
            out, lost = outline(seg.person, sp.labels != 0)
            row.append(f"{ious[0]:8.3f} {ious[1]:8.3f} {out:6.2f} {lost:6.2f}")
        print(f"{name:30s} {row[0]} | {row[1]}")
    image, person, hair = mesh_subject_front()
    a = analyze_portrait(image, detector="cascade")  # the figures in docs/building.md
    row = []
    for boundary in (True, False):
        seg = segment_portrait(image, a, boundary=boundary)
        out, lost = outline(seg.person, person)
        row.append(f"{(seg.hair & hair).sum() / max(1, (seg.hair | hair).sum()):8.3f} {'':8s} {out:6.2f} {lost:6.2f}")
    print(f"{'mesh subject, front, JPEG':30s} {row[0]} | {row[1]}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true",
                    help="tiny sizes, one repeat: only checks that the script runs")
    args = ap.parse_args(argv)
    if args.quick:
        args.repeat = 1
    print(f"avatarkit 2D recon stages; cv2 threads {cv2.getNumThreads()}, cpus {os.cpu_count()} (timings are noisy on a shared box)")
    base = read_image(SAMPLE)
    analyze_portrait(base, detector="cascade")  # load the cascades once, outside the timings
    for size in (512,) if args.quick else (512, 1024, 2048):
        bench_size(base, size, args.repeat)
    bench_fill(args.repeat)
    bench_synthetic()
    return 0


if __name__ == "__main__":
    sys.exit(main())
