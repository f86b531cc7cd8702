"""Preview clips: frame sequences as MP4 (OpenCV) or GIF (Pillow), streamed and atomic.

    with VideoWriter("turntable.mp4", fps=24) as video:
        for camera in cameras:
            video.append(render(gaussians, camera).rgb)

Frames are (H, W, 3) RGB, float in [0, 1] or uint8, all one size. MP4 is H.264 ("avc1") where
the installed OpenCV/FFmpeg can encode it, else MPEG-4 Part 2 ("mp4v", which the pip wheels of
opencv-python-headless always can). GIF frames are quantised to a palette each and loop forever.
Nothing appears under the requested name unless the whole clip was written.
"""
from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Iterable

import numpy as np

from avatarkit.errors import InputError, OutputError
from avatarkit.export.images import to_uint8
from avatarkit.fileio import atomic_path

VIDEO_EXTENSIONS = (".mp4", ".gif")
MP4_CODECS = ("avc1", "mp4v")


def video_format(path: str | os.PathLike) -> str:
    """"mp4" or "gif" from the file name; OutputError for anything else."""
    ext = Path(path).suffix.lower()
    if ext not in VIDEO_EXTENSIONS:
        raise OutputError(f"unknown video extension {ext or '(none)'!r}; use .mp4 or .gif", path)
    return ext[1:]


@contextlib.contextmanager
def _silenced_stderr():
    """FFmpeg reports a codec it lacks on the process's stderr; we try codecs quietly."""
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


class VideoWriter:
    """Append frames one at a time; the file is complete (and renamed into place) on `close()`
    or when the `with` block ends without an exception (then the partial file is removed)."""

    def __init__(self, path: str | os.PathLike, fps: float = 24.0, codec: str | None = None):
        self.path = Path(path)
        self.format = video_format(path)
        try:
            self.fps = float(fps)
        except (TypeError, ValueError):
            raise InputError(f"fps must be a number, got {fps!r}") from None
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InputError(f"fps must be > 0, got {fps!r}")
        if codec is not None and (self.format != "mp4" or len(codec) != 4):
            raise InputError(f"codec must be a 4-letter MP4 fourcc such as 'mp4v', got {codec!r}")
        self.codec = codec  # the fourcc actually used, once the first frame is in (MP4)
        self.frame_count = 0
        self._size: tuple[int, int] | None = None
        self._atomic = atomic_path(self.path)
        self._tmp = self._atomic.__enter__()
        self._cv_writer = None
        self._gif_frames: list = []
        self._closed = False

    # --- frames -----------------------------------------------------------------------------
    def append(self, frame: np.ndarray) -> None:
        """Add one frame (H, W, 3) RGB, float [0, 1] or uint8."""
        if self._closed:
            raise OutputError("video already closed", self.path)
        img = to_uint8(frame)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
            raise InputError(f"video frames must have shape (H, W, 3), got {np.shape(frame)}")
        size = (img.shape[1], img.shape[0])
        if self._size is None:
            self._size = size
            if self.format == "mp4":
                self._open_mp4(size)
        elif size != self._size:
            raise InputError(f"frame {self.frame_count} is {size[0]}x{size[1]}, the video is "
                             f"{self._size[0]}x{self._size[1]}")
        if self.format == "mp4":
            self._cv_writer.write(np.ascontiguousarray(img[..., ::-1]))
        else:
            from PIL import Image

            # adaptive palette per frame; dithering off keeps turntables from shimmering
            self._gif_frames.append(Image.fromarray(img).quantize(
                colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE))
        self.frame_count += 1

    def extend(self, frames: Iterable[np.ndarray]) -> None:
        for f in frames:
            self.append(f)

    def _open_mp4(self, size: tuple[int, int]) -> None:
        import cv2

        tried = [self.codec] if self.codec else list(MP4_CODECS)
        for codec in tried:
            with _silenced_stderr():
                writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*codec), self.fps, size)
            if writer.isOpened():
                self._cv_writer, self.codec = writer, codec
                return
            writer.release()
        raise OutputError(f"OpenCV cannot encode MP4 here (tried {', '.join(tried)})", self.path)

    # --- finishing --------------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file and move it into place."""
        if self._closed:
            return
        try:
            if self.frame_count == 0:
                raise InputError("a video needs at least one frame", self.path)
            if self.format == "mp4":
                self._cv_writer.release()
                if not self._tmp.exists() or self._tmp.stat().st_size == 0:
                    raise OutputError("OpenCV wrote an empty MP4", self.path)
            else:
                first, *rest = self._gif_frames
                first.save(self._tmp, format="GIF", save_all=True, append_images=rest,
                           duration=max(1, round(1000.0 / self.fps)), loop=0, optimize=False)
        except BaseException as e:
            self._abort(e)
            raise
        self._closed = True
        self._gif_frames = []
        self._atomic.__exit__(None, None, None)

    def _abort(self, exc: BaseException) -> None:
        if self._closed:
            return
        self._closed = True
        if self._cv_writer is not None:
            self._cv_writer.release()
        self._gif_frames = []
        with contextlib.suppress(type(exc)):
            self._atomic.__exit__(type(exc), exc, exc.__traceback__)

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc is None:
            self.close()
        else:
            self._abort(exc)
        return False


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 24.0) -> int:
    """Write all `frames` (an iterable: rendered lazily, one at a time) -> number of frames."""
    with VideoWriter(path, fps) as video:
        video.extend(frames)
    return video.frame_count


def read_video_frames(path: str | os.PathLike) -> list[np.ndarray]:
    """Decode a written MP4 or GIF back to uint8 RGB frames (H, W, 3) (for checks and tests)."""
    fmt = video_format(path)
    if not Path(path).is_file():
        raise InputError("video file not found", path)
    if fmt == "gif":
        from PIL import Image, ImageSequence

        with Image.open(path) as im:
            return [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]
    import cv2

    cap = cv2.VideoCapture(os.fspath(path))
    frames = []
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            frames.append(bgr[..., ::-1].copy())
    finally:
        cap.release()
    return frames
