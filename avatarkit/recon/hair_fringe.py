"""The wall seen between the strands: hair Gaussians whose colour is more wall than hair, cleared.

At a fringe of thin strands (the ends of a bob, strand tips standing off the head) a keyframe's
pixel is part strand, part the wall behind; the segmentation calls it hair, and the colour stage
gives the hair Gaussian there that mix, at full opacity. The person's hair there covers less
than half the pixel, so the subject shows the backdrop through it: over the wall the video was
shot on the mix passes, over any other backdrop (the web player's black) it is a pale blot on
the hair, and over the recording's own wall it hides the dark strands it lies on. Session 28
(docs/video-build.md, "The wall between the strands") put most of the bob's profile error over
black in such Gaussians (white on dark hair), and clearing them raised its views over white too.

A hair Gaussian's colour c is read as a mix c = a h + (1 - a) w of the hair's colour h (the
median colour of the avatar's hair: robust to the few mixed ones) and the wall's w (the video's
wall plate, `track.background_plate`, at the Gaussian's pixel in the reference view, or the
nearest known plate pixel: the wall beside where it lies). Where c lies within `OFF_LINE` of
that segment and a < `WALL_SHARE` the Gaussian is more wall than hair and is cleared; a colour
off the segment (another colour of hair, a highlight not toward the wall) or darker than h is
kept. Only a video build with a wall plate (a build from one photo knows no wall behind its hair).
"""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet

#: a hair Gaussian whose colour reads as less than this share of the hair's colour (the rest the
#: wall's) is cleared; None: off. One half: what the renderer's silhouette (alpha 0.5) draws
WALL_SHARE = 0.5
#: the largest distance (RGB in [0, 1]) of a colour from the segment hair -> wall for it to be
#: read as their mix: a highlight or a second hair colour lies off it
OFF_LINE = 0.1
#: the hair's colour and the wall's must lie at least this far apart (RGB in [0, 1]) for a mix to
#: be read at all: a wall like the hair leaves every share unreadable
MIN_CONTRAST = 0.25


def wall_shares(colours: np.ndarray, hair: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """(N,) the hair's share a in [0, 1] of colours (N, 3) read as a h + (1 - a) w, with hair
    h (3,) and walls w (N, 3), all RGB in [0, 1]; 1 where the colour is not such a mix (farther
    than `OFF_LINE` from the segment h -> w, or h and w closer than `MIN_CONTRAST`)."""
    c = np.asarray(colours, np.float64)
    h = np.asarray(hair, np.float64)[None]
    w = np.asarray(walls, np.float64)
    seg = w - h                                                              # (N, 3)
    l2 = (seg ** 2).sum(axis=1)
    s = ((c - h) * seg).sum(axis=1) / np.maximum(l2, 1e-12)                  # 0 at h, 1 at w
    s = np.clip(s, 0.0, 1.0)
    off = np.linalg.norm(c - h - s[:, None] * seg, axis=1)
    readable = (off <= OFF_LINE) & (l2 >= MIN_CONTRAST ** 2)
    return np.where(readable, 1.0 - s, 1.0)


def plate_walls(points: np.ndarray, camera, plate, shape: tuple[int, int]) -> np.ndarray | None:
    """(N, 3) RGB in [0, 1]: the wall behind points (N, 3) in the rest frame as camera (the
    reference view, image (H, W) = shape) sees it: the plate's colour at the point's pixel where
    the plate knows it, else at the nearest known plate pixel. None without a known plate pixel."""
    from scipy import ndimage

    colour, known = plate.at(shape)
    if not known.any():
        return None
    h, w = shape
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    px, _ = camera.project(np.asarray(points, np.float64))
    px = np.where(np.isfinite(px), px, 0.0)
    xi = np.clip(px[:, 0].astype(np.int64), 0, w - 1)
    yi = np.clip(px[:, 1].astype(np.int64), 0, h - 1)
    ny, nx = iy[yi, xi], ix[yi, xi]
    return np.asarray(colour, np.float64)[ny, nx] / 255.0


def clear_wall_hair(hair: GaussianSet, camera, plate, shape: tuple[int, int]) -> tuple[GaussianSet, dict]:
    """hair without the Gaussians more wall than hair (module docstring; `WALL_SHARE`), and
    figures for the build report. camera: the reference view's; shape: its image's (H, W)."""
    info = {"cleared": 0}
    if WALL_SHARE is None or plate is None or len(hair) == 0:
        return hair, info
    walls = plate_walls(hair.means, camera, plate, shape)
    if walls is None:
        return hair, info
    colours = hair.colors
    share = wall_shares(colours, np.median(colours, axis=0), walls)
    clear = share < WALL_SHARE
    info["cleared"] = int(clear.sum())
    if not clear.any() or clear.all():
        return hair, info
    return hair.subset(~clear), info


__all__ = ["MIN_CONTRAST", "OFF_LINE", "WALL_SHARE", "clear_wall_hair", "plate_walls", "wall_shares"]
