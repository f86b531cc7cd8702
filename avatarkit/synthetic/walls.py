"""Walls behind the synthetic turning videos: what a phone video's background looks like besides
a white studio wall (session 21, docs/video-build.md "Non-white walls").

`wall_image(kind, size)` is a deterministic (size, size, 3) image: "white", "dark" (a dark grey
wall), "colour" (a saturated teal wall) or "clutter" (a beige wall with a door frame's stripes, a
poster and a dark post touching the head's sides, a shelf of books, green stripes). `over_wall`
puts a render made over black (premultiplied colour) on it.
"""
from __future__ import annotations

import numpy as np

WALLS = ("white", "dark", "colour", "clutter")


def wall_image(kind: str, size: int) -> np.ndarray:
    """(size, size, 3) float32 in [0, 1]: the wall `kind` (one of `WALLS`)."""
    if kind not in WALLS:
        raise ValueError(f"unknown wall {kind!r} (one of {', '.join(WALLS)})")
    if kind == "white":
        return np.ones((size, size, 3), np.float32)
    if kind == "dark":
        return np.full((size, size, 3), 0.22, np.float32)
    if kind == "colour":
        return np.broadcast_to(np.array([0.05, 0.55, 0.50], np.float32), (size, size, 3)).copy()
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:size, 0:size] / size          # share of the side
    img = np.empty((size, size, 3), np.float32)
    img[:] = (0.80, 0.74, 0.62)                         # beige plaster...
    img += rng.normal(0, 0.03, (size, size, 1)).astype(np.float32)   # ...with its texture
    img[(xx < 0.22) & ((xx * 40).astype(int) % 3 == 0)] = (0.45, 0.28, 0.15)   # a door frame's stripes
    img[(xx > 0.66) & (xx < 0.95) & (yy > 0.12) & (yy < 0.55)] = (0.80, 0.15, 0.12)   # a poster by the head
    for cy, cx, r in ((0.25, 0.78, 0.06), (0.42, 0.86, 0.05)):
        img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = (0.10, 0.20, 0.70)
    # a dark brown post touching the head's other side: the colour of dark hair
    img[(xx > 0.27) & (xx < 0.33) & (yy > 0.05) & (yy < 0.75)] = (0.22, 0.14, 0.08)
    img[(yy > 0.62) & (yy < 0.66)] = (0.30, 0.20, 0.12)                          # a shelf
    books = [(0.1, 0.5, 0.2), (0.85, 0.75, 0.1), (0.15, 0.15, 0.4), (0.7, 0.3, 0.5), (0.9, 0.9, 0.85)]
    for i, x0 in enumerate(np.arange(0.0, 1.0, 0.07)):
        img[(yy > 0.52) & (yy < 0.62) & (xx > x0) & (xx < x0 + 0.055)] = books[i % len(books)]
    img[(yy < 0.10) & (((xx + yy) * 25).astype(int) % 2 == 0)] = (0.2, 0.6, 0.25)
    return np.clip(img, 0.0, 1.0)


def over_wall(rgb: np.ndarray, alpha: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """(H, W, 3) float: a render made over black (rgb (H, W, 3), premultiplied by its coverage
    alpha (H, W)) composited over `wall` (H, W, 3)."""
    a = np.asarray(alpha, np.float32)[..., None]
    return np.asarray(rgb, np.float32) + np.asarray(wall, np.float32) * (1.0 - a)


__all__ = ["WALLS", "over_wall", "wall_image"]
