"""Build from one frame of a video (`avatarkit build VIDEO --frame N`, `avatarkit evaluate`).

The default frame is the most frontal one with a neutral mouth, chosen from a tracking of the
video with the template head (`choose_build_frame`): among the frames whose confidence is at
least `MIN_CONFIDENCE_SHARE` of the best, the one with the smallest
    |head rotation| (rad) + 2 |jaw| (rad) + 0.1 |expression coefficients|
(an open jaw counts double a turn of the same angle; expression coefficients are ~1 at a
clear expression, so 0.1 of them weighs like a 6 degree turn). The frame is then read
(`video.read_frame`), written as a PNG into a temporary folder and built by the portrait build.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

MIN_CONFIDENCE_SHARE = 0.8
#: files `build` treats as videos (anything else is a photo)
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm")


def is_video(path: str | os.PathLike) -> bool:
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def frame_costs(result) -> np.ndarray:
    """(T,) the choice's cost per clip frame (module docstring); inf where not eligible."""
    clip = result.clip
    conf = np.where(result.found, np.asarray(result.confidence, np.float64), 0.0)
    cost = (np.linalg.norm(clip.rotation, axis=1) + 2.0 * np.linalg.norm(clip.jaw, axis=1)
            + 0.1 * np.linalg.norm(clip.expr, axis=1))
    ok = conf >= MIN_CONFIDENCE_SHARE * conf.max() if conf.max() > 0 else np.zeros(len(conf), bool)
    return np.where(ok, cost, np.inf)


def choose_build_frame(result) -> int:
    """The video frame number (`result.frame_index`) to build from (module docstring)."""
    return int(result.frame_index[int(np.argmin(frame_costs(result)))])


def portrait_frame(video: str | os.PathLike, frame: int | None,
                   progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, int]:
    """((H, W, 3) uint8 image, frame number) of the frame to build from."""
    from avatarkit.video import read_frame

    if frame is None:
        from avatarkit.track.video import track_video

        frame = choose_build_frame(track_video(video, progress=progress))
    return read_frame(video, int(frame)).rgb, int(frame)


def build_from_video(video: str | os.PathLike, output: str | os.PathLike, frame: int | None = None, *,
                     options=None, n_bald: int | None = None, n_hair: int | None = None,
                     progress: Callable[[int, int], None] | None = None, stage_progress=None):
    """Build the avatar folder `output` from one frame of `video`; returns the frame number.
    options: `BuildOptions` (n_bald / n_hair override its counts); the avatar's provenance
    records the video and the frame."""
    from avatarkit.recon.pipeline import BuildOptions

    options = options or BuildOptions(preview=False)
    if n_bald is not None:
        options.n_bald = n_bald
    if n_hair is not None:
        options.n_hair = n_hair
    image, index = portrait_frame(video, frame, progress)
    build_image(image, output, options, stage_progress,
                source={"video": os.path.abspath(os.fspath(video)), "frame": index})
    return index


def build_image(image: np.ndarray, output, options, progress=None, source: dict | None = None):
    """Build `output` from an (H, W, 3) uint8 image through the portrait build (which reads a
    file: the image goes through a temporary PNG). Returns the Avatar."""
    from avatarkit.export.images import write_png
    from avatarkit.recon.pipeline import build_avatar, save_avatar

    with tempfile.TemporaryDirectory(prefix="avatarkit-frame-") as tmp:
        png = Path(tmp) / "frame.png"
        write_png(png, image)
        avatar = build_avatar(png, options, progress)
    if source is not None:
        avatar.provenance["source_video"] = source
    save_avatar(avatar, output)
    return avatar
