"""Still images of renders: PNG files and contact sheets (a grid of views on one PNG).

Images are (H, W, 3) RGB (or (H, W) grey), either float in [0, 1] (clipped, rounded to 8 bits)
or uint8. PNGs are written through OpenCV, atomically.
"""
from __future__ import annotations

import math
import os
from typing import Sequence

import numpy as np

from avatarkit.errors import InputError, OutputError
from avatarkit.fileio import atomic_path


def to_uint8(image: np.ndarray) -> np.ndarray:
    """(H, W, C) or (H, W) float in [0, 1] or uint8 -> uint8 of the same shape."""
    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a
    if not np.issubdtype(a.dtype, np.floating) and not np.issubdtype(a.dtype, np.integer):
        raise InputError(f"image must be numeric, got dtype {a.dtype}")
    if np.issubdtype(a.dtype, np.floating):
        a = np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0)
        return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.clip(a, 0, 255).astype(np.uint8)


def _check_image(image, name: str = "image") -> np.ndarray:
    a = to_uint8(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"{name} must have shape (H, W, 3) or (H, W), got {np.shape(image)}")
    return a


def write_png(path: str | os.PathLike, image: np.ndarray, alpha: np.ndarray | None = None) -> None:
    """Write an RGB image (H, W, 3) (plus optional alpha (H, W) -> RGBA) as PNG, atomically."""
    rgb = _check_image(image)[..., :3]
    if alpha is not None:
        a = to_uint8(alpha)
        if a.shape != rgb.shape[:2]:
            raise InputError(f"alpha has shape {a.shape}, image is {rgb.shape[:2]}")
        rgb = np.concatenate([rgb, a[..., None]], axis=2)
    import cv2

    bgr = rgb[..., [2, 1, 0, 3]] if rgb.shape[2] == 4 else rgb[..., ::-1]
    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(bgr)):
            raise OutputError("OpenCV could not write the PNG", path)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read a PNG (or any image OpenCV reads) as uint8 RGB(A) (H, W, 3|4)."""
    import cv2

    img = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError("cannot read image", path)
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=2)
    return img[..., [2, 1, 0, 3]] if img.shape[2] == 4 else img[..., ::-1].copy()


def contact_sheet(images: Sequence[np.ndarray], columns: int | None = None,
                  labels: Sequence[str] | None = None, pad: int = 4,
                  background=(255, 255, 255)) -> np.ndarray:
    """Lay equally sized images out on a grid -> uint8 (H, W, 3).

    columns: default ceil(sqrt(n)); labels (optional, one per image) are drawn small in the top
    left corner of each cell, dark on a light box so they read on any render.
    """
    imgs = [_check_image(im, f"image {i}")[..., :3] for i, im in enumerate(images)]
    if not imgs:
        raise InputError("a contact sheet needs at least one image")
    h, w = imgs[0].shape[:2]
    for i, im in enumerate(imgs):
        if im.shape[:2] != (h, w):
            raise InputError(f"contact sheet images must share one size: image 0 is {w}x{h}, "
                             f"image {i} is {im.shape[1]}x{im.shape[0]}")
    n = len(imgs)
    cols = int(columns) if columns else math.ceil(math.sqrt(n))
    if cols < 1:
        raise InputError(f"columns must be >= 1, got {columns}")
    if labels is not None and len(labels) != n:
        raise InputError(f"got {len(labels)} labels for {n} images")
    if pad < 0:
        raise InputError(f"pad must be >= 0, got {pad}")
    rows = math.ceil(n / cols)
    sheet = np.empty((rows * h + (rows + 1) * pad, cols * w + (cols + 1) * pad, 3), np.uint8)
    sheet[:] = np.asarray(background, dtype=np.uint8)
    for i, im in enumerate(imgs):
        r, c = divmod(i, cols)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        cell = sheet[y:y + h, x:x + w]
        cell[:] = im
        if labels is not None and labels[i]:
            _draw_label(cell, str(labels[i]))
    return sheet


def _draw_label(cell: np.ndarray, text: str) -> None:
    import cv2

    scale = max(0.3, min(cell.shape[:2]) / 500.0)
    thick = 1
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    m = max(2, int(4 * scale))
    cv2.rectangle(cell, (0, 0), (min(tw + 2 * m, cell.shape[1] - 1), min(th + base + 2 * m,
                  cell.shape[0] - 1)), (240, 240, 240), thickness=-1)
    cv2.putText(cell, text, (m, m + th), cv2.FONT_HERSHEY_SIMPLEX, scale, (20, 20, 20), thick,
                cv2.LINE_AA)


def write_contact_sheet(path: str | os.PathLike, images: Sequence[np.ndarray],
                        columns: int | None = None, labels: Sequence[str] | None = None,
                        pad: int = 4, background=(255, 255, 255)) -> None:
    """`contact_sheet` written as PNG, atomically."""
    write_png(path, contact_sheet(images, columns, labels, pad, background))
