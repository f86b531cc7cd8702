"""Regenerate docs/images/video_build_views.png: two known subjects turning their heads in the
benchmark's synthetic video (`benchmarks/build_video.py`: the eased clip, 96 frames at 192x192,
a slow turn to about 80 degrees each side), the single-frame build and the video build of that
video, each rendered at rest from the front, three-quarter and profile. Rows: the known subject,
the single-frame build, the video build; columns: the sample avatar (splatted) at 0 / 45 / 90
degrees, then the mesh subject (a textured mesh head, rasterised: not made of our Gaussians).

Run: `.venv/bin/python scripts/video_build_views.py [-o docs/images/video_build_views.png]`
(four builds, each in its own process as the benchmark makes them: about 5 minutes on 2 cores).
Prints each build's PSNR at the benchmark's views (192 px), the benchmark's figures to the digit.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COUNTS = (8000, 4000)          # the benchmark's bald + hair Gaussians
AZIMUTHS = (0.0, 45.0, 90.0)   # the picture's columns per subject


def _truth(subject: str):
    if subject == "mesh":
        from avatarkit.synthetic.mesh_head import MeshHead

        return MeshHead.make()
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    return make_sample_avatar(n_hair=3000, n_bald=12000, style="short", cage_vertices=200)


def _build(kind: str, subject: str, video: str, png: str | None, out: str) -> tuple[dict, int]:
    """One build in a fresh process (as the benchmark's `_score`), saved to out: (PSNR by
    azimuth at the benchmark's 192 px views, the reference frame)."""
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    from avatarkit.recon.pipeline import BuildOptions, build_avatar
    from avatarkit.track.video_build import build_video_avatar

    opts = BuildOptions(n_bald=COUNTS[0], n_hair=COUNTS[1], preview=False, hair_mode="rigid")
    avatar = build_video_avatar(video, opts) if kind == "video" else build_avatar(png, opts)
    avatar.save(out, preview=False)
    truth = _truth(subject)
    if subject == "mesh":
        from avatarkit.synthetic.mesh_head import view_psnr

        ps = view_psnr(avatar, truth, 192)
    else:
        from avatarkit.synthetic.turning_video import novel_view_psnr

        ps = novel_view_psnr(avatar, truth, 192)
    return ps, int(avatar.provenance.get("source_video", {}).get("frame", -1))


def _own_process(*args):
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_build, *args).result()


def _views(subject: str, truth, avatar, size: int) -> np.ndarray:
    """(size, 3 size, 3) uint8: the truth (avatar None) or a build at rest, on white, at AZIMUTHS."""
    from avatarkit.export.images import to_uint8
    from avatarkit.render import render
    from avatarkit.render.views import frame_camera, scene_bounds

    bounds = truth.bounds() if subject == "mesh" else scene_bounds(truth.bald)
    tiles = []
    for az in AZIMUTHS:
        cam = frame_camera(bounds, az, 0.0, width=size, height=size)
        if avatar is None and subject == "mesh":
            rgb = truth.render(cam, background=(1.0, 1.0, 1.0))[0]
        else:
            rgb = render((truth if avatar is None else avatar).rest_gaussians(), cam, (1.0, 1.0, 1.0)).rgb
        tiles.append(to_uint8(rgb))
    return np.concatenate(tiles, axis=1)


def _crop(block: np.ndarray, size: int, margin: int = 6) -> np.ndarray:
    """block (rows x size, 3 size, 3) uint8 -> the same tiles cut to the box every tile's head fits
    in (the cameras frame the head from 0.6 m: most of each view is wall)."""
    tiles = block.reshape(block.shape[0] // size, size, 3, size, 3).transpose(0, 2, 1, 3, 4)  # (R, 3, size, size, 3)
    drawn = (tiles < 250).any(axis=-1).any(axis=(0, 1))                                      # (size, size)
    ys, xs = np.nonzero(drawn)
    y0, y1 = max(ys.min() - margin, 0), min(ys.max() + margin + 1, size)
    x0, x1 = max(xs.min() - margin, 0), min(xs.max() + margin + 1, size)
    cut = tiles[:, :, y0:y1, x0:x1]
    return np.concatenate([np.concatenate(list(row), axis=1) for row in cut], axis=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", default=os.path.join(ROOT, "docs", "images", "video_build_views.png"))
    ap.add_argument("--size", type=int, default=320, help="pixels per view before the views are cut to the head")
    a = ap.parse_args()
    from avatarkit.avatar import Avatar
    from avatarkit.export.images import write_png
    from avatarkit.synthetic.turning_video import eased_turning_clip, write_turning_video
    from avatarkit.video import read_frame

    clip = eased_turning_clip(96)
    columns = []
    with tempfile.TemporaryDirectory() as tmp:
        for subject in ("avatar", "mesh"):
            truth = _truth(subject)
            video = os.path.join(tmp, f"turn_{subject}.mp4")
            if subject == "mesh":
                from avatarkit.synthetic.mesh_head import turning_video

                turning_video(truth, video, size=192, clip=clip)
            else:
                write_turning_video(truth, video, size=192, clip=clip)
            pv, ref = _own_process("video", subject, video, None, os.path.join(tmp, f"{subject}_video"))
            png = os.path.join(tmp, f"{subject}_ref.png")
            write_png(png, read_frame(video, ref).rgb)
            ps, _ = _own_process("single", subject, video, png, os.path.join(tmp, f"{subject}_single"))
            rows = [_views(subject, truth, None, a.size)]
            for kind in ("single", "video"):
                rows.append(_views(subject, truth, Avatar.load(os.path.join(tmp, f"{subject}_{kind}")), a.size))
            columns.append(_crop(np.concatenate(rows, axis=0), a.size))
            order = sorted(pv, key=lambda az: (az != 0, abs(az), -az))
            for name, p in (("single frame", ps), ("video", pv)):
                print(f"{subject:>6s} {name:>12s}: " + " / ".join(f"{p[az]:.2f}" for az in order)
                      + f" dB ({' / '.join(f'{az:+.0f}' for az in order)})", file=sys.stderr)
            prof = np.mean([pv[az] - ps[az] for az in pv if abs(az) == 90])
            print(f"{subject:>6s} profile gain (mean of +-90): {prof:+.2f} dB", file=sys.stderr)
    height = max(c.shape[0] for c in columns)
    gap = np.full((height, 16, 3), 255, np.uint8)
    padded = [np.pad(c, ((0, height - c.shape[0]), (0, 0), (0, 0)), constant_values=255) for c in columns]
    write_png(a.output, np.concatenate([padded[0], gap, *padded[1:]], axis=1))
    print(f"wrote {a.output}", file=sys.stderr)


if __name__ == "__main__":
    main()
