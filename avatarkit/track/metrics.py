"""Image and landmark metrics of the self-reenactment evaluation (`track.evaluate`).

Person region. Both images are compared on one mask, the same for both: the pixels where our
render's alpha exceeds `ALPHA_THRESHOLD` (head, hair and neck: what the avatar models). Outside
it both images are set to one constant background colour (`composite`), so the video's room
and the avatar's missing torso do not count. Why the render's alpha and not a segmentation of
the video frame: a person mask of the video holds the shoulders and clothes, which the avatar
does not model (every avatar would lose there by the same large amount), and the project's
segmentation (`recon.segment`, GrabCut seeded from the face) costs ~1 s per frame, which a
250-frame clip cannot afford. The price: video pixels of the head that our render misses
(hair drawn too small) are not counted; the mask's share of the frame is reported per frame
so that shrinking avatars show up.

PSNR is 10 log10(1 / MSE) with the MSE over the mask's pixels and the three channels (values
in [0, 1]). SSIM is the Gaussian-window SSIM of Wang et al. 2004 (sigma 1.5, population
covariances: `skimage.metrics.structural_similarity` with those settings) computed on the
composited full images, its map averaged over the mask's pixels (and over channels). The
full-frame figures (`psnr_full`, `ssim_full`: the composited images compared whole, as the
papers' tables do after removing the background) are reported beside them; they rise with the
share of constant background in the frame. `evaluate` computes all four on the mask's bounding
box (`region_metrics`, with `ssim_map_fast`, an OpenCV twin of skimage's SSIM): the same
numbers as `masked_psnr` and `ssim_map` on the whole frames, which stay as the references.
"""
from __future__ import annotations

import numpy as np

ALPHA_THRESHOLD = 0.5
#: SSIM settings of Wang et al. 2004 (skimage's defaults use a 7x7 uniform window instead)
SSIM_SETTINGS = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0}


def person_mask(alpha: np.ndarray, threshold: float | None = None) -> np.ndarray:
    """(H, W) bool: where the render's alpha (H, W) (or (H, W, 1)) exceeds `threshold`."""
    threshold = ALPHA_THRESHOLD if threshold is None else threshold
    a = np.asarray(alpha, np.float64)
    if a.ndim == 3:
        a = a[..., 0]
    return a > threshold


def to_float(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 or float in [0, 1] -> float64 in [0, 1]."""
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    return np.clip(a.astype(np.float64), 0.0, 1.0)


def composite(image: np.ndarray, mask: np.ndarray, background) -> np.ndarray:
    """(H, W, 3) float64: `image` inside `mask` (H, W), the colour `background` (3,) outside."""
    out = to_float(image).copy()
    out[~np.asarray(mask, bool)] = np.asarray(background, np.float64).reshape(3)
    return out


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR in dB of images a, b (H, W, 3) over the pixels of `mask` (H, W); inf when they
    agree there exactly, NaN when the mask is empty."""
    m = np.asarray(mask, bool)
    if not m.any():
        return float("nan")
    mse = float(np.mean((to_float(a)[m] - to_float(b)[m]) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(1.0 / mse))


def ssim_map(a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """(whole-image SSIM as skimage reports it, (H, W) map averaged over channels)."""
    from skimage.metrics import structural_similarity

    value, full = structural_similarity(to_float(a), to_float(b), channel_axis=2, full=True,
                                        **SSIM_SETTINGS)
    return float(value), full.mean(axis=2)


#: radius in pixels of skimage's Gaussian window at SSIM_SETTINGS (truncate 3.5 x sigma, rounded)
SSIM_RADIUS = int(3.5 * SSIM_SETTINGS["sigma"] + 0.5)


def mask_box(mask: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    """(rows, cols) slices of the bounding box of `mask` (H, W) grown by `margin` pixels and
    clipped to the image; None when the mask is empty."""
    m = np.asarray(mask, bool)
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    if not len(rows):
        return None
    h, w = m.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + 1 + margin, h)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + 1 + margin, w)))


def region_metrics(a: np.ndarray, b: np.ndarray, mask: np.ndarray, background=None) -> dict:
    """psnr / ssim over `mask` and psnr_full / ssim_full over the whole frame of two composited
    images a, b (H, W, 3) that are equal outside `mask` (both the background there), computed
    on the mask's bounding box only with `ssim_map_fast`: the same numbers as `masked_psnr` /
    `ssim_map` on the whole frames (to float rounding; tests compare them), at a fraction of
    the cost. background: when given (3,), a and b are the images before compositing (uint8
    or float) and are composited onto it inside the box only: the same numbers again, without
    converting and copying the whole frames.

    Why it is exact: outside the mask the squared error is 0, and SSIM's map is 1 wherever the
    Gaussian window (radius `SSIM_RADIUS`) sees only equal pixels. The box is grown by twice
    that radius, so every pixel whose window reaches the mask lies at least a radius inside
    the box (or at the image border, where the box's border is the image's), and its value on
    the box equals its value on the whole frame; the rest of the frame contributes 1 each.
    """
    m = np.asarray(mask, bool)
    h, w = m.shape
    box = mask_box(m, 2 * SSIM_RADIUS)
    if box is None:
        return {"psnr": float("nan"), "ssim": float("nan"), "psnr_full": float("inf"), "ssim_full": 1.0}
    mb = m[box]
    if background is None:
        fa, fb = to_float(a[box]), to_float(b[box])
    else:
        fa, fb = composite(a[box], mb, background), composite(b[box], mb, background)
    sq = (fa - fb) ** 2                                         # (h', w', 3), 0 outside the mask
    mse_mask = float(sq[mb].mean())
    mse_full = float(sq.sum()) / (h * w * 3)
    out = {"psnr": float("inf") if mse_mask == 0 else float(10.0 * np.log10(1.0 / mse_mask)),
           "psnr_full": float("inf") if mse_full == 0 else float(10.0 * np.log10(1.0 / mse_full))}
    win = 2 * SSIM_RADIUS + 1
    if min(fa.shape[:2]) < win:         # a box narrower than the window: only on tiny frames
        if background is not None:
            a, b = composite(a, m, background), composite(b, m, background)
        ssim_full, smap = ssim_map_fast(a, b)
        out.update(ssim=float(smap[m].mean()), ssim_full=ssim_full)
        return out
    _, s = _ssim_float(fa, fb)          # (h', w') map on the box, averaged over channels
    out["ssim"] = float(s[mb].mean())
    # skimage's whole-image value: the mean over the frame less a border of the window's radius
    r = SSIM_RADIUS
    inner = np.zeros((h, w), bool)
    inner[r:h - r, r:w - r] = True
    inner_box = inner[box]
    n_inner = int(inner.sum())
    n_rest = n_inner - int(inner_box.sum())
    out["ssim_full"] = float((s[inner_box].sum() + n_rest) / n_inner)
    return out


def ssim_map_fast(a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:
    """`ssim_map` with OpenCV's separable filter instead of scipy's: the same Gaussian taps
    (radius `SSIM_RADIUS`, normalised as scipy does), the same mirrored border (scipy's
    'reflect' is OpenCV's BORDER_REFLECT) and the same formula as skimage's, all three channels
    per call; equal to `ssim_map` to float rounding (tests compare them), ~8x faster."""
    return _ssim_float(to_float(a), to_float(b))


def _ssim_float(fa: np.ndarray, fb: np.ndarray) -> tuple[float, np.ndarray]:
    """`ssim_map_fast` of float64 images already in [0, 1]."""
    import cv2

    r = SSIM_RADIUS
    x = np.arange(-r, r + 1, dtype=np.float64)
    taps = np.exp(-0.5 * (x / SSIM_SETTINGS["sigma"]) ** 2)
    taps /= taps.sum()

    def blur(img):
        return cv2.sepFilter2D(img, cv2.CV_64F, taps, taps, borderType=cv2.BORDER_REFLECT)

    ux, uy = blur(fa), blur(fb)
    vx = blur(fa * fa) - ux * ux
    vy = blur(fb * fb) - uy * uy
    vxy = blur(fa * fb) - ux * uy
    c1 = (0.01 * SSIM_SETTINGS["data_range"]) ** 2
    c2 = (0.03 * SSIM_SETTINGS["data_range"]) ** 2
    num = 2 * ux * uy
    num += c1
    num *= 2 * vxy + c2
    den = ux * ux
    den += uy * uy
    den += c1
    vx += vy
    vx += c2
    den *= vx
    s = np.divide(num, den, out=num)
    h, w = s.shape[:2]
    return float(s[r:h - r, r:w - r].mean(axis=(0, 1)).mean()), s.mean(axis=2)


def masked_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """SSIM of a, b (H, W, 3) averaged over the pixels of `mask` (H, W); NaN when empty."""
    m = np.asarray(mask, bool)
    if not m.any():
        return float("nan")
    return float(ssim_map(a, b)[1][m].mean())


def interocular(landmarks: np.ndarray) -> float:
    """Distance in pixels between the two eye centres of a face mesh (468, 2): the mean of the
    eye-corner pairs (MediaPipe indices 33/133 and 362/263)."""
    p = np.asarray(landmarks, np.float64)
    left = (p[33] + p[133]) / 2
    right = (p[362] + p[263]) / 2
    return float(np.linalg.norm(left - right))


def landmark_error(ours: np.ndarray | None, theirs: np.ndarray | None) -> float:
    """Median pixel distance between two face meshes (468, 2) of the same frame; NaN when
    either is missing (no face found)."""
    if ours is None or theirs is None:
        return float("nan")
    a, b = np.asarray(ours, np.float64)[:, :2], np.asarray(theirs, np.float64)[:, :2]
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return float("nan")
    return float(np.median(np.linalg.norm(a - b, axis=1)))


def error_heat_map(a: np.ndarray, b: np.ndarray, mask: np.ndarray, full_scale: float = 0.25,
                   margin: int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 colour map (inferno) of the mean absolute difference per pixel inside
    `mask` (black outside); `full_scale` (in [0, 1] units) maps to the brightest colour.
    margin: colour only the mask's bounding box grown by this many pixels (the rest is black
    anyway): the same image for less work."""
    if margin is not None:
        out = np.zeros(np.shape(a)[:2] + (3,), np.uint8)
        box = mask_box(np.asarray(mask, bool), margin)
        if box is not None:
            out[box] = error_heat_map(a[box], b[box], np.asarray(mask, bool)[box], full_scale)
        return out
    import cv2

    err = np.abs(to_float(a) - to_float(b)).mean(axis=2)
    err = np.where(np.asarray(mask, bool), err, 0.0)
    level = np.clip(err / full_scale * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)[..., ::-1].copy()
    rgb[~np.asarray(mask, bool)] = 0      # inferno's zero is not quite black
    return rgb
