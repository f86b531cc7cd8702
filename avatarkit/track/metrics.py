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
share of constant background in the frame.
"""
from __future__ import annotations

import numpy as np

ALPHA_THRESHOLD = 0.5
#: SSIM settings of Wang et al. 2004 (skimage's defaults use a 7x7 uniform window instead)
SSIM_SETTINGS = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0}


def person_mask(alpha: np.ndarray, threshold: float = ALPHA_THRESHOLD) -> np.ndarray:
    """(H, W) bool: where the render's alpha (H, W) (or (H, W, 1)) exceeds `threshold`."""
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


def error_heat_map(a: np.ndarray, b: np.ndarray, mask: np.ndarray, full_scale: float = 0.25) -> np.ndarray:
    """(H, W, 3) uint8 colour map (inferno) of the mean absolute difference per pixel inside
    `mask` (black outside); `full_scale` (in [0, 1] units) maps to the brightest colour."""
    import cv2

    err = np.abs(to_float(a) - to_float(b)).mean(axis=2)
    err = np.where(np.asarray(mask, bool), err, 0.0)
    level = np.clip(err / full_scale * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)[..., ::-1].copy()
    rgb[~np.asarray(mask, bool)] = 0      # inferno's zero is not quite black
    return rgb
