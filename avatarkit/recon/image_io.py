"""Read portrait images (and masks) into numpy arrays; write images atomically.

Reading goes through Pillow because it honours EXIF orientation (`ImageOps.exif_transpose`)
and decodes every common format (JPEG, PNG, WebP, TIFF, BMP, GIF: first frame). Conventions
of what comes back:

- colour: (H, W, 3) uint8 RGB, in the orientation a viewer shows (EXIF applied);
- grey, palette, CMYK and 16-bit images are converted to 8-bit RGB (16-bit values scaled by 1/257);
- transparency: the colour is composited on **white**, and the alpha channel is returned
  separately by `load_image` (`LoadedImage.alpha`, (H, W) uint8; None for opaque images), so a
  cut-out portrait looks right and its alpha can still serve as a person mask;
- size: images whose longer side exceeds `MAX_SIDE` (2048 px) are downscaled (area-preserving
  resampling, aspect kept) to that working size; `LoadedImage.scale` says by how much. Every
  later stage works in the returned image's pixels. Images above Pillow's decompression-bomb
  limit (about 179 megapixels) are refused.
"""
from __future__ import annotations

import io
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path

#: longer side, in pixels, above which images are downscaled on reading
MAX_SIDE = 2048


@dataclass(frozen=True, eq=False)
class LoadedImage:
    """An image as read from disk."""

    rgb: np.ndarray              # (H, W, 3) uint8, composited on white where transparent
    alpha: np.ndarray | None     # (H, W) uint8, or None when the file has no transparency
    path: str
    original_size: tuple[int, int]  # (width, height) after EXIF orientation, before downscaling
    scale: float                 # returned width / original width (1.0 unless downscaled)


def _open(path: Path):
    from PIL import Image, UnidentifiedImageError

    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError("is a folder, not an image file", path)
    try:
        with warnings.catch_warnings():
            # We downscale large images ourselves, so Pillow's "possible decompression bomb"
            # warning (89-179 MP) is noise; above 179 MP it raises and we refuse the file.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(path)
    except Image.DecompressionBombError as e:
        raise FormatError(f"image is too large to decode safely ({e})", path) from None
    except UnidentifiedImageError:
        raise FormatError("not an image file Pillow can read (JPEG, PNG, WebP, TIFF, BMP, GIF)", path) from None
    except OSError as e:
        raise FormatError(f"cannot open image: {e}", path) from None
    return img


def _to_rgb_alpha(img) -> tuple[np.ndarray, np.ndarray | None]:
    """Pillow image of any mode -> (H, W, 3) uint8 straight colour and (H, W) uint8 alpha or None."""
    mode = img.mode
    if mode in ("I", "I;16", "I;16L", "I;16B", "I;16N", "F"):
        grey = np.asarray(img, dtype=np.float64)
        if mode == "F" and grey.size and np.nanmax(grey) <= 1.0:
            grey = grey * 255.0
        elif mode != "F":
            grey = grey / 257.0  # 16-bit range -> 8-bit
        g8 = np.clip(np.nan_to_num(grey), 0, 255).round().astype(np.uint8)
        return np.repeat(g8[:, :, None], 3, axis=2), None
    has_alpha = mode in ("RGBA", "LA", "PA", "RGBa", "La") or "transparency" in img.info
    if has_alpha:
        rgba = np.asarray(img.convert("RGBA"), dtype=np.uint8)
        return np.ascontiguousarray(rgba[:, :, :3]), np.ascontiguousarray(rgba[:, :, 3])
    return np.asarray(img.convert("RGB"), dtype=np.uint8), None


def _composite_on_white(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    a = alpha.astype(np.float32)[:, :, None] / 255.0
    out = rgb.astype(np.float32) * a + 255.0 * (1.0 - a)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _area_resize(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    import cv2

    return cv2.resize(a, size, interpolation=cv2.INTER_AREA)


def load_image(path: str | os.PathLike, max_side: int | None = None) -> LoadedImage:
    """Read an image file; see the module docstring for the conventions.

    Raises InputError (missing file, folder) or FormatError (not an image, corrupt or
    truncated data), both naming the file.
    """
    max_side = MAX_SIDE if max_side is None else max_side
    from PIL import ImageOps

    path = Path(path)
    img = _open(path)
    try:
        with img:
            w0, h0 = img.size
            if max_side and max(w0, h0) > max_side:
                # JPEG can decode straight at 1/2, 1/4, 1/8 size: huge photos load fast.
                k = max_side / max(w0, h0)
                img.draft("RGB", (math.ceil(w0 * k), math.ceil(h0 * k)))
            exif_size = _oriented_size(img, (w0, h0))
            img = ImageOps.exif_transpose(img)
            img.load()
            rgb, alpha = _to_rgb_alpha(img)
    except InputError:
        raise
    except (OSError, ValueError, SyntaxError, EOFError) as e:
        # Pillow reports truncated/corrupt data as OSError ("image file is truncated"),
        # broken headers as SyntaxError/ValueError.
        raise FormatError(f"corrupt or truncated image data: {e}", path) from None
    if rgb.size == 0:
        raise FormatError("image has no pixels", path)

    if alpha is not None:
        if alpha.min() == 255:
            alpha = None  # an alpha channel that is fully opaque carries no information
        else:
            # Composite before any resampling: transparent pixels' colours are often garbage.
            rgb = _composite_on_white(rgb, alpha)
    h, w = rgb.shape[:2]
    if max_side and max(w, h) > max_side:
        k = max_side / max(w, h)
        size = (max(1, round(w * k)), max(1, round(h * k)))
        rgb = _area_resize(rgb, size)
        alpha = _area_resize(alpha, size) if alpha is not None else None
    return LoadedImage(rgb=np.ascontiguousarray(rgb), alpha=alpha, path=os.fspath(path),
                       original_size=exif_size, scale=rgb.shape[1] / exif_size[0])


def _oriented_size(img, size: tuple[int, int]) -> tuple[int, int]:
    """Full-resolution (width, height) as displayed, i.e. swapped for EXIF orientations 5-8."""
    try:
        orientation = img.getexif().get(0x0112, 1)
    except Exception:  # a broken EXIF block must not stop us reading the pixels
        orientation = 1
    return (size[1], size[0]) if orientation in (5, 6, 7, 8) else size


def read_image(path: str | os.PathLike, max_side: int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file: EXIF-oriented, transparency composited on white,
    downscaled so the longer side is at most `max_side` (0 = never downscale)."""
    max_side = MAX_SIDE if max_side is None else max_side
    return load_image(path, max_side).rgb


def read_mask(path: str | os.PathLike, shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) bool mask from an image file (EXIF orientation honoured): a pixel is True when its
    value is non-zero (any colour channel) and, if the file has alpha, it is not transparent.
    A mask whose colour is constant and whose alpha varies is read from the alpha alone.

    With `shape` (H, W) the mask is resized (nearest neighbour) to it when the aspect ratios
    agree within 1%, otherwise FormatError: a mask for a different picture is a user mistake.
    """
    img = _open(Path(path))
    try:
        with img:
            arr = np.asarray(_exif_oriented(img))
    except (OSError, ValueError, SyntaxError, EOFError) as e:
        raise FormatError(f"corrupt or truncated image data: {e}", path) from None
    if arr.size == 0:
        raise FormatError("mask image has no pixels", path)
    if arr.ndim == 3 and arr.shape[2] in (2, 4):  # LA / RGBA
        colour, alpha = arr[:, :, :-1], arr[:, :, -1]
        on = colour.any(axis=2) if np.ptp(colour) > 0 else np.ones(alpha.shape, bool)
        mask = on & (alpha > 0)
    elif arr.ndim == 3:
        mask = arr.any(axis=2)
    else:
        mask = arr != 0
    return fit_mask(mask, shape, path) if shape is not None else mask


def _exif_oriented(img):
    """The image as displayed (EXIF applied) in a mode numpy reads as raw values."""
    from PIL import ImageOps

    img = ImageOps.exif_transpose(img)
    if img.mode == "P":
        img = img.convert("RGBA" if "transparency" in img.info else "RGB")
    elif img.mode in ("1", "CMYK", "YCbCr", "LAB", "HSV"):
        img = img.convert("L" if img.mode == "1" else "RGB")
    img.load()
    return img


def fit_mask(mask: np.ndarray, shape: tuple[int, int], path: str | os.PathLike | None = None) -> np.ndarray:
    """Resize a (h, w) mask to `shape` (H, W) with nearest neighbour if the aspect ratios agree
    within 1%; otherwise FormatError (naming `path` when given)."""
    import cv2

    mask = np.asarray(mask)
    if mask.ndim == 3:
        mask = mask.any(axis=2)
    if mask.ndim != 2 or mask.size == 0:
        raise FormatError(f"mask must be a 2D image, got shape {mask.shape}", path)
    h, w = mask.shape
    H, W = shape
    if (h, w) == (H, W):
        return mask != 0
    if abs((w / h) / (W / H) - 1.0) > 0.01:
        raise FormatError(f"mask is {w}x{h} px but the image is {W}x{H} px (different aspect ratio)", path)
    resized = cv2.resize((mask != 0).astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST)
    return resized.astype(bool)


def write_image(path: str | os.PathLike, rgb: np.ndarray, quality: int = 95) -> None:
    """Write an (H, W, 3) uint8 RGB or (H, W) uint8 image atomically; format from the extension
    (.png, .jpg/.jpeg, .webp, .tif/.tiff, .bmp)."""
    from PIL import Image

    from avatarkit.errors import OutputError

    arr = np.asarray(rgb)
    if arr.dtype != np.uint8 or arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] not in (3, 4)):
        raise InputError(f"image must be uint8 (H, W), (H, W, 3) or (H, W, 4), got {arr.dtype} {arr.shape}")
    formats = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".webp": "WEBP",
               ".tif": "TIFF", ".tiff": "TIFF", ".bmp": "BMP"}
    fmt = formats.get(Path(path).suffix.lower())
    if fmt is None:
        raise OutputError(f"unknown image extension; use one of {', '.join(sorted(formats))}", path)
    params = {"quality": quality} if fmt in ("JPEG", "WEBP") else {}
    # Encoded in memory, then written by Python: Pillow's C encoders (JPEG) ignore a failed
    # write() to a file and return as if it had worked, leaving a truncated image.
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(arr)).save(buf, format=fmt, **params)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getbuffer())
