"""A synthetic portrait with known labels, for tests and benchmarks of the 2D stages.

Face detectors are not fooled by drawings, so it comes with its face box; build the analysis
with `analysis_from_box(image_size, face_box)`. Geometry follows `FACE_PROPORTIONS`
(eye midpoint at `eye_mid`, inter-ocular distance `iod`), colours are flat plus noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.recon.portrait import BOX_RATIOS

SKIN_RGB = (224, 178, 148)
HAIR_RGB = (72, 46, 30)
BACKGROUND_RGB = (120, 150, 185)
BODY_RGB = (60, 120, 70)


@dataclass(frozen=True, eq=False)
class SyntheticPortrait:
    image: np.ndarray      # (H, W, 3) uint8
    labels: np.ndarray     # (H, W) uint8 ground truth: 0 background, 1 skin, 2 hair, 3 body
    face_box: tuple[int, int, int, int]


def synthetic_portrait(size: int = 256, hair: bool = True, seed: int = 0, noise: float = 3.0,
                       hair_rgb=None, skin_rgb=None, background_rgb=None,
                       body_rgb=None, blur: float = 0.0) -> SyntheticPortrait:
    """A frontal "portrait": background, shaded skin ellipse with eyes and mouth, a hair cap
    (optional), a neck and shoulders. Eye midpoint at (size/2, 0.43 size), IOD = 0.156 size.
    `blur` (Gaussian sigma, pixels) softens the edges the way a camera does; noise comes after."""
    hair_rgb = HAIR_RGB if hair_rgb is None else hair_rgb
    skin_rgb = SKIN_RGB if skin_rgb is None else skin_rgb
    background_rgb = BACKGROUND_RGB if background_rgb is None else background_rgb
    body_rgb = BODY_RGB if body_rgb is None else body_rgb
    rng = np.random.default_rng(seed)
    s = size / 256.0
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) + 0.5  # pixel centres
    cx, ey, iod = size / 2, 110 * s, 40 * s
    u, v = (x - cx) / iod, (y - ey) / iod

    face = (u / 1.0) ** 2 + ((v - 0.5) / 1.25) ** 2 <= 1.0
    neck = (np.abs(u) < 0.42) & (v > 1.2) & (v < 2.5)
    body = (v > 2.2) & (np.abs(u) < 0.8 + (v - 2.2) * 1.6)
    hair_m = np.zeros_like(face)
    if hair:
        cap = (u / 1.45) ** 2 + ((v + 0.25) / 1.75) ** 2 <= 1.0
        hair_m = cap & (~face | (v < -0.55)) & (v < 1.0)

    labels = np.zeros((size, size), np.uint8)
    labels[body] = 3
    labels[face | neck] = 1
    labels[hair_m] = 2

    img = np.empty((size, size, 3), np.float32)
    img[:] = background_rgb
    img[body] = body_rgb
    # Skin with soft shading: darker toward the face outline, as on a real (convex) face.
    shade = np.clip(1.0 - 0.25 * (u**2 + ((v - 0.5) / 1.25) ** 2), 0.7, 1.0)
    skin_px = face | neck
    img[skin_px] = np.asarray(skin_rgb, np.float32) * shade[skin_px, None]
    for ex in (-0.5, 0.5):  # eyes
        img[((u - ex) / 0.16) ** 2 + (v / 0.09) ** 2 <= 1.0] = (45, 35, 35)
    img[(u / 0.3) ** 2 + ((v - 0.95) / 0.09) ** 2 <= 1.0] = (170, 70, 75)  # mouth
    img[hair_m] = hair_rgb
    if blur > 0:
        import cv2

        img = cv2.GaussianBlur(img, (0, 0), blur)
    img += rng.normal(0.0, noise, img.shape)
    image = np.clip(img + 0.5, 0, 255).astype(np.uint8)

    # The face box a Haar detector would report: eyes at BOX_RATIOS of it.
    bw = iod / (BOX_RATIOS["left_eye"][0] - BOX_RATIOS["right_eye"][0])
    box = (int(round(cx - 0.5 * bw)), int(round(ey - BOX_RATIOS["left_eye"][1] * bw)), int(round(bw)), int(round(bw)))
    return SyntheticPortrait(image=image, labels=labels, face_box=box)
