"""Preview files of splats: one PNG, a contact sheet PNG, or a turntable MP4/GIF.

`render_preview(source, output, PreviewOptions(...))` is what `avatarkit render` runs; the
output kind follows the file extension. Frames are rendered and written one at a time.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from avatarkit.errors import InputError, OutputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.limits import MAX_RENDER_PIXELS
from avatarkit.render.camera import Camera
from avatarkit.render.pipeline import check_background, check_render_size, render
from avatarkit.render.views import framing, turntable_cameras

DEFAULT_TURNTABLE_FRAMES = 36
_NAMED_COLORS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0), "gray": (0.5, 0.5, 0.5),
                 "grey": (0.5, 0.5, 0.5)}


def parse_color(text: str) -> tuple[float, float, float]:
    """"r,g,b" (floats in [0, 1]), "#rrggbb", or black/white/gray -> (r, g, b)."""
    s = str(text).strip().lower()
    if s in _NAMED_COLORS:
        return _NAMED_COLORS[s]
    if s.startswith("#") and len(s) == 7:
        try:
            return tuple(int(s[i:i + 2], 16) / 255.0 for i in (1, 3, 5))
        except ValueError:
            pass
    else:
        try:
            rgb = tuple(float(v) for v in s.split(","))
        except ValueError:
            rgb = ()
        if len(rgb) == 3 and all(np.isfinite(v) and 0.0 <= v <= 1.0 for v in rgb):
            return rgb
    raise InputError(f"cannot read colour {text!r}: use r,g,b in [0, 1], #rrggbb, black, white or gray")


def parse_vec3(text: str, what: str = "point") -> tuple[float, float, float]:
    """"x,y,z" -> 3 finite floats."""
    try:
        v = tuple(float(p) for p in str(text).split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(np.isfinite(x) for x in v):
        raise InputError(f"cannot read {what} {text!r}: expected x,y,z")
    return v


@dataclass
class PreviewOptions:
    width: int | None = None          # default 512, or the --camera file's size
    height: int | None = None
    fov_deg: float = 30.0             # vertical field of view
    azimuth_deg: float = 0.0          # 0 = from the front (+Z); turntables start here
    elevation_deg: float = 0.0
    distance: float | None = None     # default: frames the splats
    target: tuple[float, float, float] | None = None  # default: the splats' centre
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    camera: Camera | None = None      # an explicit camera (one view) instead of the orbit
    turntable: int | None = None      # views for an .mp4/.gif (default 36)
    contact_sheet: int | None = None  # views around the subject on one PNG
    columns: int | None = None        # contact sheet columns (default ~sqrt(views))
    fps: float = 24.0
    crf: int | None = None            # H.264 quality of an .mp4 (default: export.video.DEFAULT_CRF)


@dataclass
class PreviewResult:
    output: Path
    kind: str        # "image", "contact_sheet" or "video"
    frames: int
    width: int
    height: int
    seconds: float


def output_kind(output: str | os.PathLike, options: PreviewOptions) -> str:
    """Validate the output name against the options before any work is done."""
    ext = Path(output).suffix.lower()
    if ext not in (".png", ".mp4", ".gif"):
        raise OutputError(f"unknown output extension {ext or '(none)'!r}: use .png, .mp4 or .gif",
                          output)
    if options.camera is not None and (options.turntable or options.contact_sheet):
        raise InputError("a --camera file gives one view; it cannot be combined with "
                         "--turntable or --contact-sheet")
    check_preview_size(options, ext)
    if ext == ".png":
        if options.turntable:
            raise InputError("a turntable is a video: write it to .mp4 or .gif "
                             "(or use --contact-sheet N for views on one PNG)")
        return "contact_sheet" if options.contact_sheet else "image"
    if options.contact_sheet:
        raise InputError("a contact sheet is a PNG image, not a video", output)
    if options.camera is not None:
        raise InputError("a --camera file gives one view; write it to .png", output)
    return "video"


#: frames x pixels a GIF turntable may hold (it is encoded from frames kept in memory)
MAX_GIF_PIXELS = 4 * MAX_RENDER_PIXELS


def check_preview_size(options: PreviewOptions, ext: str) -> None:
    """InputError when the images asked for exceed the stated bounds (`avatarkit.limits`),
    before anything is loaded or allocated."""
    cam = options.camera
    w = options.width or (cam.width if cam is not None else 512)
    h = options.height or (cam.height if cam is not None else 512)
    check_render_size(w, h)
    if ext == ".png" and options.contact_sheet:
        if options.contact_sheet * w * h > MAX_RENDER_PIXELS:
            raise InputError(f"a contact sheet of {options.contact_sheet} views of {w}x{h} would have "
                             f"{options.contact_sheet * w * h:,} pixels; the limit is {MAX_RENDER_PIXELS:,}")
    if ext == ".gif":
        n = options.turntable or 36
        if n * w * h > MAX_GIF_PIXELS:
            raise InputError(f"a GIF of {n} frames of {w}x{h} would hold {n * w * h:,} pixels; the limit "
                             f"is {MAX_GIF_PIXELS:,} (write .mp4, or fewer or smaller frames)")


def _count(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"{name} must be a positive number of views, got {value!r}")
    return int(value)


def preview_cameras(gaussians: GaussianSet, options: PreviewOptions, kind: str) -> list[Camera]:
    """The cameras a preview renders (one for an image)."""
    if options.camera is not None:
        cam = options.camera
        if options.width or options.height:
            cam = cam.with_size(options.width or cam.width, options.height or cam.height)
        return [cam]
    width, height = options.width or 512, options.height or 512
    target, distance = options.target, options.distance
    if target is None or distance is None:
        if len(gaussians) == 0:
            raise InputError("there are no splats to frame; give --target and --distance")
        auto_t, auto_d = framing(gaussians, options.fov_deg, width, height)
        target = auto_t if target is None else target
        distance = auto_d if distance is None else distance
    if kind == "image":
        return [Camera.orbit(target, options.azimuth_deg, options.elevation_deg, distance,
                             options.fov_deg, width, height)]
    n = _count("turntable", options.turntable or DEFAULT_TURNTABLE_FRAMES) if kind == "video" \
        else _count("contact sheet", options.contact_sheet)
    return turntable_cameras(n, target=target, distance=distance, elevation_deg=options.elevation_deg,
                             fov_deg=options.fov_deg, width=width, height=height,
                             start_azimuth_deg=options.azimuth_deg)


def render_preview(source: GaussianSet | str | os.PathLike, output: str | os.PathLike,
                   options: PreviewOptions | None = None,
                   progress: Callable[[int, int], None] | None = None) -> PreviewResult:
    """Render `source` (a GaussianSet, a splat file or an avatar folder, whose bald and hair
    Gaussians are drawn at rest) to `output` (.png/.mp4/.gif).

    progress(done, total) is called after each frame.
    """
    options = options or PreviewOptions()
    t0 = time.perf_counter()
    kind = output_kind(output, options)
    background = check_background(options.background)
    if isinstance(source, GaussianSet):
        gaussians = source
    elif Path(source).is_dir():  # an avatar folder: bald and hair at rest
        from avatarkit.avatar import load_rest_splats
        gaussians = load_rest_splats(source)
    else:
        from avatarkit.gaussians.io import load_gaussians
        gaussians = load_gaussians(source)
    try:
        cameras = preview_cameras(gaussians, options, kind)
    except InputError as e:  # an empty splat file: name it
        raise (e if isinstance(source, GaussianSet) else e.with_path(source)) from None
    total = len(cameras)

    def frames():
        for i, cam in enumerate(cameras):
            yield render(gaussians, cam, background).rgb
            if progress is not None:
                progress(i + 1, total)

    if kind == "image":
        from avatarkit.export.images import write_png
        write_png(output, next(frames()))
    elif kind == "contact_sheet":
        from avatarkit.export.images import write_contact_sheet
        labels = [f"az {options.azimuth_deg + 360.0 * i / total:g} el {options.elevation_deg:g}"
                  for i in range(total)]
        write_contact_sheet(output, list(frames()), columns=options.columns, labels=labels)
    else:
        from avatarkit.export.video import DEFAULT_CRF, write_video
        write_video(output, frames(), options.fps,
                    crf=DEFAULT_CRF if options.crf is None else options.crf)
    cam = cameras[0]
    return PreviewResult(Path(output), kind, total, cam.width, cam.height, time.perf_counter() - t0)
