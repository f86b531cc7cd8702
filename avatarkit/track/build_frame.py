"""Build from one frame of a video (`avatarkit build VIDEO --frame N`, `avatarkit evaluate`).

The default frame is the most frontal one with a neutral mouth, chosen from a tracking of the
video with the template head (`choose_build_frame`): among the frames whose confidence is at
least `MIN_CONFIDENCE_SHARE` of the best, the one with the smallest
    |head rotation| (rad) + 2 |jaw| (rad) + 0.1 |expression coefficients|
      + MOUTH_WEIGHT * (lip gap + mouth widening) (eye distances, from the face mesh)
(an open jaw counts double a turn of the same angle; expression coefficients are ~1 at a
clear expression, so 0.1 of them weighs like a 6 degree turn). The frame is then read
(`video.read_frame`), written as a PNG into a temporary folder and built by the portrait build.

Why the mouth is also read from the detected face mesh (`mouth_cost`): the tracked jaw and
expression under-read a smile (the expression prior and the head model's few mouth shapes),
and the tracker's per-landmark calibration (`TrackOptions.calibration_frames`) absorbs the
mouth shape of its first frames, so with it every frame fits well: the confidence no longer
rules out the expressive frames it used to (measured on talking_man_glasses.mp4: uncalibrated,
frame 175, lips apart with the teeth showing in a wide smile, had confidence 0.63 of the best
0.83 and was not eligible; calibrated, 0.96 of 0.997, and it won on its head pose). The lip
gap (inner lips, points 13 and 14) and the mouth's widening beyond its median width over the
video (corners 61 and 291) are what the mesh sees directly, whatever head model or
calibration the tracking used.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from avatarkit.track.neck import clip_head_rotation

MIN_CONFIDENCE_SHARE = 0.8
#: radians of head turn one eye distance of lip gap or mouth widening is worth: lips 0.1 eye
#: distances apart (the teeth show) weigh like a ~6 degree turn
MOUTH_WEIGHT = 1.0
#: face-mesh points: inner lips (upper, lower), mouth corners, eye corners (right pair, left pair)
_LIPS_INNER = (13, 14)
_MOUTH_CORNERS = (61, 291)
_EYE_CORNERS = ((33, 133), (362, 263))
#: files `build` treats as videos (anything else is a photo)
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm")


def is_video(path: str | os.PathLike) -> bool:
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def mouth_cost(landmarks: np.ndarray) -> np.ndarray:
    """(T,) lip gap + widening of the mouth beyond its median width, in eye distances, from the
    detected face meshes landmarks (T, 468, 2) (NaN rows: no face; their cost is NaN)."""
    p = np.asarray(landmarks, np.float64)
    (r0, r1), (l0, l1) = _EYE_CORNERS
    iod = np.linalg.norm((p[:, r0] + p[:, r1]) / 2 - (p[:, l0] + p[:, l1]) / 2, axis=1)   # (T,)
    iod = np.where(iod > 0, iod, np.nan)
    gap = np.linalg.norm(p[:, _LIPS_INNER[0]] - p[:, _LIPS_INNER[1]], axis=1) / iod
    width = np.linalg.norm(p[:, _MOUTH_CORNERS[0]] - p[:, _MOUTH_CORNERS[1]], axis=1) / iod
    seen = np.isfinite(width)
    widen = np.maximum(width - np.median(width[seen]), 0.0) if seen.any() else width
    return gap + widen


def frame_costs(result) -> np.ndarray:
    """(T,) the choice's cost per clip frame (module docstring); inf where not eligible."""
    clip = result.clip
    conf = np.where(result.found, np.asarray(result.confidence, np.float64), 0.0)
    mouth = mouth_cost(result.landmarks)
    cost = (np.linalg.norm(clip_head_rotation(clip), axis=1) + 2.0 * np.linalg.norm(clip.jaw, axis=1)
            + 0.1 * np.linalg.norm(clip.expr, axis=1) + MOUTH_WEIGHT * np.nan_to_num(mouth, nan=np.inf))
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
