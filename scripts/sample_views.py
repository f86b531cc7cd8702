"""Regenerate docs/sample_views.png (the README's first picture): samples/portrait.jpg beside the
avatar avatarkit builds from it, rendered by the CPU renderer from the front, three-quarter and
profile.

Run: `.venv/bin/python scripts/sample_views.py [--avatar DIR] [-o docs/sample_views.png]`
(without --avatar the sample is built first with the default options, as `make demo` does:
about half a minute on 2 cores; `make demo` leaves one in demo_out/portrait_avatar).
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
VIEWS = (("avatar: front", 0.0), ("three-quarter", 45.0), ("profile", 90.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--avatar", help="an avatar folder built from samples/portrait.jpg (default: build one)")
    ap.add_argument("-o", "--output", default=os.path.join(ROOT, "docs", "sample_views.png"))
    ap.add_argument("--size", type=int, default=256, help="pixels per view")
    a = ap.parse_args()
    import cv2

    from avatarkit.avatar import load_avatar
    from avatarkit.export.images import to_uint8, write_png
    from avatarkit.recon.image_io import read_image
    from avatarkit.recon.pipeline import BuildOptions, build_avatar
    from avatarkit.render import render
    from avatarkit.render.views import frame_camera, scene_bounds

    portrait = os.path.join(ROOT, "samples", "portrait.jpg")
    if a.avatar:
        avatar = load_avatar(a.avatar)
    else:
        avatar = build_avatar(portrait, BuildOptions(preview=False))
    gs = avatar.rest_gaussians()
    bounds = scene_bounds(avatar.bald)
    s = a.size
    photo = read_image(portrait)                                   # (H, W, 3) uint8
    h, w = photo.shape[:2]
    k = s / max(h, w)
    photo = cv2.resize(photo, (round(w * k), round(h * k)), interpolation=cv2.INTER_AREA)
    tile = np.full((s, s, 3), 255, np.uint8)
    tile[:photo.shape[0], :photo.shape[1]] = photo
    tiles = [("input portrait", tile)]
    for label, az in VIEWS:
        cam = frame_camera(bounds, az, 0.0, width=s, height=s)
        tiles.append((label, to_uint8(render(gs, cam, (1.0, 1.0, 1.0)).rgb)))
    strip = []
    for label, img in tiles:
        caption = np.full((20, s, 3), 255, np.uint8)
        cv2.putText(caption, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        strip.append(np.concatenate([img, caption], axis=0))
    write_png(a.output, np.concatenate(strip, axis=1))
    print(f"wrote {a.output}", file=sys.stderr)


if __name__ == "__main__":
    main()
