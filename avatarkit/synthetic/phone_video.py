"""A phone's video of a synthetic turning head: the benchmark's square clip at a phone's size.

A phone records 1080x1920 (portrait) or 1920x1080 (landscape) at 30 fps, H.264 High without
B-frames, ~16 Mbit/s; a portrait video is stored landscape with a display matrix that turns it
upright (what `avatarkit.video` applies). `phone_video` makes such a file from a square video
(`turning_video.write_turning_video`, `mesh_head.turning_video`): each frame upscaled to the
phone frame's shorter side (bicubic) and the wall extended to its size by repeating the border
pixels (a plain wall: its own colour; the neck runs on down), the frames restamped at `fps`.
The build sees the same head turn at 2.25x the pixels across (480 -> 1080) in 9x the pixels of
a 480x480 frame: the build time and memory at a phone's size (`benchmarks/build_video.py
--time-phone`, session 28, docs/video-build.md).
"""
from __future__ import annotations

import os

import numpy as np

#: the phone frame (upright width, height) of `phone_video(portrait=True)`; landscape swaps them
PHONE_SIZE = (1080, 1920)
#: ...its frame rate and bit rate
PHONE_FPS = 30
PHONE_BIT_RATE = 16_000_000


def phone_frame(rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """rgb (h, w, 3) uint8 square frame -> (height, width, 3) uint8: upscaled to the shorter side
    of the phone's frame (bicubic), centred, the border pixels repeated out to its edges."""
    import cv2

    s = min(width, height)
    big = cv2.resize(np.ascontiguousarray(rgb), (s, s), interpolation=cv2.INTER_CUBIC)
    py, px = (height - s) // 2, (width - s) // 2
    return np.pad(big, ((py, height - s - py), (px, width - s - px), (0, 0)), mode="edge")


def phone_video(source: str | os.PathLike, path: str | os.PathLike, portrait: bool = True,
                size: tuple[int, int] | None = None, fps: float | None = None) -> int:
    """Write `source`'s frames at a phone's size to `path` (MP4, H.264) -> the number of frames.
    portrait: shown `size` (width, height; None: `PHONE_SIZE`) upright, stored turned a quarter
    counter-clockwise with a display matrix turning it back (a phone's portrait video);
    landscape: shown and stored with width and height swapped (the longer side across), no
    matrix. fps: the frames' new rate (None: `PHONE_FPS`): every source frame once."""
    import av

    from avatarkit.video import open_video

    w, h = PHONE_SIZE if size is None else size
    if not portrait:
        w, h = max(w, h), min(w, h)
    stored = (h, w) if portrait else (w, h)                      # the coded picture's (width, height)
    rate = PHONE_FPS if fps is None else fps
    n = 0
    tmp = f"{os.fspath(path)}.part.mp4"
    with open_video(source) as video, av.open(tmp, "w") as out:
        stream = out.add_stream("libx264", rate=int(round(rate)))
        stream.width, stream.height, stream.pix_fmt = stored[0], stored[1], "yuv420p"
        stream.bit_rate = PHONE_BIT_RATE
        stream.options = {"profile": "high", "bf": "0", "g": str(int(round(rate)))}
        if portrait:
            stream.set_display_rotation(-90)                     # shown turned a quarter clockwise
        for frame in video.frames():
            img = phone_frame(frame.rgb, w, h)
            if portrait:
                img = np.ascontiguousarray(np.rot90(img, 1))     # stored: a quarter counter-clockwise
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(packet)
            n += 1
        for packet in stream.encode():
            out.mux(packet)
    os.replace(tmp, path)
    return n


__all__ = ["PHONE_BIT_RATE", "PHONE_FPS", "PHONE_SIZE", "phone_frame", "phone_video"]
