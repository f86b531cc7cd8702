"""The 2D bald filter (paper section 3.2): remove the hair, fill the scalp with plausible skin.

Hair pixels are split in two:
- the *scalp*: hair inside the head region (plus the blended skin pixels along the hairline) (by default an ellipse in the eye frame reaching the
  skull top, `FACE_PROPORTIONS`; the fitted head's projected scalp when `scalp_hint` is given).
  Filled with skin: the face's skin colour (Lab mean of the skin model) with a smooth
  lightness falloff toward the head outline fitted to the face's own shading, plus a harmonic
  (Laplace) correction that matches the real pixels at the hairline, so the seam is invisible;
- everything else: hair against the background, grown by a couple of pixels into the background
  to take the hair's anti-aliased fringe with it. Filled with a harmonic membrane from the
  surrounding background pixels only (face, body and scalp do not bleed into it).
Pixels outside the filled mask are returned unchanged, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.recon.fill import harmonic_fill_fast
from avatarkit.recon.portrait import FACE_PROPORTIONS, PortraitAnalysis
from avatarkit.recon.segment import BACKGROUND, HAIR, SKIN, Segmentation, face_regions, lab_to_rgb, rgb_to_lab
from avatarkit.recon import segment as _segment  # its switches read at call time


@dataclass(eq=False)
class BaldResult:
    image: np.ndarray        # (H, W, 3) uint8: the bald portrait
    scalp_mask: np.ndarray   # (H, W) bool: pixels filled with skin (scalp hair + the hairline's blend pixels)
    filled_mask: np.ndarray  # (H, W) bool: every pixel that changed (scalp + background fill)
    labels: np.ndarray       # (H, W) uint8: the segmentation relabelled (scalp -> skin, rest -> background)


def head_region(analysis: PortraitAnalysis, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool ellipse covering the bald head (skull top to chin, temple to temple)."""
    u, v = analysis.face_grid(shape)
    return _head_ellipse_r2(u, v) <= 1.0


def _head_ellipse_r2(u, v):
    au = FACE_PROPORTIONS["head_half_width"][0]
    top, chin = FACE_PROPORTIONS["skull_top"][1], FACE_PROPORTIONS["chin"][1]
    cv, av = 0.5 * (top + chin), 0.5 * (chin - top)
    return (u / au) ** 2 + ((v - cv) / av) ** 2


def _shading(image, labels, skin_model, u, v) -> tuple[float, float, float, float]:
    """Lightness model of the face: L = a + b n_z, clamped to [lo, hi]; returns (a, b, lo, hi).

    n_z is the view-facing component of the head ellipsoid's normal; fitted on the face's
    skin-coloured pixels, so the filled scalp darkens toward the outline the way this face does."""
    sample = (labels == SKIN) & face_regions(u, v)["face_core"]
    lab = rgb_to_lab(image[sample])
    keep = skin_model.distance2(lab) <= _segment.MATCH_D2  # no eyes, brows, lips
    lum = lab[keep, 0].astype(np.float64)
    nz = _facing(u[sample][keep], v[sample][keep])
    mean_l = float(skin_model.mean[0])
    if len(lum) < 20:
        return mean_l, 0.0, mean_l, mean_l
    a, b = float(np.mean(lum)), 0.0
    if np.ptp(nz) > 0.05:
        design = np.stack([np.ones(len(lum)), nz], axis=1)
        (_, b), *_ = np.linalg.lstsq(design, lum, rcond=None)
        b = float(np.clip(b, 0.0, 40.0))  # brighter toward the centre, never inverted
        a = float(np.mean(lum) - b * np.mean(nz))
    # Never darker or lighter than this face's own skin: the fit only interpolates shading.
    lo, hi = np.percentile(lum, [5, 95])
    return a, b, float(lo), float(hi)


def _facing(u, v):
    return np.sqrt(np.clip(1.0 - _head_ellipse_r2(u, v), 0.0, 1.0))


def make_bald_image(image: np.ndarray, segmentation: Segmentation, analysis: PortraitAnalysis,
                    scalp_hint: np.ndarray | None = None, *, grow: int | None = None,
                    work_size: int = 384) -> BaldResult:
    """Remove the hair from a portrait.

    image: (H, W, 3) uint8 RGB; segmentation and analysis made on it.
    scalp_hint: optional (H, W) mask (any non-zero = head) of where the bald head is, e.g. the
        fitted head mesh's projection; default: the head ellipse (`head_region`).
    grow: pixels the hair is grown before filling, to take its soft, blended edge along: into the
        background around the hair and into the skin along the scalp's hairline. Default 5% of
        the inter-ocular distance, at least 2. 0 changes exactly the hair pixels.
    work_size: the fills are solved on a copy at most this large, then refined at full resolution
        along their borders (see `harmonic_fill_fast`).
    """
    import cv2

    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must be (H, W, 3) uint8 RGB, got {image.dtype} {image.shape}")
    H, W = image.shape[:2]
    labels = segmentation.labels
    if labels.shape != (H, W):
        raise InputError(f"segmentation is {labels.shape[1]}x{labels.shape[0]} but the image is {W}x{H}")
    if tuple(analysis.image_size) != (W, H):
        raise InputError(f"the analysis was made on a {analysis.image_size[0]}x{analysis.image_size[1]} "
                         f"image, this one is {W}x{H}")
    u, v = analysis.face_grid((H, W))
    if scalp_hint is not None:
        hint = np.asarray(scalp_hint)
        if hint.shape[:2] != (H, W):
            raise InputError(f"scalp hint is {hint.shape[1] if hint.ndim > 1 else '?'}x{hint.shape[0]} "
                             f"but the image is {W}x{H}")
        head = hint.reshape(H, W, -1).any(axis=2)
    else:
        head = _head_ellipse_r2(u, v) <= 1.0

    hair = labels == HAIR
    if not hair.any():
        empty = np.zeros((H, W), bool)
        return BaldResult(image=image.copy(), scalp_mask=empty, filled_mask=empty.copy(), labels=labels.copy())
    if grow is None:
        grow = max(2, round(0.05 * analysis.eye_distance))
    shading = _shading(image, labels, segmentation.skin_model, u, v)

    # Everything below happens in the window around the grown hair (plus a pixel of boundary).
    ys, xs = np.nonzero(hair)
    pad = grow + 2
    win = (slice(max(0, ys.min() - pad), min(H, ys.max() + pad + 1)),
           slice(max(0, xs.min() - pad), min(W, xs.max() + pad + 1)))
    img8, lbl, hair_w, u_w, v_w = image[win], labels[win], hair[win], u[win], v[win]

    scalp = hair_w & head[win]
    fringe = np.zeros(lbl.shape, bool)
    if grow > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
        fringe = cv2.dilate(hair_w.astype(np.uint8), k).astype(bool) & (lbl == BACKGROUND)
        # The skin pixels along the hairline are a blend of hair and skin: refill them too, or
        # the harmonic correction would carry the hair tint up over the whole scalp.
        scalp |= cv2.dilate(scalp.astype(np.uint8), k).astype(bool) & (lbl == SKIN)
    to_background = (hair_w & ~scalp) | fringe

    img = img8.astype(np.float64)
    out = img.copy()
    if to_background.any():
        known = (lbl == BACKGROUND) & ~to_background
        bg = img[known]
        if not len(bg):  # no background in the window: the picture's border stands in for it
            bg = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]]).astype(np.float64)
        filled = harmonic_fill_fast(img, to_background, known, fallback=np.median(bg, axis=0), work_size=work_size)
        out[to_background] = filled[to_background]
    if scalp.any():
        a, b, lo, hi = shading
        target_lab = np.empty(img.shape, np.float32)
        target_lab[:, :, 0] = np.clip(a + b * _facing(u_w, v_w), lo, hi)
        target_lab[:, :, 1:] = segmentation.skin_model.mean[1:]
        target = lab_to_rgb(target_lab).astype(np.float64)
        # Match the real skin at the hairline: harmonic residual from skin-coloured neighbours,
        # zero residual (the pure target) against everything else (background, body, and
        # brows or hair wisps the segmentation left in the face).
        skinlike = segmentation.skin_model.distance2(rgb_to_lab(img8)) <= _segment.MATCH_D2
        residual = np.where(((lbl == SKIN) & skinlike & ~scalp)[:, :, None], img - target, 0.0)
        corr = harmonic_fill_fast(residual, scalp, ~scalp, work_size=work_size)
        out[scalp] = target[scalp] + corr[scalp]

    filled = scalp | to_background
    result = image.copy()
    result[win][filled] = np.clip(np.round(out[filled]), 0, 255).astype(np.uint8)
    new_labels = labels.copy()
    new_labels[win][to_background] = BACKGROUND
    new_labels[win][scalp] = SKIN
    scalp_mask = np.zeros((H, W), bool)
    scalp_mask[win] = scalp
    filled_mask = np.zeros((H, W), bool)
    filled_mask[win] = filled
    return BaldResult(image=result, scalp_mask=scalp_mask, filled_mask=filled_mask, labels=new_labels)
