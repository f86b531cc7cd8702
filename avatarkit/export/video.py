"""Preview clips: frame sequences as H.264 MP4 (PyAV) or GIF (Pillow), streamed and atomic.

    with VideoWriter("turntable.mp4", fps=24) as video:
        for camera in cameras:
            video.append(render(gaussians, camera).rgb)

Frames are (H, W, 3) RGB, float in [0, 1] or uint8, all one size.

MP4 is H.264 (libx264 from PyAV's FFmpeg), 4:2:0 (`yuv420p`), BT.709 colours tagged in the
stream, `moov` atom first (`+faststart`): what browsers, chat apps and review tools play.
`crf` sets the quality (0 lossless luma .. 51 worst; 18 looks transparent, +6 halves the size;
default 20). 4:2:0 needs an even width and height: an odd one is *padded* by repeating the last
row / column, so no rendered pixel is lost and the video is at most one pixel wider / taller
than the frames. Only when PyAV is not installed does the writer fall back to OpenCV's MPEG-4
Part 2 (`mp4v`, which browsers do not play) with one `Mp4vFallbackWarning`.
GIF frames are quantised to a palette each and loop forever.

Nothing appears under the requested name unless the whole clip was written and checked: the
clip goes to a temporary name beside it, is read back (its `moov` atom and every frame's packet
are there), then renamed. A full disk (ENOSPC) or any other write failure is an OutputError
naming the file, and the temporary file is removed.
"""
from __future__ import annotations

import contextlib
import errno
import os
import sys
import warnings
from fractions import Fraction
from pathlib import Path
from typing import Iterable

import numpy as np

from avatarkit.errors import InputError, OutputError
from avatarkit.export.images import to_uint8
from avatarkit.fileio import atomic_path

VIDEO_EXTENSIONS = (".mp4", ".gif")
DEFAULT_CRF = 20
# x264's speed/size trade-off: our frames come from a CPU renderer that is far slower than any
# preset, and "veryfast" reaches the same PSNR as "medium" at a similar size in a third of the time.
DEFAULT_PRESET = "veryfast"
X264_PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow",
                "slower", "veryslow")


class Mp4vFallbackWarning(UserWarning):
    """PyAV is missing, so an MP4 was written as MPEG-4 Part 2 through OpenCV."""


MP4V_FALLBACK_MESSAGE = ("PyAV is not installed: writing MPEG-4 Part 2 ('mp4v'), which browsers "
                         "do not play; `pip install av` for H.264")


def video_format(path: str | os.PathLike) -> str:
    """"mp4" or "gif" from the file name; OutputError for anything else."""
    ext = Path(path).suffix.lower()
    if ext not in VIDEO_EXTENSIONS:
        raise OutputError(f"unknown video extension {ext or '(none)'!r}; use .mp4 or .gif", path)
    return ext[1:]


def even_size(width: int, height: int) -> tuple[int, int]:
    """The (width, height) of the H.264 picture that holds a width x height frame (4:2:0 needs
    both even; we pad by one)."""
    return width + width % 2, height + height % 2


def pad_to_even(img: np.ndarray) -> np.ndarray:
    """img: (H, W, 3) -> (H + H % 2, W + W % 2, 3), the last row / column repeated (an edge of
    repeated pixels does not bleed a seam of another colour into the picture when subsampled)."""
    h, w = img.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return img
    return np.pad(img, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


@contextlib.contextmanager
def _silenced_stderr():
    """OpenCV's FFmpeg logs its complaints ("moov atom not found") on the process's stderr,
    which would break the CLI's one-line errors; our own checks report the failure."""
    fd = 2  # C libraries write to descriptor 2 whatever sys.stderr is
    with contextlib.suppress(AttributeError, OSError, ValueError):
        sys.stderr.flush()
    try:
        saved = os.dup(fd)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _write_failure(exc: OSError, path: Path) -> OutputError:
    """An OSError met while writing `path` as the one-line error the CLI reports."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOSPC:
        return OutputError("disk full while writing the video (nothing was written)", path)
    if code == errno.EDQUOT:
        return OutputError("disk quota exceeded while writing the video (nothing was written)", path)
    reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return OutputError(f"cannot write the video: {reason}", path)


def _open_output(path: Path):
    """The file object the MP4 muxer and the GIF encoder write through. Python file I/O (not
    FFmpeg's) so that every failed write (a full disk, a dropped network mount) surfaces as an
    OSError here; tests replace this to inject one."""
    return open(path, "w+b")


class _H264Encoder:
    """libx264 through PyAV into an MP4 on an open file object."""

    def __init__(self, fileobj, size: tuple[int, int], fps: float, crf: int, preset: str):
        import av

        self.width, self.height = even_size(*size)
        self.container = av.open(fileobj, mode="w", format="mp4",
                                 options={"movflags": "+faststart"})
        try:
            rate = Fraction(fps).limit_denominator(1001 * 1000)
            stream = self.container.add_stream("libx264", rate=rate)
            stream.width, stream.height = self.width, self.height
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(crf), "preset": preset}
            cc = stream.codec_context
            # Say which RGB -> YUV matrix we used (BT.709, limited range): players that guess
            # pick BT.601 for small pictures and shift the colours.
            cc.colorspace, cc.color_range, cc.color_primaries, cc.color_trc = 1, 1, 1, 1
            self.stream = stream
        except BaseException:
            self.container.close()
            raise
        self.next_pts = 0

    def encode(self, img: np.ndarray) -> None:
        import av
        from av.video.reformatter import ColorRange, Colorspace

        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(pad_to_even(img)), format="rgb24")
        frame = frame.reformat(format="yuv420p", dst_colorspace=Colorspace.ITU709,
                               dst_color_range=ColorRange.MPEG, dst_color_trc=1, dst_color_primaries=1)
        frame.pts = self.next_pts
        self.next_pts += 1
        self.container.mux(self.stream.encode(frame))

    def finish(self) -> None:
        self.container.mux(self.stream.encode())  # flush the frames x264 holds back
        self.container.close()

    def discard(self) -> None:
        with contextlib.suppress(Exception):
            self.container.close()


def check_mp4(path: str | os.PathLike, frames: int, codec: str) -> None:
    """Raise OutputError unless `path` is an MP4 whose first video stream has codec `codec` and
    `frames` packets (demuxed only, nothing decoded: a file cut short has no index and fails)."""
    import av

    try:
        with av.open(os.fspath(path)) as c:
            if not c.streams.video:
                raise OutputError("the written MP4 has no video stream", path)
            stream = c.streams.video[0]
            name = stream.codec_context.name
            count = sum(1 for p in c.demux(stream) if p.size > 0)
    except av.FFmpegError as e:
        raise OutputError(f"the written MP4 does not read back ({e})", path) from None
    if name != codec or count != frames:
        raise OutputError(f"the written MP4 reads back as {count} {name} frames, not {frames} {codec}",
                          path)


class VideoWriter:
    """Append frames one at a time; the file is complete (and renamed into place) on `close()`
    or when the `with` block ends without an exception (then the partial file is removed).

    `codec` is the MP4 codec used ("h264", or "mp4v" when PyAV is missing), "gif" for GIFs;
    `size` is (width, height) of the frames once the first is in; `stored_size` the picture
    size in the file (even for H.264, see `pad_to_even`).
    """

    def __init__(self, path: str | os.PathLike, fps: float = 24.0, crf: int | None = None,
                 preset: str | None = None):
        crf = DEFAULT_CRF if crf is None else crf
        preset = DEFAULT_PRESET if preset is None else preset
        self.path = Path(path)
        self.format = video_format(path)
        try:
            self.fps = float(fps)
        except (TypeError, ValueError):
            raise InputError(f"fps must be a number, got {fps!r}") from None
        if not (np.isfinite(self.fps) and 0 < self.fps <= 1000):
            raise InputError(f"fps must be > 0 and <= 1000, got {fps!r}")
        if isinstance(crf, bool) or not isinstance(crf, (int, np.integer)) or not 0 <= crf <= 51:
            raise InputError(f"crf must be an integer from 0 (best) to 51 (worst), got {crf!r}")
        if preset not in X264_PRESETS:
            raise InputError(f"unknown x264 preset {preset!r}; use one of {', '.join(X264_PRESETS)}")
        self.crf, self.preset = int(crf), preset
        self.codec = "gif"
        if self.format == "mp4":
            try:
                import av  # noqa: F401
                self.codec = "h264"
            except ImportError:
                self.codec = "mp4v"
                warnings.warn(Mp4vFallbackWarning(MP4V_FALLBACK_MESSAGE), stacklevel=2)
        self.frame_count = 0
        self.size: tuple[int, int] | None = None
        self._atomic = atomic_path(self.path)
        self._tmp = self._atomic.__enter__()
        self._file = None
        self._encoder: _H264Encoder | None = None
        self._cv_writer = None
        self._gif_frames: list = []
        self._closed = False

    @property
    def stored_size(self) -> tuple[int, int] | None:
        if self.size is None or self.codec != "h264":
            return self.size
        return even_size(*self.size)

    # --- frames -----------------------------------------------------------------------------
    def append(self, frame: np.ndarray) -> None:
        """Add one frame (H, W, 3) RGB, float [0, 1] or uint8."""
        if self._closed:
            raise OutputError("video already closed", self.path)
        img = to_uint8(frame)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] == 0 or img.shape[1] == 0:
            raise InputError(f"video frames must have shape (H, W, 3), got {np.shape(frame)}")
        size = (img.shape[1], img.shape[0])
        try:
            if self.size is None:
                self.size = size
                if self.format == "mp4":
                    self._open_mp4(size)
            elif size != self.size:
                raise InputError(f"frame {self.frame_count} is {size[0]}x{size[1]}, the video is "
                                 f"{self.size[0]}x{self.size[1]}")
            if self._encoder is not None:
                self._encoder.encode(img)
            elif self._cv_writer is not None:
                with _silenced_stderr():
                    self._cv_writer.write(np.ascontiguousarray(img[..., ::-1]))
            else:
                from PIL import Image

                # adaptive palette per frame; dithering off keeps turntables from shimmering
                self._gif_frames.append(Image.fromarray(img).quantize(
                    colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE))
        except OSError as e:
            err = _write_failure(e, self.path)
            self._abort(err)
            raise err from None
        self.frame_count += 1

    def extend(self, frames: Iterable[np.ndarray]) -> None:
        for f in frames:
            self.append(f)

    def _open_mp4(self, size: tuple[int, int]) -> None:
        if self.codec == "h264":
            self._file = _open_output(self._tmp)
            self._encoder = _H264Encoder(self._file, size, self.fps, self.crf, self.preset)
            return
        import cv2

        with _silenced_stderr():
            writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, size)
        if not writer.isOpened():
            writer.release()
            raise OutputError("OpenCV cannot encode MP4 (mp4v) here; install PyAV (`pip install av`)",
                              self.path)
        self._cv_writer = writer

    # --- finishing --------------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file, check it, and move it into place."""
        if self._closed:
            return
        try:
            if self.frame_count == 0:
                raise InputError("a video needs at least one frame", self.path)
            try:
                self._finish()
            except OSError as e:
                raise _write_failure(e, self.path) from None
        except BaseException as e:
            self._abort(e)
            raise
        self._closed = True
        self._gif_frames = []
        self._atomic.__exit__(None, None, None)

    def _finish(self) -> None:
        if self._encoder is not None:
            encoder, self._encoder = self._encoder, None
            try:
                encoder.finish()
            except BaseException:
                encoder.discard()
                raise
            file, self._file = self._file, None
            file.close()  # flushes the last buffered bytes: may itself fail on a full disk
            check_mp4(self._tmp, self.frame_count, "h264")
        elif self._cv_writer is not None:
            with _silenced_stderr():
                self._cv_writer.release()
                self._cv_writer = None
                # OpenCV reports no write errors: read the file back
                complete = _count_cv2_frames(self._tmp) == self.frame_count
            if not complete:
                raise OutputError("the MP4 was not completely written (is the disk full?)", self.path)
        else:
            first, *rest = self._gif_frames
            with _open_output(self._tmp) as f:
                first.save(f, format="GIF", save_all=True, append_images=rest,
                           duration=max(1, round(1000.0 / self.fps)), loop=0, optimize=False)
            if self._tmp.stat().st_size == 0:
                raise OutputError("the GIF was not written", self.path)

    def _abort(self, exc: BaseException) -> None:
        if self._closed:
            return
        self._closed = True
        if self._encoder is not None:
            self._encoder.discard()
            self._encoder = None
        if self._file is not None:
            with contextlib.suppress(OSError):
                self._file.close()
            self._file = None
        if self._cv_writer is not None:
            self._cv_writer.release()
            self._cv_writer = None
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


def _count_cv2_frames(path: Path) -> int:
    import cv2

    cap = cv2.VideoCapture(os.fspath(path))
    n = 0
    try:
        while cap.grab():
            n += 1
    finally:
        cap.release()
    return n


def write_video(path: str | os.PathLike, frames: Iterable[np.ndarray], fps: float = 24.0,
                crf: int | None = None) -> int:
    """Write all `frames` (an iterable: rendered lazily, one at a time) -> number of frames."""
    crf = DEFAULT_CRF if crf is None else crf
    with VideoWriter(path, fps, crf=crf) as video:
        video.extend(frames)
    return video.frame_count


def read_video_frames(path: str | os.PathLike) -> list[np.ndarray]:
    """Decode a written MP4 or GIF back to uint8 RGB frames (H, W, 3) (for checks and tests).

    MP4s are read with `avatarkit.video` (PyAV), or OpenCV where PyAV is missing."""
    fmt = video_format(path)
    if not Path(path).is_file():
        raise InputError("video file not found", path)
    if fmt == "gif":
        from PIL import Image, ImageSequence

        with Image.open(path) as im:
            return [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]
    try:
        import av  # noqa: F401
    except ImportError:
        return _read_cv2(path)
    from avatarkit.video import open_video

    with open_video(path) as video:
        return [f.rgb for f in video]


def _read_cv2(path) -> list[np.ndarray]:
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

