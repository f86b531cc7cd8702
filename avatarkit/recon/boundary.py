"""Pull a person mask's outline back onto the real edge: a colour-mixing (matting-style) test
against local background and person colours.

Why: GrabCut's cut on a portrait sits a few pixels outside the person on a light, plain
background. Its pairwise term is weak where the edge is soft (anti-aliased or blurred hair, a
JPEG's ringing), and its colour models are mixtures fitted to whole regions, so the mixed
pixels of the edge, and a few background pixels beyond them, score closer to the person's
bright mixture components than to the background's. That halo then becomes hair (it is not
skin-coloured) and the real hair, left without seeds, becomes skin.

The test: every person pixel within `band` pixels of the outline is modelled as a mix
C = a F + (1 - a) B of a local person colour F (a smoothed mean of the person's interior,
the part more than `band` px inside, read at the nearest interior pixel) and a local
background colour B (a smoothed mean of the background more than 1 px outside, read at the
nearest such pixel); a = (C - B).(F - B) / |F - B|^2. Pixels with a < 0.5 are mostly
background. They are removed only where F and B differ clearly (dark hair on a dark wall keeps
GrabCut's outline: the mix says nothing there), only where C is nearer B than any interior
colour within 2 `band` px (a smoothed mean F is no person colour at a textured hair edge: a
dark strand against a dark wall reads as mostly wall by the mix, but finds its like inside),
and only from the outside in (the removed pixels must connect to the background), so a
background-coloured patch inside the person (a grey shirt on a grey wall) stays.

`drop_mask` is the vectorised rule; `drop_mask_reference` loops over the band's pixels
with brute-force nearest-pixel searches (the test compares the two).
"""
from __future__ import annotations

import threading

import numpy as np

#: |F - B| (RGB, 0-255 units) below which the mix is not trusted and a pixel keeps its label
MIN_CONTRAST = 24.0
#: a band pixel is background when its person share a is below this
ALPHA_CUT = 0.5


def _local_mean(img: np.ndarray, region: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W, 3) float32: the Gaussian-weighted mean colour of `region`'s pixels around each
    pixel (normalised convolution; where no region pixel is near, the plain image)."""
    import cv2

    w = region.astype(np.float32)
    k = int(2 * round(3 * sigma) + 1)
    num = cv2.GaussianBlur(img * w[..., None], (k, k), sigma, borderType=cv2.BORDER_REPLICATE)
    den = cv2.GaussianBlur(w, (k, k), sigma, borderType=cv2.BORDER_REPLICATE)
    return np.where(den[..., None] > 1e-4, num / np.maximum(den, 1e-4)[..., None], img)


def _cores(person: np.ndarray, band: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(interior (H, W) bool, clean background, band of person pixels to test)."""
    from scipy import ndimage

    inside = ndimage.distance_transform_edt(person)   # to the nearest background pixel
    outside = ndimage.distance_transform_edt(~person)  # to the nearest person pixel
    interior = inside > band
    clean_bg = outside > 1.0
    return interior, clean_bg, person & ~interior


_KERNEL_LOCK = threading.Lock()


def _nearest_interior_colour2(f: np.ndarray, interior: np.ndarray, ring: np.ndarray, reach: int) -> np.ndarray:
    """(H, W) float32: for each `ring` pixel the smallest squared colour distance to an
    `interior` pixel at most `reach` px away (inf where none is; 0 off the ring). Whole-number
    colours (`person_share`'s uint8 pixels) go to a Taichi kernel (`_boundary_kernels`: one
    task per ring pixel, exact integer distances, so the same array; 0.4-0.5 s -> a few ms a
    512 px frame); others to `_nearest_interior_colour2_loop`, the offset-by-offset twin."""
    f = np.asarray(f, np.float32)
    if not (len(f) and np.array_equal(f, np.round(f)) and np.abs(f).max() <= 255):
        return _nearest_interior_colour2_loop(f, interior, ring, reach)
    H, W = interior.shape
    out = np.zeros((H, W), np.float32)
    ys, xs = np.nonzero(ring)
    if not len(ys):
        return out
    from avatarkit.recon import _boundary_kernels as k

    best = np.empty(len(ys), np.float32)
    with _KERNEL_LOCK:      # frames segmented on several threads (`track.frame_hull`): one launch at a time
        k.nearest_interior(ys.astype(np.int32), xs.astype(np.int32), np.ascontiguousarray(f),
                           np.ascontiguousarray(interior, np.uint8), int(reach), best)
    best[best >= k.NONE] = np.inf
    out[ys, xs] = best
    return out


def _nearest_interior_colour2_loop(f: np.ndarray, interior: np.ndarray, ring: np.ndarray, reach: int) -> np.ndarray:
    """(H, W) float32: for each `ring` pixel the smallest squared colour distance to an
    `interior` pixel at most `reach` px away (inf where none is; 0 off the ring). Only the
    ring's pixels are visited, once per offset in the disc. The obvious twin of
    `_nearest_interior_colour2`, which it runs for colours that are not whole numbers."""
    H, W = interior.shape
    out = np.zeros((H, W), np.float32)
    ys, xs = np.nonzero(ring)
    if not len(ys):
        return out
    c = f[ys, xs]                                        # (N, 3)
    best = np.full(len(ys), np.inf, np.float32)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if dy * dy + dx * dx > reach * reach:
                continue
            y2, x2 = ys + dy, xs + dx
            ok = (y2 >= 0) & (y2 < H) & (x2 >= 0) & (x2 < W)
            ok[ok] = interior[y2[ok], x2[ok]]
            e = c[ok] - f[y2[ok], x2[ok]]
            d2 = np.einsum("ij,ij->i", e, e)
            best[ok] = np.minimum(best[ok], d2)
    out[ys, xs] = best
    return out


def person_share(img: np.ndarray, person: np.ndarray, band: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mixing test's numbers for the band pixels.

    img: (H, W, 3) uint8 RGB; person: (H, W) bool; band: px.
    Returns (band (H, W) bool, alpha (H, W) float32 (1 off the band), contrast (H, W) float32
    |F - B| (0 off the band), wall2 (H, W) float32 |C - B|^2, person2 (H, W) float32: the
    smallest |C - P|^2 over the interior pixels P within 2 `band` px (inf where none))."""
    from scipy import ndimage

    f = np.asarray(img, np.float32)
    interior, clean_bg, ring = _cores(person, band)
    alpha = np.ones(person.shape, np.float32)
    contrast = np.zeros(person.shape, np.float32)
    wall2 = np.zeros(person.shape, np.float32)
    person2 = np.zeros(person.shape, np.float32)
    if not interior.any() or not clean_bg.any() or not ring.any():
        return ring, alpha, contrast, wall2, person2
    sigma = max(1.0, band / 2)
    fg_mean, bg_mean = _local_mean(f, interior, sigma), _local_mean(f, clean_bg, sigma)
    _, (fy, fx) = ndimage.distance_transform_edt(~interior, return_indices=True)
    _, (by, bx) = ndimage.distance_transform_edt(~clean_bg, return_indices=True)
    ys, xs = np.nonzero(ring)
    F = fg_mean[fy[ys, xs], fx[ys, xs]]  # (N, 3)
    B = bg_mean[by[ys, xs], bx[ys, xs]]
    d = F - B
    n2 = np.einsum("ij,ij->i", d, d)
    alpha[ys, xs] = np.einsum("ij,ij->i", f[ys, xs] - B, d) / np.maximum(n2, 1e-6)
    contrast[ys, xs] = np.sqrt(n2)
    c = f[ys, xs] - B
    wall2[ys, xs] = np.einsum("ij,ij->i", c, c)
    person2 = _nearest_interior_colour2(f, interior, ring, 2 * band)
    return ring, alpha, contrast, wall2, person2


def _peel(person: np.ndarray, drop: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """`person` without the `drop` pixels that connect (8-connected, through other dropped
    pixels) to the background; `keep` pixels are never dropped."""
    from scipy import ndimage

    drop = drop & person & ~keep
    lab, n = ndimage.label(drop | ~person, structure=np.ones((3, 3), bool))
    if n == 0:
        return person
    outside = np.zeros(n + 1, bool)
    outside[np.unique(lab[~person])] = True
    outside[0] = False
    return person & ~(drop & outside[lab])


def _decide(alpha, contrast, wall2, person2):
    """The boundary step's rule (arrays or scalars): mostly wall by the mix, the mix
    trustworthy, and nearer the local wall colour than any nearby person colour (a dark
    strand at a textured hair edge finds its like inside and stays)."""
    return (alpha < ALPHA_CUT) & (contrast >= MIN_CONTRAST) & (wall2 < person2)


def drop_mask(img: np.ndarray, person: np.ndarray, band: int) -> np.ndarray:
    """(H, W) bool: the band pixels the rule calls wall (before the outside-in peel)."""
    ring, alpha, contrast, wall2, person2 = person_share(img, np.asarray(person, bool), band)
    return ring & _decide(alpha, contrast, wall2, person2)


def refine_person(img: np.ndarray, person: np.ndarray, band: int, keep: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: `person` with the band pixels that are mostly background removed.

    img: (H, W, 3) uint8 RGB; person: (H, W) bool; band: how deep (px) the outline may move
    in; keep: (H, W) bool pixels that stay person whatever their colour (the sure face)."""
    person = np.asarray(person, bool)
    keep = np.zeros_like(person) if keep is None else np.asarray(keep, bool)
    return _peel(person, drop_mask(img, person, band), keep)


def drop_mask_reference(img: np.ndarray, person: np.ndarray, band: int) -> tuple[np.ndarray, np.ndarray]:
    """`drop_mask` pixel by pixel, with brute-force searches for the nearest interior and
    clean-background pixels and for the nearest person colour. Returns (drop (H, W) bool,
    tied (H, W) bool): where several pixels are nearest and they disagree, the decision
    depends on which one a search picks (`drop` holds the first's); the test skips those."""
    person = np.asarray(person, bool)
    f = np.asarray(img, np.float32)
    interior, clean_bg, ring = _cores(person, band)
    drop, tied = np.zeros_like(person), np.zeros_like(person)
    if not interior.any() or not clean_bg.any():
        return drop, tied
    sigma = max(1.0, band / 2)
    fg_mean, bg_mean = _local_mean(f, interior, sigma), _local_mean(f, clean_bg, sigma)
    iy, ix = np.nonzero(interior)
    cy, cx = np.nonzero(clean_bg)
    for y, x in zip(*np.nonzero(ring)):
        di = (iy - y) ** 2 + (ix - x) ** 2
        dc = (cy - y) ** 2 + (cx - x) ** 2
        near = di <= (2 * band) ** 2
        p2 = float(((f[iy[near], ix[near]] - f[y, x]) ** 2).sum(axis=1).min()) if near.any() else np.inf
        votes = set()
        for i in np.flatnonzero(di == di.min()):
            for j in np.flatnonzero(dc == dc.min()):
                F, B = fg_mean[iy[i], ix[i]], bg_mean[cy[j], cx[j]]
                d = F - B
                n2 = float(d @ d)
                a = float((f[y, x] - B) @ d) / max(n2, 1e-6)
                w2 = float(((f[y, x] - B) ** 2).sum())
                votes.add(bool(_decide(a, np.sqrt(n2), w2, p2)))
        drop[y, x] = votes == {True}
        tied[y, x] = len(votes) > 1
    return drop, tied
