"""Tracked clips on disk: a motion .npz that `bake` reads (GaussianAvatars/VHAP keys, see
`motion.io`) with the tracking's extras beside the motion, all float64 or integer so readers
that keep only float32 arrays (GaussianAvatars) skip them:

    camera_K (3, 3)               pixel intrinsics of the tracked camera
    camera_world_to_camera (4, 4) its extrinsics (OpenCV axes; fixed over the clip)
    image_size (2,)               width, height in pixels
    frame_index (T,)              the source video's frame number of each clip frame
    found (T,)                    1 where a face was found, 0 where the frame was interpolated
    confidence (T,)               in [0, 1] (`tracker` module docstring)
    landmarks (T, 468, 2)         the face mesh detected in each frame (pixels; NaN: no face)
    landmark_error (T,)           median pixels between fitted and detected landmarks
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError
from avatarkit.render.camera import Camera

TRACK_KEYS = ("camera_K", "camera_world_to_camera", "image_size", "frame_index", "found",
              "confidence", "landmarks", "landmark_error")


def tracking_extras(result) -> dict:
    cam = result.camera
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    return {"camera_K": K, "camera_world_to_camera": np.asarray(cam.world_to_camera, np.float64),
            "image_size": np.array([cam.width, cam.height], np.int64),
            "frame_index": np.asarray(result.frame_index, np.int64),
            "found": np.asarray(result.found, np.uint8),
            "confidence": np.asarray(result.confidence, np.float64),
            "landmarks": np.asarray(result.landmarks, np.float64),
            "landmark_error": np.asarray(result.landmark_error, np.float64)}


def save_tracking(path: str | os.PathLike, result) -> None:
    """Write a `TrackResult` as one .npz (atomically)."""
    from avatarkit.motion.io import save_clip

    save_clip(path, result.clip, extras=tracking_extras(result))


def load_tracking(path: str | os.PathLike):
    """Read a tracked clip back as a `TrackResult` (raw per-frame fits are not stored).
    A motion clip without the tracking's keys is a FormatError naming what is missing."""
    from avatarkit.fileio import read_npz
    from avatarkit.motion.io import load_clip
    from avatarkit.track.tracker import TrackResult

    p = Path(path)
    clip = load_clip(p)
    data = read_npz(p)
    missing = [k for k in TRACK_KEYS if k not in data]
    if missing:
        raise FormatError(f"not a tracked clip (written by `avatarkit track`): missing {', '.join(missing)}", p)
    T = clip.n_frames
    try:
        K = np.asarray(data["camera_K"], np.float64).reshape(3, 3)
        w, h = (int(v) for v in np.asarray(data["image_size"]).reshape(2))
        camera = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], w, h,
                        np.asarray(data["camera_world_to_camera"], np.float64).reshape(4, 4))
    except (ValueError, TypeError) as e:
        raise FormatError(f"tracked camera is malformed ({e})", p) from None
    except Exception as e:  # InputError from Camera's checks
        raise FormatError(f"tracked camera is invalid ({e})", p) from None
    arrays = {}
    for key, shape in (("frame_index", (T,)), ("found", (T,)), ("confidence", (T,)),
                       ("landmarks", (T, 468, 2)), ("landmark_error", (T,))):
        a = np.asarray(data[key])
        if a.shape != shape:
            raise FormatError(f"{key!r} has shape {a.shape}, expected {shape}", p)
        arrays[key] = a
    return TrackResult(clip, camera, arrays["frame_index"].astype(np.int64), arrays["found"].astype(bool),
                       arrays["confidence"].astype(np.float64), arrays["landmarks"].astype(np.float32),
                       arrays["landmark_error"].astype(np.float64))
