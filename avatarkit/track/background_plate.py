"""The wall behind the head, from a whole video: what a video knows and a photo does not.

A phone video's wall stays still while the head moves. Per pixel, the frames in which the tracked
head is far from that pixel show the wall there; their median colour is the wall's (the plate),
and how many of them agree with it says how well the plate is known there. The portrait
segmentation of every keyframe and of the reference frame (`recon.segment`, `plate=`) then takes
a pixel that matches a well-supported plate for sure background: a portrait's GrabCut has no
sure-background zone when the head fills the frame, and took clutter touching the head (a
poster, a door post, books) for the person (session 21, docs/video-build.md "Non-white walls").

Where a pixel is the wall's (`person_zone`, per tracked frame): outside the tracked head model's
projected outline dilated by `ZONE_MARGIN` of the head's size (the hair beyond the skull, the
tracking's error) and outside a torso swept down from the jaw, widening by `ZONE_SLOPE` px a row.
A pixel the zone covers in every frame (a head that never moves: where the head and the body
are) has no plate, and its segmentation is the plate-less one.

Closer to the head (`PASS_MARGIN`, inside the zone's margin; off by default) a pixel's wall is
taken only where the head is seen to pass over it: the frames that show the pixel outside the
tighter zone agree (the plate there) and enough of the frames with the tighter zone over it
differ from them (`PASS_FRAMES`, `PASS_SHARE`). A talking head that barely moves has the top of
its hair outside a tight zone in every frame and never shows anything else there: no plate (hair
is not wall); a turning head uncovers the wall beside its face and covers it again. It cannot
tell the wall just above a turning head's top, which the head never passes over either: off.
What tells it (`CONTINUE_MARGIN`, on) is its colour: the wall beside it continuing into it, grown
from the known wall a ring at a time in the colours of the wall far from the head (`_continued`).

Sizes: the plate is made at most `PLATE_SIZE` px on its longer side from at most `PLATE_FRAMES`
frames spread over the tracked clip; `Plate.at(shape)` resizes it to an image's size.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

#: the plate's longer side (px): a phone video's 1080p frames are median-filtered at this size
PLATE_SIZE = 256
#: at most this many frames (every k-th tracked frame) make the plate
PLATE_FRAMES = 64
#: the person zone: the head model's projected outline dilated by this share of the head's size
#: (sqrt of the outline's area): the hair beyond the skull. At 0.14 the shared talking clips'
#: plates held the top of the hair (the grey clip's keyframe lost 9,700 px of person, hair) and
#: the synthetic walls gained most (the clutter bob's front 16.6 dB against 13.7 at 0.25); at 0.25
#: the real clips' segmentations are as without a plate (session 22, docs/video-build.md)
ZONE_MARGIN = 0.25
#: the tighter zone of the pass test (`plate_from_frames(tight=)`): outside the `ZONE_MARGIN` zone's
#: plate, a pixel outside this one's outline is wall where the head is seen to pass over it. 0
#: (or >= `ZONE_MARGIN`): no pass test, the `ZONE_MARGIN` plate alone (the default). At 0.14 the
#: shared clips' keyframes segment as with the `ZONE_MARGIN` plate alone, to the pixel (0.14
#: alone cut the top of their hair), the dark-wall bob gains 2.6 dB of profile, but the cluttered walls lose 1.3 / 2.1 dB
#: (bob / sample avatar): the wall just above a turning head's top is never passed over, as a
#: still head's hair is not, and stays unknown there (session 22, docs/video-build.md). Off.
PASS_MARGIN = 0.0
#: the head passed over a pixel where at least this many of the frames with the tighter zone over
#: it differ from the plate (no channel within `AGREE`)...
PASS_FRAMES = 4
#: ...and at least this share of them. Low: the zone is generous (a turned head's outline covers
#: the wall beside a front face) and a turning head's hair covers such a pixel in few of the
#: frames the zone is over it (the dark-wall bob: 3,002 px at 4 frames, 2,940 at 0.1, 504 at
#: 0.5); the share keeps out a still head's hair whose colour a few frames' exposure changed
PASS_SHARE = 0.1
#: the continued wall (`plate_from_frames(near=)`; 0, or >= `ZONE_MARGIN`: off): where the
#: `ZONE_MARGIN` plate is not known, a pixel takes the plate of this tighter zone (the median of
#: the frames that show it outside the head model's outline dilated by this share) where that
#: colour continues the known wall next to it: grown out from the known wall a ring at a time,
#: a pixel joins where at least `CONTINUE_MATCHES` of the wall pixels (known or joined) within
#: `CONTINUE_REACH` of it are within `AGREE` of its colour. The wall just above a turning head's
#: top, which the head never passes over (`PASS_MARGIN`), is the wall beside it continuing; the
#: top of a still head's hair, outside a tight zone in every frame too, is not the wall's colour.
#: On (session 25, docs/video-build.md "The wall above the head"): the white-wall builds and the
#: shared clips' keyframes are as without it, to the digit and the pixel
CONTINUE_MARGIN = 0.14
#: ...the neighbourhood a joining pixel's colour is matched in (share of the plate's longer side)
CONTINUE_REACH = 0.015
#: ...and how many of the wall pixels there must match it (one stray pixel does not vouch)
CONTINUE_MATCHES = 3
#: ...and only in the colours of the known wall at least this far (share of the longer side) from
#: what the plate does not know (`wall_palette`, bins of `PALETTE_BIN` levels and their
#: neighbours), grown from known pixels of those colours
CONTINUE_DEEP = 0.025
#: ...in bins of this many levels a channel (a bin and its 26 neighbours: a wall's colour within
#: about 8-16 levels of one the far wall shows)
PALETTE_BIN = 8
#: the torso below the jaw (from this share of the outline's height down) widens this many px a row
ZONE_START = 0.75
ZONE_SLOPE = 0.5
#: a frame agrees with the plate where no channel differs from it by more than this (0-255
#: levels: camera noise and a codec's ringing at the clutter's edges)
AGREE = 12
#: the plate is known where at least this many frames agree with it...
MIN_FRAMES = 4
#: ...and at least this share of the frames that saw the pixel outside the person zone (a pixel
#: the hair crossed in a few frames: the wall wins only where it is what most of them saw)
MIN_AGREEMENT = 0.6


@dataclass(eq=False)
class Plate:
    """The wall seen behind a moving head.

    colour (h, w, 3) uint8: the median of the frames that saw each pixel outside the person
    zone (0 where none did); support (h, w) int32: how many of them agree with it (`AGREE`);
    seen (h, w) int32: how many saw it outside the zone; frames: how many frames were read.
    (h, w) is the video's frame size scaled to at most `PLATE_SIZE`."""

    colour: np.ndarray
    support: np.ndarray
    seen: np.ndarray
    frames: int

    @property
    def known(self) -> np.ndarray:
        """(h, w) bool: where the plate is well supported (`MIN_FRAMES`, `MIN_AGREEMENT`)."""
        return (self.support >= MIN_FRAMES) & (self.support >= MIN_AGREEMENT * np.maximum(self.seen, 1))

    def at(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The plate at an image's size (H, W): (colour (H, W, 3) uint8 (bilinear), known (H, W)
        bool (nearest, eroded by a pixel where scaled: a known pixel's colour is not a blend
        with an unknown one))."""
        import cv2

        H, W = shape
        known = self.known
        if known.shape == (H, W):
            return self.colour, known
        colour = cv2.resize(self.colour, (W, H), interpolation=cv2.INTER_LINEAR)
        k = cv2.erode(known.astype(np.uint8), np.ones((3, 3), np.uint8))
        return colour, cv2.resize(k, (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)

    def matches(self, image: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels of `image` ((H, W, 3) uint8, a frame of the video at any
        size) where the plate is known and no channel differs from it by more than `AGREE`."""
        colour, known = self.at(image.shape[:2])
        diff = np.abs(np.asarray(image, np.int16) - colour.astype(np.int16)).max(axis=2)
        return known & (diff <= AGREE)

    def summary(self) -> dict:
        """Figures for the build report."""
        known = self.known
        return {"frames": int(self.frames), "size": [int(self.colour.shape[1]), int(self.colour.shape[0])],
                "known_share": round(float(known.mean()), 4)}


def person_zone(points: np.ndarray, shape: tuple[int, int], margin: float | None = None) -> np.ndarray:
    """(h, w) bool: where the person may be in a frame whose head model projects to `points`
    ((V, 2) px, NaN where behind the camera): the points' convex outline dilated by `margin`
    (None: `ZONE_MARGIN`) of its size, and below `ZONE_START` of its height a torso widening by
    `ZONE_SLOPE` px a row. All True when no point projects (nothing known: no plate from it)."""
    import cv2

    h, w = shape
    p = np.asarray(points, np.float32)
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < 3:
        return np.ones(shape, bool)
    hull = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(hull, np.round(cv2.convexHull(p)[:, 0]).astype(np.int32), 1)
    if not hull.any():
        return np.ones(shape, bool)
    r = (ZONE_MARGIN if margin is None else margin) * np.sqrt(hull.sum())
    dist = cv2.distanceTransform((1 - hull).astype(np.uint8), cv2.DIST_L2, 3)
    zone = dist <= r
    rows = np.nonzero(hull.any(axis=1))[0]
    y0 = int(rows[0] + ZONE_START * (rows[-1] - rows[0]))
    cols = np.nonzero(zone[y0])[0]
    yy, xx = np.mgrid[0:h, 0:w]
    k = np.maximum(yy - y0, 0) * ZONE_SLOPE
    return zone | ((yy >= y0) & (xx >= cols.min() - k) & (xx <= cols.max() + k))


def _median_plate(frames: np.ndarray, out: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel of frames (T, h, w, 3) uint8, the channel-wise median of those where out (T, h, w)
    bool: colour (h, w, 3) uint8 (0 where none), agree (T, h, w) bool (an `out` frame within
    `AGREE` of it) and diff (T, h, w) bool (any frame not within `AGREE` of it)."""
    import warnings

    x = np.where(out[..., None], frames.astype(np.float32), np.nan)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # all-NaN pixels: no plate
        med = np.nanmedian(x, axis=0)                        # (h, w, 3)
    colour = np.nan_to_num(np.round(med), nan=0.0).astype(np.uint8)
    diff = np.abs(frames.astype(np.int16) - colour[None].astype(np.int16)).max(axis=3) > AGREE
    return colour, out & ~diff, diff


def _continued(known: np.ndarray, colour: np.ndarray, candidate: np.ndarray, c_colour: np.ndarray) -> np.ndarray:
    """(h, w) bool: the `candidate` pixels (h, w) bool whose colour `c_colour` (h, w, 3) uint8
    continues the wall `known` (h, w) bool of colour `colour` (h, w, 3): grown from it a ring at a
    time, a pixel joins where at least `CONTINUE_MATCHES` wall pixels (known or joined) within
    `CONTINUE_REACH` are within `AGREE` of its colour in every channel; only pixels (candidates and
    the known wall they grow from) of the far wall's colours (`wall_palette`)."""
    import cv2

    h, w = known.shape
    r = max(1, int(round(CONTINUE_REACH * max(h, w))))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
    cc = np.asarray(c_colour, np.int16)
    col = np.where(known[..., None], np.asarray(colour, np.int16), cc)     # (h, w, 3) the wall's colour
    table = wall_palette(known, colour)
    wall = known & in_palette(table, col)
    candidate = candidate & in_palette(table, cc)
    pad_w = np.pad(wall, r)
    pad_c = np.pad(col, ((r, r), (r, r), (0, 0)))
    while True:
        ring = candidate & ~wall & (cv2.dilate(wall.astype(np.uint8), disc) > 0)
        ys, xs = np.nonzero(ring)
        if len(ys) == 0:
            break
        # the ring's own pixels are not wall yet: the disc's centre counts nothing
        join = agreeing(pad_w, pad_c, ys, xs, cc[ys, xs], disc) >= CONTINUE_MATCHES
        if not join.any():
            break
        wall[ys[join], xs[join]] = True
        pad_w[ys[join] + r, xs[join] + r] = True
    return wall & ~known


def agreeing(wall: np.ndarray, colour: np.ndarray, ys: np.ndarray, xs: np.ndarray, c: np.ndarray,
             disc: np.ndarray, enough: int | None = None) -> np.ndarray:
    """(N,) int: for each pixel (ys, xs) (N,) of colour c (N, 3) int16, how many pixels of `wall`
    within `disc` ((2r + 1, 2r + 1) bool, centred on it) are within `AGREE` of c in every channel;
    wall (h + 2r, w + 2r) bool and colour (h + 2r, w + 2r, 3) int16 padded by r (so (ys, xs)
    index the disc's corner). enough: a pixel stops counting once it has this many (the count
    returned is min(count, enough)): the disc's offsets nearest its centre first, the pixels done
    dropped every `AGREEING_CHUNK` offsets."""
    count = np.zeros(len(ys), np.int32)
    if enough is None:
        for dy, dx in zip(*np.nonzero(disc)):
            yy, xx = ys + dy, xs + dx
            count += wall[yy, xx] & (np.abs(colour[yy, xx] - c).max(axis=1) <= AGREE)
        return count
    dys, dxs = np.nonzero(disc)
    r = disc.shape[0] // 2
    order = np.argsort((dys - r) ** 2 + (dxs - r) ** 2, kind="stable")
    dys, dxs = dys[order], dxs[order]
    live = np.arange(len(ys))                               # (L,) the pixels still counting
    ly, lx, lc, n = ys, xs, c, count.copy()
    for i0 in range(0, len(dys), AGREEING_CHUNK):
        if enough <= 0 or len(live) == 0:
            break
        for dy, dx in zip(dys[i0:i0 + AGREEING_CHUNK], dxs[i0:i0 + AGREEING_CHUNK]):
            yy, xx = ly + dy, lx + dx
            n += wall[yy, xx] & (np.abs(colour[yy, xx] - lc).max(axis=1) <= AGREE)
        count[live] = n
        more = n < enough
        live, ly, lx, lc, n = live[more], ly[more], lx[more], lc[more], n[more]
    return np.minimum(count, enough)


#: `agreeing(enough=)`: how many of the disc's offsets run between two drops of the pixels done
AGREEING_CHUNK = 256


def _colour_bins(known: np.ndarray, colour: np.ndarray, w: int) -> tuple[int, np.ndarray, np.ndarray]:
    """The known pixels' colour bins, `w` levels a channel: (n bins a channel, bins (B,) int, each
    the code (r * n + g) * n + b of a bin the known pixels fill, label (H, W) int32: the index in
    `bins` of each known pixel's bin, -1 where unknown), for `known` (H, W) bool and `colour`
    (H, W, 3)."""
    n = 255 // w + 1
    kb = np.asarray(colour, np.int32)[known] // w                    # (K, 3) the known pixels' bins
    code = (kb[:, 0] * n + kb[:, 1]) * n + kb[:, 2]
    bins, inv = np.unique(code, return_inverse=True)
    label = np.full(known.shape, -1, np.int32)
    label[known] = inv.ravel()
    return n, bins, label


def square_bound(known: np.ndarray, colour: np.ndarray, ys: np.ndarray, xs: np.ndarray, c: np.ndarray,
                 r: int) -> np.ndarray:
    """(N,) int: an upper bound of `agreeing`'s count for the pixels (ys, xs) (N,) of colour c
    (N, 3) int: the pixels the plate knows (`known` (H, W) bool, of colour `colour` (H, W, 3);
    unpadded) in the (2r + 1)-square around each (which holds its disc) whose colour's bin
    (`AGREE` levels a channel) is within one of c's in every channel. Two levels within `AGREE`
    of each other lie in the same bin or in neighbouring ones, so every pixel `agreeing` counts
    is counted here. One summed-area table per bin the known wall's colours fill (a plain wall:
    a few; a cluttered one: a few hundred)."""
    import cv2

    H, W = known.shape
    w = max(int(AGREE), 1)
    n, bins, label = _colour_bins(known, colour, w)
    pb = np.asarray(c, np.int32) // w                                # (N, 3)
    y0, y1 = np.clip(ys - r, 0, H), np.clip(ys + r + 1, 0, H)
    x0, x1 = np.clip(xs - r, 0, W), np.clip(xs + r + 1, 0, W)
    bound = np.zeros(len(ys), np.int64)
    for j, b in enumerate(bins):
        i = np.flatnonzero((np.abs(pb - (b // (n * n), (b // n) % n, b % n)) <= 1).all(axis=1))
        if len(i) == 0:
            continue
        S = cv2.integral((label == j).astype(np.uint8), sdepth=cv2.CV_32S)   # (H + 1, W + 1)
        bound[i] += S[y1[i], x1[i]] - S[y0[i], x1[i]] - S[y1[i], x0[i]] + S[y0[i], x0[i]]
    return bound


def disc_bound(known: np.ndarray, colour: np.ndarray, ys: np.ndarray, xs: np.ndarray, c: np.ndarray,
               disc: np.ndarray, strips: int | None = None) -> np.ndarray:
    """(N,) int: a lower bound of `agreeing`'s count for the pixels (ys, xs) (N,) of colour c
    (N, 3) int: the known pixels (`known` (H, W) bool, of colour `colour` (H, W, 3); unpadded)
    of c's own colour bin (`AGREE` + 1 levels a channel: two levels in one bin are within `AGREE`)
    in a stack of rectangles inside the disc ((2r + 1, 2r + 1), `strips` (None: `DISC_STRIPS`)
    bands of rows above and below a middle one, each as wide as the disc's narrowest row in it).
    The wall continuing into the wall it stands beside has most of its disc in its own colour:
    decided without counting (`continues`)."""
    import cv2

    H, W = known.shape
    r = disc.shape[0] // 2
    half = (np.asarray(disc, bool).sum(axis=1) - 1) // 2            # (2r + 1,) each row's half-width
    k = max(1, int(DISC_STRIPS if strips is None else strips))
    edges = np.unique(np.round(np.linspace(0, r, k + 1)).astype(int))    # row offsets 0 = e0 < e1 .. = r
    # pieces (dy0, dy1, hw): rows dy0..dy1 (offsets from the centre), columns -hw..hw
    pieces = [(-edges[0], edges[0], int(half[r + edges[0]]))]
    for lo, hi in zip(edges[:-1], edges[1:]):
        hw = int(half[r + hi])                                      # the band's narrowest row
        pieces += [(lo + 1, hi, hw), (-hi, -lo - 1, hw)]
    w = int(AGREE) + 1
    n, bins, label = _colour_bins(known, colour, w)
    pb = np.asarray(c, np.int32) // w
    pcode = (pb[:, 0] * n + pb[:, 1]) * n + pb[:, 2]
    bound = np.zeros(len(ys), np.int64)
    for j in np.flatnonzero(np.isin(bins, pcode)):
        i = np.flatnonzero(pcode == bins[j])
        S = cv2.integral((label == j).astype(np.uint8), sdepth=cv2.CV_32S)   # (H + 1, W + 1)
        for dy0, dy1, hw in pieces:
            y0, y1 = np.clip(ys[i] + dy0, 0, H), np.clip(ys[i] + dy1 + 1, 0, H)
            x0, x1 = np.clip(xs[i] - hw, 0, W), np.clip(xs[i] + hw + 1, 0, W)
            bound[i] += S[y1, x1] - S[y0, x1] - S[y1, x0] + S[y0, x0]
    return bound


#: `disc_bound`: the bands of rows (each side of the middle row) its rectangles fill the disc with
DISC_STRIPS = 8


def continues(known: np.ndarray, colour: np.ndarray, image: np.ndarray, region: np.ndarray,
              r: int, enough: int) -> np.ndarray:
    """(H, W) bool: the pixels of `region` (H, W) bool where `continuing`'s count reaches `enough`
    (the same decision, without counting past it): only the pixels whose `square_bound` reaches
    it are counted (a head's skin beside a white wall is not near any of its colours), each until
    it has `enough` (`agreeing(enough=)`), and not those whose `disc_bound` reaches it already
    (the wall beside the known wall: the relabelling's band). At the coverage's reach (0.1 of the longer side) a
    phone video's 1920 px frame has a disc of ~116,000 offsets against 7,200 at 480 px, over 16x
    the pixels: hours counted in full (session 28, docs/video-build.md)."""
    import cv2

    region = np.asarray(region, bool)
    out = np.zeros(region.shape, bool)
    known = np.asarray(known, bool)
    if enough <= 0:
        return region.copy()
    ys, xs = np.nonzero(region)
    if len(ys) == 0 or not known.any():
        return out
    c = np.asarray(image, np.int16)[ys, xs]
    may = square_bound(known, colour, ys, xs, c, r) >= enough
    ys, xs, c = ys[may], xs[may], c[may]
    if len(ys) == 0:
        return out
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
    sure = disc_bound(known, colour, ys, xs, c, disc) >= enough
    out[ys[sure], xs[sure]] = True
    ys, xs, c = ys[~sure], xs[~sure], c[~sure]
    if len(ys) == 0:
        return out
    count = agreeing(np.pad(known, r), np.pad(np.asarray(colour, np.int16), ((r, r), (r, r), (0, 0))),
                     ys, xs, c, disc, enough)
    out[ys, xs] = count >= enough
    return out


def continuing(known: np.ndarray, colour: np.ndarray, image: np.ndarray, region: np.ndarray,
               r: int) -> np.ndarray:
    """(H, W) int32: for each pixel of `region` (H, W) bool, how many pixels the plate knows
    (`known` (H, W) bool, of colour `colour` (H, W, 3)) within r px (a disc) are within `AGREE` of
    image's (H, W, 3) colour there in every channel (`agreeing`); 0 outside region. How far a
    pixel's colour continues the known wall beside it (the turned keyframes' relabelling, the video
    build's coverage)."""
    import cv2

    region = np.asarray(region, bool)
    out = np.zeros(region.shape, np.int32)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
    # only the pixels with a known pixel inside their disc can count any: the rest stay 0 (the
    # head's inside, far from the wall, is most of a region; at 480 px the disc has ~7,200 offsets)
    near = cv2.dilate(np.asarray(known, np.uint8), disc, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    ys, xs = np.nonzero(region & near)
    if len(ys) == 0:
        return out
    out[ys, xs] = agreeing(np.pad(np.asarray(known, bool), r),
                           np.pad(np.asarray(colour, np.int16), ((r, r), (r, r), (0, 0))),
                           ys, xs, np.asarray(image, np.int16)[ys, xs], disc)
    return out


def wall_palette(known: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """(32768,) bool: the colour bins (`PALETTE_BIN` levels a channel; with their 26 neighbours)
    of the known wall far from what the plate does not know: the known pixels at least
    `CONTINUE_DEEP` of the longer side from an unknown one. A still head's flyaway top of the hair
    lies outside the zone in most frames and is known (the grey clip: 181 px by the unknown);
    grown from, it took the hair. The wall far from the head never shows it."""
    import cv2
    from scipy import ndimage

    d = max(1, int(round(CONTINUE_DEEP * max(known.shape))))
    deep = cv2.distanceTransform(known.astype(np.uint8), cv2.DIST_L2, 3) > d
    n = 256 // PALETTE_BIN
    q = (np.asarray(colour)[deep] // PALETTE_BIN).astype(np.intp)
    table = np.zeros(n**3, bool)
    table[(q[:, 0] * n + q[:, 1]) * n + q[:, 2]] = True
    return ndimage.binary_dilation(table.reshape(n, n, n), np.ones((3, 3, 3), bool)).ravel()


def in_palette(table: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """(...) bool: colours (..., 3) whose bin is in the palette `table` (`wall_palette`)."""
    n = 256 // PALETTE_BIN
    q = (np.asarray(colour) // PALETTE_BIN).astype(np.intp)
    return table[(q[..., 0] * n + q[..., 1]) * n + q[..., 2]]


def plate_from_frames(frames: np.ndarray, zones: np.ndarray, tight: np.ndarray | None = None,
                      near: np.ndarray | None = None) -> Plate:
    """The plate of frames (T, h, w, 3) uint8 with their person zones (T, h, w) bool (True: the
    person may be there). Per pixel the channel-wise median of the frames outside their zone,
    the count that agree with it (`AGREE`) and the count outside. tight (T, h, w) bool: the
    frames' tighter zones (`PASS_MARGIN`); where the plate of `zones` is not known, a pixel takes
    the plate of `tight` if that is known there and the head passed over it: at least
    `PASS_FRAMES` and `PASS_SHARE` of the frames with the tighter zone over it differ from it.
    near (T, h, w) bool: the frames' zones at `CONTINUE_MARGIN`; where the plate (after the pass
    test) is still not known, a pixel takes the plate of `near` where that is known and its colour
    continues the known wall (`_continued`)."""
    frames = np.asarray(frames)
    out = ~np.asarray(zones, bool)                          # (T, h, w) the frame saw the wall here
    colour, agree, _ = _median_plate(frames, out)
    plate = Plate(colour, agree.sum(axis=0).astype(np.int32), out.sum(axis=0).astype(np.int32), int(len(frames)))
    if tight is not None:
        _pass_test(plate, frames, np.asarray(tight, bool))
    if near is not None:
        inside = np.asarray(near, bool)
        n_colour, n_agree, _ = _median_plate(frames, ~inside)
        n_plate = Plate(n_colour, n_agree.sum(axis=0).astype(np.int32), (~inside).sum(axis=0).astype(np.int32), plate.frames)
        known = plate.known
        take = _continued(known, plate.colour, n_plate.known & ~known, n_colour)
        plate.colour[take] = n_colour[take]
        plate.support[take] = n_plate.support[take]
        plate.seen[take] = n_plate.seen[take]
    return plate


def _pass_test(plate: Plate, frames: np.ndarray, inside: np.ndarray) -> None:
    """`plate` given the plate of the tighter zones `inside` (T, h, w) bool where the head was
    seen to pass over a pixel (`plate_from_frames`, `PASS_MARGIN`), in place."""
    t_colour, t_agree, t_diff = _median_plate(frames, ~inside)
    t_plate = Plate(t_colour, t_agree.sum(axis=0).astype(np.int32), (~inside).sum(axis=0).astype(np.int32), plate.frames)
    over = inside.sum(axis=0)                               # (h, w) frames with the head over it
    passed = (inside & t_diff).sum(axis=0)                  # (h, w) ...that show something else
    take = t_plate.known & ~plate.known & (passed >= PASS_FRAMES) & (passed >= PASS_SHARE * over)
    plate.colour[take] = t_colour[take]
    plate.support[take] = t_plate.support[take]
    plate.seen[take] = t_plate.seen[take]


def video_plate(video: str | os.PathLike, result) -> Plate | None:
    """The plate of a tracked video (`TrackResult` of `track.video.track_video` on it): at most
    `PLATE_FRAMES` of its frames where the face was found, at most `PLATE_SIZE` px, each with the person zone of
    its tracked head (`person_zone` of the head model posed by the clip, projected by the
    tracking's camera). None when the video gives fewer than `MIN_FRAMES` frames."""
    import cv2

    from avatarkit.head.model import HeadParams
    from avatarkit.video import open_video

    index = np.asarray(result.frame_index)
    # only the frames whose face the tracker found: a lost stretch's pose is interpolated (a
    # turn's end read tens of degrees short), and its head's zone left the hair behind it out
    found = np.flatnonzero(np.asarray(result.found, bool))
    step = max(1, int(np.ceil(len(found) / PLATE_FRAMES)))
    rows = found[::step]
    if len(rows) < MIN_FRAMES:
        return None
    want = {int(index[t]): t for t in rows}
    images, ts = [], []
    with open_video(video) as v:
        for frame in v.frames(min(want), max(want) + 1):
            t = want.get(int(frame.index))
            if t is None:
                continue
            rgb = frame.rgb
            H, W = rgb.shape[:2]
            k = min(1.0, PLATE_SIZE / max(H, W))
            if k < 1.0:
                rgb = cv2.resize(rgb, (max(1, round(W * k)), max(1, round(H * k))), interpolation=cv2.INTER_AREA)
            images.append(rgb)
            ts.append(t)
    if len(images) < MIN_FRAMES:
        return None
    h, w = images[0].shape[:2]
    params = HeadParams.from_clip(result.clip, frames=[int(t) for t in ts])
    params.shape = np.asarray(result.clip.shape, np.float32)
    verts = result.model.forward(params)[0]                 # (T, V, 3)
    sx, sy = w / result.camera.width, h / result.camera.height
    passing = 0.0 < PASS_MARGIN < ZONE_MARGIN
    continuing = 0.0 < CONTINUE_MARGIN < ZONE_MARGIN
    zones, tight, near = [], [], []
    for vt in verts:
        px, _ = result.camera.project(vt)
        px = px * np.array([sx, sy])
        zones.append(person_zone(px, (h, w)))
        if passing:
            tight.append(person_zone(px, (h, w), PASS_MARGIN))
        if continuing:
            near.append(person_zone(px, (h, w), CONTINUE_MARGIN))
    return plate_from_frames(np.stack(images), np.stack(zones), np.stack(tight) if passing else None,
                             np.stack(near) if continuing else None)


__all__ = ["AGREE", "CONTINUE_MATCHES", "CONTINUE_MARGIN", "CONTINUE_DEEP", "CONTINUE_REACH", "PALETTE_BIN", "MIN_AGREEMENT", "MIN_FRAMES", "PASS_FRAMES", "PASS_MARGIN", "PASS_SHARE", "PLATE_FRAMES", "PLATE_SIZE", "ZONE_MARGIN", "ZONE_SLOPE",
           "ZONE_START", "Plate", "agreeing", "continues", "continuing", "disc_bound", "square_bound", "DISC_STRIPS", "in_palette", "person_zone", "plate_from_frames", "video_plate", "wall_palette"]
