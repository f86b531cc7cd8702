"""Reading an image at projected points: bilinear colour samples and nearest-pixel lookups."""
from __future__ import annotations

import numpy as np


def sample_image(image: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Bilinear samples (N, C) float32 of an (H, W, C) image at continuous pixel coordinates
    (N, 2) (pixel i's centre at i + 0.5); outside the image the border is repeated."""
    import cv2

    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = img[:, :, None]
    p = np.asarray(px, np.float32).reshape(-1, 2) - 0.5
    p = np.nan_to_num(p, nan=-1e6)
    out = np.empty((len(p), img.shape[2]), np.float32)
    chunk = 1 << 14  # cv2.remap's maps must stay below 32767 in each dimension
    for s in range(0, len(p), chunk):
        q = p[s:s + chunk]
        out[s:s + chunk] = cv2.remap(img, q[:, 0][None], q[:, 1][None], cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE).reshape(len(q), -1)
    return out


def lookup(mask: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of an (H, W) array at pixel coordinates (N, 2); False/0 outside."""
    h, w = mask.shape[:2]
    p = np.nan_to_num(np.asarray(px, np.float64), nan=-1.0)
    xi = np.floor(p[:, 0]).astype(np.int64)
    yi = np.floor(p[:, 1]).astype(np.int64)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    out = np.zeros(len(p), dtype=mask.dtype)
    out[ok] = mask[yi[ok], xi[ok]]
    return out


__all__ = ["lookup", "sample_image"]
