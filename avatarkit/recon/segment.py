"""Portrait segmentation into background / skin (face) / hair / body with a classical method.

Built-in method (all in the eye frame of `PortraitAnalysis`, unit = inter-ocular distance):
1. person vs background: `cv2.grabCut` seeded from the face: the face core and neck are sure
   person, a head ellipse (room for hair) and a widening torso below the chin probable person,
   far left/right of the head sure background, the rest probable background. GrabCut sees the
   image with camera-size noise put back into its flat pixels, the light ones and those of
   the wall's own colours when dark (`_renoise_flat`: a clipped, JPEG- or codec-flattened
   wall otherwise gives its background model a zero-spread component, and the wall's pixels
   near the person join the person); then the outline's band (0.1 IOD) is
   peeled from the outside where a pixel is mostly wall by a local colour mix
   (`recon.boundary`). Without the two, a plain light wall left a 1.5-10 px halo in the
   person, which became the hair label (a flat dark wall 8-9 px until session 18). A video
   build passes the wall seen behind its moving head (`plate=`, `track.background_plate`):
   the pixels that match it where it is well known are sure background too (`PLATE_SURE`);
2. a skin colour model: a robust Gaussian in CIE Lab fitted to the cheeks and nose (below the
   eyes, above the mouth), outliers (nostrils, shadows) trimmed;
3. hair seeds: person pixels in a band above the forehead and at the temples that are not skin;
   a robust Gaussian hair colour model from them (no seeds: a bald head, no hair label; a
   dim picture that gives none is tried once more brightened to its full exposure, `DIM_GAIN`);
4. hair vs the rest of the person: a second GrabCut restricted to the person, seeded with the
   hair seeds (sure hair) and the face core (sure not hair); background pixels are repainted
   with the skin colour so they cannot teach the "not hair" model hair-like colours;
5. clean-up: hair components not connected to a seed are dropped, small holes filled; person
   pixels in the head ellipse or skin-coloured are skin, the rest of the person is body.

`hair_mask` (an array or an image path, any non-zero = hair, e.g. from SAM) replaces step 4.
GrabCut runs on a copy whose longer side is at most `work_size` (512) px; labels are upsampled.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.recon.portrait import FACE_PROPORTIONS, PortraitAnalysis

BACKGROUND, SKIN, HAIR, BODY = 0, 1, 2, 3
LABEL_NAMES = ("background", "skin", "hair", "body")

#: squared Mahalanobis distance below which a colour belongs to a model (~99.9% for 3 dof)
MATCH_D2 = 16.0
#: smallest colour spread a model may claim (Lab units): flat synthetic colours and JPEG
#: quantisation would otherwise give a singular covariance
MIN_STD = 2.0
WORK_SIZE = 512
#: how deep (IOD units) the boundary step may move GrabCut's person outline in
BOUNDARY_BAND = 0.1


def boundary_band(iod: float) -> int:
    """The boundary step's band in px for a face `iod` px wide (at least 2 px)."""
    return max(2, int(round(BOUNDARY_BAND * iod)))


def rgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 sRGB -> (..., 3) float32 CIE Lab (L in [0, 100])."""
    import cv2

    a = np.asarray(rgb, dtype=np.float32).reshape(-1, 1, 3) / 255.0
    return cv2.cvtColor(a, cv2.COLOR_RGB2Lab).reshape(np.shape(rgb))


def lab_to_rgb(lab: np.ndarray) -> np.ndarray:
    """(..., 3) float CIE Lab -> (..., 3) float32 sRGB in [0, 255] (not rounded)."""
    import cv2

    a = np.asarray(lab, dtype=np.float32).reshape(-1, 1, 3)
    return (np.clip(cv2.cvtColor(a, cv2.COLOR_Lab2RGB), 0, 1) * 255.0).reshape(np.shape(lab))


@dataclass(frozen=True, eq=False)
class ColourModel:
    """A Gaussian colour model in CIE Lab."""

    mean: np.ndarray  # (3,) float64 Lab
    cov: np.ndarray   # (3, 3) float64
    count: int        # samples it was fitted to (after trimming)

    @classmethod
    def fit(cls, lab: np.ndarray, trim_d2: float = 7.8, rounds: int = 3) -> "ColourModel":
        """Robust fit to samples (N, 3): start from the median, then `rounds` times keep the
        samples within `trim_d2` (chi-square 95% for 3 dof) and refit."""
        x = np.asarray(lab, dtype=np.float64).reshape(-1, 3)
        if len(x) == 0:
            raise InputError("cannot fit a colour model to zero samples")
        mean = np.median(x, axis=0)
        mad = np.median(np.abs(x - mean), axis=0) * 1.4826
        est = np.diag(np.maximum(mad, MIN_STD) ** 2)
        keep = np.ones(len(x), bool)
        for _ in range(rounds):
            # A tiny floor keeps flat (synthetic) colours from making the matrix singular.
            keep = _mahalanobis2(x, mean, est + 0.25 * np.eye(3)) <= trim_d2
            if keep.sum() < 4:
                break
            mean = x[keep].mean(axis=0)
            # The trimmed sample underestimates the spread of a Gaussian truncated at chi2(95%):
            # dividing by the truncated second moment (0.833 for 3 dof at 95%) undoes it.
            est = np.cov(x[keep].T) / 0.833
        cov = est + np.eye(3) * MIN_STD**2
        return cls(mean=mean, cov=cov, count=int(keep.sum()))

    def distance2(self, lab: np.ndarray) -> np.ndarray:
        """Squared Mahalanobis distance of Lab colours (..., 3) -> (...)."""
        return _mahalanobis2(lab, self.mean, self.cov)

    def log_likelihood(self, lab: np.ndarray, distance2: np.ndarray | None = None) -> np.ndarray:
        """Log density (up to a shared constant) of Lab colours (..., 3) -> (...); distance2:
        their `distance2` when the caller has it already (the same numbers, not recomputed)."""
        d2 = self.distance2(lab) if distance2 is None else distance2
        return -0.5 * d2 - 0.5 * float(np.linalg.slogdet(self.cov)[1])

    @property
    def rgb(self) -> np.ndarray:
        """(3,) uint8 sRGB of the mean colour."""
        return np.round(lab_to_rgb(self.mean[None].astype(np.float32))[0]).astype(np.uint8)


def _mahalanobis2(x, mean, cov) -> np.ndarray:
    """(..., 3) -> (...) float32 squared Mahalanobis distances (float32 maths: image-sized inputs)."""
    d = (np.asarray(x, dtype=np.float32) - np.asarray(mean, dtype=np.float32)).reshape(-1, 3)
    p = np.linalg.inv(np.asarray(cov, dtype=np.float64)).astype(np.float32)
    return np.einsum("ij,ij->i", d @ p, d).reshape(np.shape(x)[:-1])


@dataclass(eq=False)
class Segmentation:
    """Per-pixel labels of one portrait and the colour models behind them."""

    labels: np.ndarray               # (H, W) uint8: 0 background, 1 skin/face, 2 hair, 3 body/clothes
    skin_model: ColourModel
    hair_model: ColourModel | None   # None when no hair was found (and none imported)
    hair_source: str                 # "grabcut" | "imported" | "none"

    def mask(self, label: int) -> np.ndarray:
        """(H, W) bool."""
        return self.labels == label

    @property
    def hair(self) -> np.ndarray:
        return self.labels == HAIR

    @property
    def skin(self) -> np.ndarray:
        return self.labels == SKIN

    @property
    def person(self) -> np.ndarray:
        return self.labels != BACKGROUND

    def fractions(self) -> dict[str, float]:
        """Share of the image per label name."""
        counts = np.bincount(self.labels.ravel(), minlength=4)[:4]
        return {n: float(c) / self.labels.size for n, c in zip(LABEL_NAMES, counts)}


def _ellipse(u, v, cu, cv, au, av) -> np.ndarray:
    return ((u - cu) / au) ** 2 + ((v - cv) / av) ** 2 <= 1.0


def face_regions(u: np.ndarray, v: np.ndarray) -> dict[str, np.ndarray]:
    """Named boolean regions (H, W) from eye-frame coordinates (u, v) in IOD units."""
    chin = FACE_PROPORTIONS["chin"][1]
    au = np.abs(u)
    return {
        # eyes, brows, nose, mouth and cheeks: always face, never hair or background
        # (its top stops at the brows: bangs often reach down to just above them)
        "face_core": _ellipse(u, v, 0.0, 0.6, 0.9, 1.05) | ((au < 0.65) & (v > -0.45) & (v < 0.2)),
        "neck": (au < 0.3) & (v > chin - 0.05) & (v < chin + 0.45),
        # where hair can be: generous ellipse over the head
        "head_zone": _ellipse(u, v, 0.0, -0.1, 2.1, 2.5),
        # the head itself (skull + face + ears), for the skin label
        "head": _ellipse(u, v, 0.0, 0.1, 1.35, 1.95) & (v < chin + 0.1),
        "torso": (v > chin - 0.15) & (au < 1.0 + (v - chin + 0.15) * 1.5),
        "far": ~_ellipse(u, v, 0.0, -0.1, 3.2, 3.4) & (v < chin - 0.55),
        "skin_sample": (au < 0.75) & (v > 0.2) & (v < 0.75),
        "seed_zone": (((au < 0.9) & (v > -1.9) & (v < -0.9))
                      | ((au > 1.1) & (au < 1.6) & (v > -1.0) & (v < 0.4))),
        # long hair may fall beside the neck onto the shoulders
        "hair_zone": (v < chin - 0.05) | ((au > 0.7) & (v < chin + 2.5)),
    }


def _grabcut(image: np.ndarray, mask: np.ndarray, iterations: int) -> np.ndarray:
    """Run GrabCut from an initial GC_* mask; returns (H, W) bool foreground. A mask without both
    classes is returned as is (GrabCut cannot learn a model from nothing)."""
    import cv2

    fg = (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)
    if fg.all() or not fg.any():
        return fg
    m = mask.copy()
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.grabCut(np.ascontiguousarray(image), m, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    return (m == cv2.GC_FGD) | (m == cv2.GC_PR_FGD)


def _keep_touching(mask: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """The connected components (8-connected) of `mask` that contain a seed pixel."""
    from scipy import ndimage

    lab, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return mask
    keep = np.zeros(n + 1, bool)
    keep[np.unique(lab[seeds & mask])] = True
    keep[0] = False
    return keep[lab]


def _drop_small(mask: np.ndarray, max_size: int) -> np.ndarray:
    """`mask` without its 4-connected components of at most `max_size` pixels."""
    from scipy import ndimage

    lab, n = ndimage.label(mask)
    if n == 0:
        return mask
    sizes = np.bincount(lab.ravel())
    keep = sizes > max_size
    keep[0] = False
    return keep[lab]


#: sigma (0-255 levels) of the noise put back into flat pixels for GrabCut
FLAT_NOISE = 3.0
#: flat pixels with every channel at least this light get it (see `_renoise_flat`)...
FLAT_LIGHT = 128
#: ...and, when this is on, darker flat pixels of the wall's dark colours (`_wall_coloured`)
RENOISE_DARK_WALL = True
#: bin width (levels per channel) of the wall-colour table: a colour is the wall's when its
#: bin is one of, or next to one of, the bins of the wall zone's flat pixels...
WALL_BIN = 4
#: ...that hold at least this share of the wall zone's pixels (a few stray flat pixels on a
#: light wall are no flat dark wall)
WALL_MIN_SHARE = 0.002
#: when GrabCut on the re-noised image (`RENOISE_DARK_WALL`) keeps at least this share of the
#: wall zone (what it starts as probable background) as person, it is run again with only the
#: light flat pixels re-noised, and that person kept when it leaves more wall (None: never).
#: A head filling the frame (a video at 192 px: no "far" zone of sure background) on a flat
#: dark or coloured wall: the re-noised wall inside the head ellipse taught the person's
#: mixture the wall, and GrabCut took the whole frame as person, labelled hair (the bob on a
#: dark grey / teal wall: 36,864 of 36,864 px person; 14,990 / 16,519 with the light pixels
#: alone re-noised). Session 21 (docs/video-build.md, "Non-white walls").
WALL_TAKEN = 0.98
#: a video build's wall plate (`track.background_plate`, `segment_portrait(plate=)`): the pixels
#: that match it where it is well known are GrabCut's sure background (False: the plate is
#: ignored, the segmentation is the portrait's). At 192 px the head fills the frame and the
#: portrait has no sure-background zone: on a cluttered wall GrabCut took the poster, the post
#: and the books touching the head for the person, then the hair (session 22,
#: docs/video-build.md "The wall behind the head").
PLATE_SURE = True
#: ...only the parts of that match that survive an opening by a disc this wide (IOD units; 0:
#: none): the gaps between strands, a pixel or two, stay GrabCut's to decide
PLATE_OPEN = 0.05
#: ...and only where the portrait's own segmentation (without the plate) holds at least this
#: share of those pixels as person: it failed on that wall, and runs again with them sure
#: background. Where it did not (a plain white wall: at most 0.2 % of them on the synthetic
#: turning videos' keyframes; teal 0-9 %, clutter 24-69 %), the plate is left out: as sure
#: background it still changed GrabCut's colour models (no wall colour left in the person's),
#: and the white-walled bob's video build lost 0.6 dB at +90
PLATE_TAKEN = 0.02

#: a picture that gives no hair and whose light end is dim (`exposure_gain` at least
#: `DIM_GAIN_MIN`) is segmented again brightened by that gain, at most this (None: never).
#: Lab's contrast between colours shrinks with the light (L, a and b follow the cube root of
#: the luminance) while the colour models' floor (`MIN_STD`) and 8-bit levels do not: the
#: sample avatar's blonde hair on its skin, darkened to 50 %, left 94 "not skin" seeds that
#: GrabCut dropped, and the mesh subject's already at 60 % too few seeds (a bald avatar).
#: Session 28 (docs/building.md "A dim picture").
DIM_GAIN = 4.0
#: ...when the light end is below 255 / this (a full exposure reaches ~255)...
DIM_GAIN_MIN = 1.25
#: ...measured at this percentile of the pixels' brightest channel (a few specular pixels,
#: a lamp's, are not the exposure)
DIM_PERCENTILE = 99.0


def _colour_bins(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 -> (H, W) int: each pixel's colour bin (`WALL_BIN` levels a side)."""
    n = 256 // WALL_BIN
    q = (img // WALL_BIN).astype(np.intp)
    return (q[..., 0] * n + q[..., 1]) * n + q[..., 2]


def _wall_coloured(img: np.ndarray, flat: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels whose colour bin is, or touches (26-neighbourhood), a bin that
    holds at least `WALL_MIN_SHARE` of the `wall` zone's pixels (the zone GrabCut starts as
    background) as `flat` pixels. A 64^3 table of bins, dilated once;
    `_wall_coloured_reference` is the rule pixel by pixel."""
    from scipy import ndimage

    n = 256 // WALL_BIN
    key = _colour_bins(img)
    counts = np.bincount(key[flat & wall], minlength=n**3)
    table = counts >= max(1.0, WALL_MIN_SHARE * wall.sum())
    if not table.any():
        return np.zeros(img.shape[:2], bool)
    table = ndimage.binary_dilation(table.reshape(n, n, n), np.ones((3, 3, 3), bool)).ravel()
    return table[key]


def _wall_coloured_reference(img: np.ndarray, flat: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """`_wall_coloured` the obvious way: every pixel's bin against every wall bin with enough
    flat wall pixels (Chebyshev distance in bins at most 1)."""
    q = np.asarray(img, np.intp) // WALL_BIN
    bins, counts = np.unique(q[flat & wall], axis=0, return_counts=True)  # (K, 3), (K,)
    out = np.zeros(img.shape[:2], bool)
    for b, c in zip(bins, counts):
        if c >= max(1.0, WALL_MIN_SHARE * wall.sum()):
            out |= np.abs(q - b).max(axis=2) <= 1
    return out


def _flat_pixels(img: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose 3x3 neighbourhood holds one colour."""
    import cv2

    k = np.ones((3, 3), np.uint8)
    return (cv2.dilate(img, k) - cv2.erode(img, k)).max(axis=2) == 0


def _renoise_flat(img: np.ndarray, wall: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8: `img` with a fixed pattern of Gaussian noise (`FLAT_NOISE`) added to
    its flat pixels (3x3 neighbourhood of one colour) that are light (every channel at least
    `FLAT_LIGHT`) or, given the `wall` zone (H, W) bool and with `RENOISE_DARK_WALL` on, of
    a colour the wall's dark flat pixels have (`_wall_coloured`).

    A camera's noise never leaves a pixel's neighbourhood exactly one colour; clipping (a
    blown-out white wall), JPEG's quantisation of a plain wall (it drops the noise), video
    codecs and synthetic renders do. Such a wall gives GrabCut's background mixture a component
    of almost no spread (OpenCV adds only 0.01 to its diagonal), under which the wall's own
    pixels a few levels off (JPEG ringing and 8x8 blocks near the person, chroma subsampling,
    the edge's mixed pixels) are far less likely than under the person's broad components:
    GrabCut then kept most of the probable-person zone (head ellipse, torso) of wall as
    person. Noise in the flat pixels gives the component a camera's spread and leaves every
    other pixel as it was (noise everywhere made dark hair on a dark wall fall to the
    background).

    Dark flat pixels: session 8 left them alone (re-noised, the sample composited onto black
    once lost an 8 px notch of dark hair), so a flat dark wall kept its halo: 8-9 px of wall
    in the person on a JPEG near-black or dark grey wall, and on a dark video frame the halo
    became the hair label while the real (blonde) hair became skin. Now the dark ones are
    re-noised where their colour is the wall's: all of the wall's flat pixels, the ones
    inside the probable-person zones too (re-noising only the wall zone left the flat wall
    inside the head ellipse to the person's mixture as a zero-spread component of its own,
    and GrabCut took the whole frame as person), and no dark flat pixel of another colour (a
    black jumper, flat dark hair on a light wall keep their values, so light walls are
    segmented as before)."""
    flat = _flat_pixels(img)
    pick = img.min(axis=2) >= FLAT_LIGHT
    if wall is not None and RENOISE_DARK_WALL:
        # the table from the dark flat pixels only: a light wall near FLAT_LIGHT (the grey
        # clip's) must not pull its few darker flat pixels in
        pick |= _wall_coloured(img, flat & ~pick, wall)
    flat &= pick
    if not flat.any():
        return img
    noise = np.random.default_rng(0).normal(0.0, FLAT_NOISE, img.shape)
    return np.clip(img + np.where(flat[..., None], noise, 0.0), 0, 255).astype(np.uint8)


def _person(img: np.ndarray, reg: dict[str, np.ndarray], iterations: int, iod: float, boundary: bool = True,
            plate=None) -> np.ndarray:
    """(H, W) bool: step 1's person. plate: a video's wall plate (`segment_portrait`)."""
    import cv2
    from scipy import ndimage

    from avatarkit.recon.boundary import refine_person

    sure = reg["face_core"] | reg["neck"]
    # the pixels that show the video's wall where its plate is well known (`PLATE_SURE`): sure
    # background, in the probable-person zones too (clutter touching the head)
    walled = plate.matches(img) & ~sure if (plate is not None and PLATE_SURE) else np.zeros(img.shape[:2], bool)
    r = int(round(PLATE_OPEN * iod))
    if r > 0 and walled.any():
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
        walled = cv2.morphologyEx(walled.astype(np.uint8), cv2.MORPH_OPEN, disc).astype(bool)
    gc = np.full(img.shape[:2], cv2.GC_PR_BGD, np.uint8)
    gc[reg["head_zone"] | reg["torso"]] = cv2.GC_PR_FGD
    gc[reg["far"]] = cv2.GC_BGD
    gc[sure] = cv2.GC_FGD
    bg_share = np.isin(gc, (cv2.GC_BGD, cv2.GC_PR_BGD)).mean()
    if bg_share < 0.02:  # the head fills the picture: nothing to learn a background from
        return np.ones(img.shape[:2], bool)
    wall = ~(reg["head_zone"] | reg["torso"])
    person = _grabcut(_renoise_flat(img, wall) if boundary else img, gc, iterations)
    taken = WALL_TAKEN
    if boundary and RENOISE_DARK_WALL and taken is not None and wall.any() and person[wall].mean() >= taken:
        # the re-noised dark wall took the frame (`WALL_TAKEN`): the light flat pixels alone
        again = _grabcut(_renoise_flat(img), gc, iterations)
        if again[wall].mean() < person[wall].mean():
            person = again
    if walled.any() and person[walled].mean() >= PLATE_TAKEN:
        # the person holds the wall the plate shows (`PLATE_TAKEN`): again, that wall sure background
        gc[walled & (gc != cv2.GC_FGD)] = cv2.GC_BGD
        wall |= walled
        cv2.setRNGSeed(0)  # the run a plate-first segmentation would make (`_working_copy`)
        person = _grabcut(_renoise_flat(img, wall) if boundary else img, gc, iterations)
    else:
        walled = np.zeros_like(walled)
    person = _keep_touching(person, sure) | sure
    # (the wall the plate shows stays out: filling holes would take a gap between strands back)
    person = ndimage.binary_fill_holes(person) & ~walled
    if not boundary:
        return _keep_touching(person, sure) | sure
    # the outline's mixed pixels and what is left of a wall's halo: peel them from the outside
    person = refine_person(img, person, boundary_band(iod), keep=sure)
    return _keep_touching(person, sure) | sure


def _hair_grabcut(img, lab, person, reg, skin, hair, seeds, iterations, iod, skin_d2=None) -> np.ndarray:
    """skin_d2: skin.distance2(lab) when the caller has it (an image-sized Mahalanobis pass
    saved twice)."""
    import cv2

    skin_d2 = skin.distance2(lab) if skin_d2 is None else skin_d2
    # Work only inside the box around the person's hair zone: GrabCut cost scales with its area.
    ys, xs = np.nonzero(reg["hair_zone"] & person)
    if len(ys) == 0:
        return np.zeros(person.shape, bool)
    pad = int(0.2 * iod) + 2
    y0, y1 = max(0, ys.min() - pad), min(person.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(person.shape[1], xs.max() + pad + 1)
    win = (slice(y0, y1), slice(x0, x1))

    sub = img[win].copy()
    sub[~person[win]] = skin.rgb
    hairlike = hair.log_likelihood(lab) > skin.log_likelihood(lab, skin_d2)
    gc = np.full(sub.shape[:2], cv2.GC_PR_BGD, np.uint8)
    gc[person[win] & reg["hair_zone"][win] & hairlike[win]] = cv2.GC_PR_FGD
    gc[seeds[win]] = cv2.GC_FGD
    gc[~person[win] | reg["face_core"][win]] = cv2.GC_BGD
    fg = np.zeros(person.shape, bool)
    fg[win] = _grabcut(sub, gc, iterations)
    fg &= person & ~reg["face_core"] & reg["hair_zone"]

    fg = _keep_touching(fg, seeds)
    # GrabCut's cut sits a pixel or two inside soft hair edges (the hairline, flyaways): take
    # the adjacent person pixels that are hair-like and clearly not skin.
    r = max(1, round(0.05 * iod))
    near = cv2.dilate(fg.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)).astype(bool)
    fg |= near & person & ~reg["face_core"] & hairlike & (skin_d2 > MATCH_D2)
    min_area = max(4, int(0.02 * iod * iod))
    fg = _drop_small(fg, min_area)
    fg |= ~_drop_small(~fg, int(0.15 * iod * iod))  # fill small holes
    return fg & person & ~reg["face_core"]


def _load_hair_mask(hair_mask, shape, path) -> np.ndarray:
    from avatarkit.recon.image_io import fit_mask, read_mask

    if isinstance(hair_mask, (str, os.PathLike)):
        return read_mask(hair_mask, shape)
    try:
        arr = np.asarray(hair_mask)
    except Exception as e:  # noqa: BLE001 - anything array-like may fail in its own way
        raise InputError(f"hair mask is not an array: {e}", path) from None
    return fit_mask(arr, shape, path)


def _checked_image(image, analysis: PortraitAnalysis, path=None) -> np.ndarray:
    """`image` as a (H, W, 3) uint8 array the size `analysis` was made on, else InputError."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must be (H, W, 3) uint8 RGB, got {image.dtype} {image.shape}", path)
    H, W = image.shape[:2]
    if tuple(analysis.image_size) != (W, H):
        raise InputError(f"the analysis was made on a {analysis.image_size[0]}x{analysis.image_size[1]} image, "
                         f"this one is {W}x{H}", path)
    return image


def _working_copy(image: np.ndarray, analysis: PortraitAnalysis, work_size: int):
    """(the image GrabCut runs on: longer side at most `work_size`, its analysis, the scale k)."""
    import cv2

    # GrabCut's k-means draws from OpenCV's thread-global RNG: without a reset each
    # segmentation starts where the last one left it, so a second build in one process (or a
    # video build's keyframes) segments differently. Seed 0 is the RNG's fresh state
    # (0xffffffff): a process's first segmentation is unchanged.
    cv2.setRNGSeed(0)
    H, W = image.shape[:2]
    k = min(1.0, work_size / max(H, W))
    if k < 1.0:
        img = cv2.resize(image, (max(1, round(W * k)), max(1, round(H * k))), interpolation=cv2.INTER_AREA)
        return img, analysis.scaled(k), k
    return image, analysis, k


def _skin_pixels(reg: dict[str, np.ndarray], person: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels the skin model is fitted to (the cheeks and nose, or the face core)."""
    skin_px = reg["skin_sample"] & person
    return skin_px if skin_px.sum() >= 10 else reg["face_core"]


def _person_and_hair(img, lab, reg, iterations, iod, boundary, plate, find_hair: bool):
    """Steps 1-4 on `img` (H, W, 3) uint8 and its `lab`: (person (H, W) bool, skin model, the
    skin model's distance2 (H, W), hair model or None, hair (H, W) bool)."""
    person = _person(img, reg, iterations, iod, boundary, plate)
    skin = ColourModel.fit(lab[_skin_pixels(reg, person)])
    skin_d2 = skin.distance2(lab)

    hair_model, hair = None, np.zeros(img.shape[:2], bool)
    if find_hair:
        seeds = reg["seed_zone"] & person & (skin_d2 > MATCH_D2) & ~reg["face_core"]
        if seeds.sum() >= max(20, 0.05 * (reg["seed_zone"] & person).sum()):
            hair_model = ColourModel.fit(lab[seeds])
            seeds &= hair_model.distance2(lab) <= MATCH_D2
            hair = _hair_grabcut(img, lab, person, reg, skin, hair_model, seeds, iterations, iod, skin_d2)
            if not hair.any():
                hair_model = None
    return person, skin, skin_d2, hair_model, hair


def exposure_gain(img: np.ndarray) -> float:
    """The gain that brings `img`'s (H, W, 3) uint8 light end (the `DIM_PERCENTILE` of each
    pixel's brightest channel) to 255: 1.0 for a picture already there, 255 for a black one."""
    top = float(np.percentile(np.asarray(img).max(axis=2), DIM_PERCENTILE))
    return 255.0 / max(top, 1.0)


def segment_portrait(image: np.ndarray, analysis: PortraitAnalysis, hair_mask=None, *,
                     work_size: int | None = None, iterations: int = 3, boundary: bool = True,
                     path: str | os.PathLike | None = None, plate=None) -> Segmentation:
    """Label every pixel of a portrait as background, skin/face, hair or body.

    image: (H, W, 3) uint8 RGB, the image `analysis` was made on.
    hair_mask: optional (h, w) array or image path; any non-zero pixel is hair. Resized to the
        image if the aspect ratio matches, else FormatError. It replaces the built-in hair label.
    work_size: GrabCut runs on a copy whose longer side is at most this many pixels.
    iterations: GrabCut iterations per cut (3 is enough on portraits; 5 is OpenCV's usual).
    boundary: False gives GrabCut's own person outline on the image as it is (no re-noised
        flat pixels, no boundary step): the behaviour before them, the benchmark's baseline.
    plate: the wall plate (`track.background_plate.Plate`) of the video `image` is a frame of,
        or None: a pixel matching it where it is well known is sure background (`PLATE_SURE`).
    """
    work_size = WORK_SIZE if work_size is None else work_size
    image = _checked_image(image, analysis, path)
    H, W = image.shape[:2]
    imported = _load_hair_mask(hair_mask, (H, W), path) if hair_mask is not None else None
    img, a, k = _working_copy(image, analysis, work_size)
    iod = a.eye_distance
    u, v = a.face_grid(img.shape[:2])
    reg = face_regions(u, v)
    lab = rgb_to_lab(img)

    person, skin, skin_d2, hair_model, hair = _person_and_hair(img, lab, reg, iterations, iod, boundary, plate,
                                                               imported is None)
    retry = imported is None and hair_model is None and DIM_GAIN is not None
    gain = min(DIM_GAIN, exposure_gain(img)) if retry else 1.0
    if gain >= DIM_GAIN_MIN:
        # a dim picture that gave no hair (`DIM_GAIN`): again on it brightened to a full
        # exposure; its labels kept when that finds hair, the models refitted to the real colours
        bright = np.clip(np.round(img.astype(np.float32) * gain), 0, 255).astype(np.uint8)
        import cv2

        cv2.setRNGSeed(0)  # GrabCut's RNG as a bright picture's segmentation starts it (`_working_copy`)
        b_lab = rgb_to_lab(bright)
        # (no plate: it holds the wall's real colours, which the brightened wall does not match)
        b_person, _, b_d2, b_model, b_hair = _person_and_hair(bright, b_lab, reg, iterations, iod, boundary,
                                                              None, True)
        if b_model is not None:
            person, hair, skin_d2 = b_person, b_hair, b_d2
            skin = ColourModel.fit(lab[_skin_pixels(reg, person)])
            hair_model = ColourModel.fit(lab[hair])

    chin = FACE_PROPORTIONS["chin"][1]
    labels = np.zeros(img.shape[:2], np.uint8)
    labels[person] = BODY
    # Skin: the head (ears, shaded jaw: loosely skin-coloured) and skin-coloured neck/chest.
    neck_zone = (np.abs(u) < 0.6) & (v < chin + 1.2)  # necks are shaded: loose colour test
    loose = (reg["head"] | neck_zone) & (skin_d2 <= 4 * MATCH_D2)
    labels[person & (loose | ((skin_d2 <= MATCH_D2) & (v > 0.5) & (v < chin + 1.5)))] = SKIN
    labels[reg["face_core"]] = SKIN
    labels[hair] = HAIR

    if k < 1.0:
        labels = _upsample_labels(labels, (W, H))
    source = "grabcut" if hair_model is not None else "none"
    if imported is not None:
        labels, hair_model = _apply_hair_mask(image, labels, imported, skin, analysis)
        source = "imported"
    return Segmentation(labels=labels, skin_model=skin, hair_model=hair_model, hair_source=source)


def segment_person(image: np.ndarray, analysis: PortraitAnalysis, *, work_size: int | None = None,
                   iterations: int = 3, plate=None) -> np.ndarray:
    """(H, W) bool: the person of `segment_portrait` (its labels other than background) without
    the skin and hair models and the hair's GrabCut, which it does not need (step 1 and the face
    core, upsampled as the labels are). For a caller that wants only the silhouette
    (`track.frame_hull`)."""
    work_size = WORK_SIZE if work_size is None else work_size
    image = _checked_image(image, analysis)
    H, W = image.shape[:2]
    img, a, k = _working_copy(image, analysis, work_size)
    u, v = a.face_grid(img.shape[:2])
    reg = face_regions(u, v)
    person = _person(img, reg, iterations, a.eye_distance, True, plate) | reg["face_core"]
    if k < 1.0:
        person = _upsample_labels(person.astype(np.uint8), (W, H)) != BACKGROUND
    return person


def _upsample_labels(labels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Smooth label upsampling: bilinear one-hot maps, then argmax (no blocky edges)."""
    import cv2

    onehot = np.stack([(labels == c).astype(np.float32) for c in range(4)], axis=2)
    up = cv2.resize(onehot, size, interpolation=cv2.INTER_LINEAR)
    return np.argmax(up, axis=2).astype(np.uint8)


def _apply_hair_mask(image, labels, mask, skin: ColourModel, analysis: PortraitAnalysis):
    """Imported hair wins; pixels the built-in method called hair but the mask does not become
    skin if skin-coloured, body below the chin, background otherwise."""
    labels = labels.copy()
    former = (labels == HAIR) & ~mask
    if former.any():
        lab = rgb_to_lab(image[former])
        centres = np.stack(np.nonzero(former)[::-1], axis=1) + 0.5  # pixel centres, (x, y)
        _, v = analysis.to_face(centres).T
        repl = np.where(skin.distance2(lab) <= MATCH_D2, SKIN,
                        np.where(v > FACE_PROPORTIONS["chin"][1], BODY, BACKGROUND))
        labels[former] = repl.astype(np.uint8)
    labels[mask] = HAIR
    hair_model = ColourModel.fit(rgb_to_lab(image[mask])) if mask.sum() >= 4 else None
    return labels, hair_model
