"""Rotated square regions of an image: cropping them to a model's input and mapping the
model's normalised outputs back to image pixels (MediaPipe's ImageToTensor and
LandmarkProjection calculators).

Pixel coordinates are continuous, x right, y down, pixel (i, j) covering [i, i+1) x [j, j+1)
(its centre at i + 0.5), as in `recon.portrait` and the renderer's cameras. A `Roi` is a
square of side `side` pixels centred at `center`, turned by `angle` radians (positive turns
its x axis toward +y, i.e. clockwise on screen); a point (u, v) in [0, 1]^2 of the region
is at  center + side * R(angle) @ (u - 0.5, v - 0.5)  in the image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Roi:
    """A rotated square region: center (2,) pixels, side pixels, angle radians."""

    center: tuple[float, float]
    side: float
    angle: float

    def rotation(self) -> np.ndarray:
        """(2, 2) R(angle) (y down)."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.array([[c, -s], [s, c]])

    def matrix(self) -> np.ndarray:
        """(3, 3) affine: region-normalised (u, v, 1) -> image pixels."""
        m = np.eye(3)
        m[:2, :2] = self.side * self.rotation()
        m[:2, 2] = np.asarray(self.center, np.float64) - m[:2, :2] @ np.array([0.5, 0.5])
        return m

    def to_image(self, uv: np.ndarray) -> np.ndarray:
        """Region-normalised points (..., 2) -> image pixels (..., 2)."""
        m = self.matrix()
        return np.asarray(uv, np.float64) @ m[:2, :2].T + m[:2, 2]

    def corners(self) -> np.ndarray:
        """(4, 2) image pixels of the region's corners."""
        return self.to_image(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))


def normalize_radians(a: float) -> float:
    """a wrapped to [-pi, pi)."""
    return a - 2 * math.pi * math.floor((a + math.pi) / (2 * math.pi))


def roi_from_points(p0, p1, points: np.ndarray, scale: float) -> Roi:
    """MediaPipe's DetectionsToRects (rotation from keypoint p0 to p1, target angle 0) then
    RectTransformation (scale, square_long): the region centred on the bounding box of
    `points` (K, 2), turned so that p0 -> p1 becomes its x axis, its side `scale` times the
    box's longer side."""
    points = np.asarray(points, np.float64)
    lo, hi = points.min(axis=0), points.max(axis=0)
    angle = normalize_radians(-math.atan2(-(p1[1] - p0[1]), p1[0] - p0[0]))
    return Roi((float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2)),
               float(max(hi - lo) * scale), angle)


def crop(image: np.ndarray, roi: Roi, size: int, border: str = "replicate",
         flip: bool = False) -> np.ndarray:
    """The region resampled to (size, size, C) float32 in the image's value range; `flip`
    mirrors it left-right (u -> 1 - u). Large regions are shrunk with area averaging first so
    the bilinear warp does not alias (a face on a 4K photo)."""
    import cv2

    image = np.asarray(image)
    h, w = image.shape[:2]
    # what part of the image the region touches, and how much it is shrunk
    corners = roi.corners()
    x0, y0 = np.floor(corners.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int) + 1
    x0, y0, x1, y1 = max(0, x0), max(0, y0), min(w, x1), min(h, y1)
    k = size / max(roi.side, 1e-6)
    pre = np.eye(3)           # image pixels -> source pixels (continuous)
    if x1 > x0 and y1 > y0:
        src = image[y0:y1, x0:x1]
        pre[:2, 2] = (-x0, -y0)
        if k < 0.5:
            f = min(1.0, 2.0 * k)
            sw, sh = max(1, round((x1 - x0) * f)), max(1, round((y1 - y0) * f))
            src = cv2.resize(src, (sw, sh), interpolation=cv2.INTER_AREA)
            pre = np.diag([sw / (x1 - x0), sh / (y1 - y0), 1.0]) @ pre
    else:  # the region lies outside the image: all border
        src = np.zeros((1, 1) + image.shape[2:], image.dtype)
        if border == "replicate":
            src[:] = image[min(max(int(roi.center[1]), 0), h - 1), min(max(int(roi.center[0]), 0), w - 1)]
    # output pixel index -> output continuous -> region-normalised -> image -> source index
    out = np.array([[1.0 / size, 0, 0.5 / size], [0, 1.0 / size, 0.5 / size], [0, 0, 1]])
    if flip:
        out = np.array([[-1.0, 0, 1.0], [0, 1, 0], [0, 0, 1]]) @ out
    to_index = np.array([[1.0, 0, -0.5], [0, 1, -0.5], [0, 0, 1]])
    m = to_index @ pre @ roi.matrix() @ out
    mode = cv2.BORDER_REPLICATE if border == "replicate" else cv2.BORDER_CONSTANT
    return cv2.warpAffine(np.asarray(src, np.float32), m[:2], (size, size),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=mode, borderValue=0)
