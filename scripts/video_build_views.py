"""Regenerate docs/images/video_build_views.png: the sample avatar turning its head in a synthetic
video, the single-frame build and the video build of that video, each rendered at rest from the
front, three-quarter and profile (rows: known avatar, single frame, video).

Run: `.venv/bin/python scripts/video_build_views.py [-o docs/images/video_build_views.png]`
(two builds: about a minute on 2 cores).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", default=os.path.join(ROOT, "docs", "images", "video_build_views.png"))
    ap.add_argument("--size", type=int, default=160, help="pixels per view")
    a = ap.parse_args()
    from avatarkit.export.images import to_uint8, write_png
    from avatarkit.recon.pipeline import BuildOptions, build_avatar
    from avatarkit.render import render
    from avatarkit.render.views import frame_camera, scene_bounds
    from avatarkit.synthetic.sample_avatar import make_sample_avatar
    from avatarkit.synthetic.turning_video import novel_view_psnr, write_turning_video
    from avatarkit.track.video_build import build_video_avatar
    from avatarkit.video import read_frame

    truth = make_sample_avatar(n_hair=3000, n_bald=12000, style="short", cage_vertices=200)

    def opts():
        return BuildOptions(n_bald=8000, n_hair=4000, preview=False, hair_mode="rigid")

    with tempfile.TemporaryDirectory() as tmp:
        video = os.path.join(tmp, "turn.mp4")
        write_turning_video(truth, video, size=192, frames=32)
        built = build_video_avatar(video, opts())
        png = os.path.join(tmp, "ref.png")
        write_png(png, read_frame(video, built.provenance["source_video"]["frame"]).rgb)
        single = build_avatar(png, opts())
    bounds = scene_bounds(truth.bald)
    rows = []
    for avatar in (truth, single, built):
        gs = avatar.rest_gaussians()
        rows.append(np.concatenate([to_uint8(render(gs, frame_camera(bounds, az, 0.0, width=a.size, height=a.size),
                                                    (1.0, 1.0, 1.0)).rgb) for az in (0.0, 45.0, 90.0)], axis=1))
    write_png(a.output, np.concatenate(rows, axis=0))
    for name, av in (("single frame", single), ("video", built)):
        p = novel_view_psnr(av, truth, a.size, (0.0, 45.0, 90.0))
        print(f"{name:>12s}: " + ", ".join(f"{az:.0f} deg {v:.2f} dB" for az, v in p.items()), file=sys.stderr)
    print(f"wrote {a.output}", file=sys.stderr)


if __name__ == "__main__":
    main()
