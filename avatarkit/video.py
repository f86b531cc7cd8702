"""Video input: the frames of a video file or an image folder, upright, with their timestamps.

One reader for every command that takes a video (`track`, `evaluate`, `build VIDEO --frame N`):

    from avatarkit.video import open_video, resample

    with open_video("talk.mov") as video:             # or open_video("frames/", fps=30)
        video.info              # VideoInfo: width, height (upright), fps, frame_count, duration, ...
        video.times             # (N,) float64 seconds of every frame, the first at 0.0
        for frame in video.frames(start=30, end=90):  # frames 30..89, decoded one at a time
            frame.index, frame.time, frame.rgb        # int, float seconds, (H, W, 3) uint8 upright
        first = video.frame(0)                        # one frame (seeks; no decoding from the start)
        for frame in resample(video.frames(), 25.0):  # a constant 25 fps: frames repeated / dropped
            frame.index, frame.source_index

What it reads
    Video files: whatever PyAV's FFmpeg demuxes and decodes, judged by content, not by name:
    MP4/MOV/M4V, MKV/WebM, AVI, GIF ...; H.264, HEVC, VP8/9, AV1, MPEG-4 Part 2, MJPEG, ProRes ...
    The first video stream is used (cover-art pictures are skipped); audio is ignored.
    Image folders: the image files in it (PNG, JPEG, WebP, TIFF, BMP), sorted by name with numbers
    compared as numbers (`f2.png` before `f10.png`); the caller gives `fps`. Each image is read
    as `recon.image_io.load_image` reads portraits (EXIF orientation applied, transparency on
    white, no downscaling); all must share one size.

Decisions
    - Timing is kept, never silently resampled: `Frame.time` is the frame's presentation time
      in seconds after the first frame, from its own timestamp, so a variable-frame-rate phone
      clip keeps its real timing. `info.fps` is the average rate; `info.variable_frame_rate`
      says whether the spacing varies. `resample` / `resample_indices` give a constant rate
      (nearest frame in time; see there).
    - Rotation is applied as the `ffmpeg` command line applies it: the display matrix (MP4/MOV
      `tkhd` matrix, which phones write instead of turning the pixels; Matroska projection) or
      a legacy `rotate` tag turns and/or mirrors every frame, so frames come out upright and
      `info.width x info.height` is the upright size. Angles that are not a multiple of 90
      degrees are rounded to the nearest one (FFmpeg would rotate with black corners).
    - Memory stays flat in the video's length: opening reads the packet headers once (no
      decoding) to count frames and collect their timestamps (8 bytes a frame), and frames are
      decoded one at a time.
    - Size: frames longer than `MAX_SIDE` (1280 px) on their upright longer side are read
      area-downscaled to it, by every command alike (a phone's 1080x1920 clip at 720x1280);
      `info.width x info.height` is the size read, `info.scale` the factor (session 28).
    - `info.frame_count` counts the stream's packets (after edit lists); a damaged file may
      decode fewer frames, and iteration then simply yields fewer.

Errors (all AvatarKitError naming the file, so the CLI exits 2): a missing or unreadable path,
a file that is not a video, a video without a video stream or without frames, a frame range
outside the video, an image folder without images, without `fps`, or with images of mixed sizes.
"""
from __future__ import annotations

import abc
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from avatarkit.errors import FormatError, InputError

#: frames larger than this on their longer side (upright, px) are read downscaled to it (area
#: averaging, cv2.INTER_AREA, as `recon.image_io.MAX_SIDE` does for photos; `info.width x
#: info.height` is then the size read, `info.scale` the factor); None: full size. A phone's
#: 1080x1920 video at 1280: 720x1280, 0.44x the pixels; every command reads the same frames, so a
#: build, its tracking and `evaluate` agree. The shared 480x480 clips and the benchmark's videos
#: are not reached (session 28, docs/video-build.md "A phone's video: size and time")
MAX_SIDE: int | None = 1280
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".bmp")
#: names `avatarkit inspect` routes here (the reader itself goes by content, not by name)
VIDEO_FILE_EXTENSIONS = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi", ".gif")


@dataclass(frozen=True)
class VideoInfo:
    """What `open_video` found out without decoding more than the first frame."""

    path: Path
    kind: str                   # "video" (a file FFmpeg reads) or "images" (a folder)
    width: int                  # upright (displayed) size in pixels, rotation applied
    height: int
    fps: float                  # frames per second: (N - 1) / span of the timestamps (the caller's for image folders)
    frame_count: int
    duration: float             # seconds: the last frame's time plus one average frame period
    codec: str                  # FFmpeg's decoder name ("h264", "hevc", ...) or "images"
    rotation: int               # degrees the stored picture is turned clockwise to show it: 0/90/180/270
    mirrored: bool              # the display matrix also mirrors the picture (rare)
    variable_frame_rate: bool   # the spacing of the frames' timestamps varies
    scale: float = 1.0          # width read / the file's upright width (`MAX_SIDE`; 1.0: full size)


@dataclass(frozen=True, eq=False)
class Frame:
    """One decoded frame."""

    index: int                  # 0-based position in the video (presentation order)
    time: float                 # seconds after the video's first frame
    rgb: np.ndarray             # (H, W, 3) uint8 RGB, upright
    source_index: int | None = None  # for `resample`d frames: the index of the source frame shown


# --- display matrix ----------------------------------------------------------------------------

def display_transform(matrix) -> tuple[str, int, bool]:
    """The turn that shows a stored picture upright, from its display matrix.

    matrix: 9 int32 (libavutil/display.h: 16.16 fixed point, row-major a b u / c d v / x y w).
    Returns (transform, rotation, mirrored): `transform` is one of "none", "clock", "cclock",
    "cclock_flip", "clock_flip", "hflip", "vflip", "hvflip" (the names of FFmpeg's `transpose`
    and flip filters), `rotation` the clockwise degrees it turns, `mirrored` whether it mirrors.
    Same decisions as the `ffmpeg` command line's autorotation (fftools' `get_rotation` and the
    filters it inserts), so our frames look like ffmpeg's and players'.
    """
    m = [int(v) for v in matrix]
    # av_display_rotation_get (what PyAV's VideoFrame.rotation returns): counter-clockwise degrees
    sx, sy = math.hypot(m[0], m[3]), math.hypot(m[1], m[4])
    if sx == 0 or sy == 0:
        return "none", 0, False
    ccw = -math.degrees(math.atan2(m[1] / sy, m[0] / sx))
    theta = -round(ccw)  # clockwise, as fftools' get_rotation
    theta -= 360 * math.floor(theta / 360 + 0.9 / 360)
    theta = (round(theta / 90) * 90) % 360  # non-right angles: nearest quarter turn (see module doc)
    if theta == 90:
        return ("cclock_flip", 90, True) if m[3] > 0 else ("clock", 90, False)
    if theta == 270:
        return ("clock_flip", 270, True) if m[3] < 0 else ("cclock", 270, False)
    if theta == 180:
        h, v = m[0] < 0, m[4] < 0
        if h and v:
            return "hvflip", 180, False  # both flips are a half turn
        return ("hflip", 0, True) if h else (("vflip", 0, True) if v else ("none", 0, False))
    return ("vflip", 0, True) if m[4] < 0 else ("none", 0, False)


def apply_transform(img: np.ndarray, transform: str) -> np.ndarray:
    """img: (H, W, C) stored picture -> the picture shown, turned as `display_transform` says."""
    if transform == "none":
        return img
    if transform in _CV2_TURNS and img.ndim == 3 and img.shape[2] in (3, 4) and img.dtype == np.uint8:
        # OpenCV's blocked copy: a phone's 1080x1920 portrait frame turns in a few ms, numpy's
        # strided one in ~25 (once per frame per pass over the video; the same pixels)
        import cv2

        return cv2.rotate(np.ascontiguousarray(img), _CV2_TURNS[transform])
    if transform == "clock":
        out = np.rot90(img, -1)
    elif transform == "cclock":
        out = np.rot90(img, 1)
    elif transform == "cclock_flip":  # a quarter turn counter-clockwise, then upside down
        out = img.transpose(1, 0, 2)
    elif transform == "clock_flip":
        out = np.rot90(img, -1)[::-1]
    elif transform == "hflip":
        out = img[:, ::-1]
    elif transform == "vflip":
        out = img[::-1]
    elif transform == "hvflip":
        out = img[::-1, ::-1]
    else:
        raise ValueError(f"unknown display transform {transform!r}")
    return np.ascontiguousarray(out)


#: the quarter and half turns `apply_transform` leaves to OpenCV (cv2.ROTATE_90_CLOCKWISE,
#: ROTATE_90_COUNTERCLOCKWISE, ROTATE_180)
_CV2_TURNS = {"clock": 0, "cclock": 2, "hvflip": 1}


def read_size(width: int, height: int, max_side: int | None = None) -> tuple[int, int]:
    """(width, height) frames of an upright size are read at: at most `max_side` (None:
    `MAX_SIDE`, read now; 0 or None there: full size) on the longer side, the aspect kept."""
    max_side = MAX_SIDE if max_side is None else max_side
    if not max_side or max(width, height) <= max_side:
        return width, height
    k = max_side / max(width, height)
    return max(1, round(width * k)), max(1, round(height * k))


def fit_frame(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """rgb (H, W, C) uint8 at (width, height) `size` (`read_size`): area-averaged where smaller."""
    if (rgb.shape[1], rgb.shape[0]) == tuple(size):
        return rgb
    import cv2

    return cv2.resize(rgb, tuple(size), interpolation=cv2.INTER_AREA)


def _rotate_tag_matrix(tag: str) -> list[int] | None:
    """A legacy `rotate` metadata tag (clockwise degrees) as a display matrix, or None."""
    try:
        degrees = float(tag)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(degrees):
        return None
    a = math.radians(-degrees)  # the matrix holds the counter-clockwise angle
    c, s = round(math.cos(a) * 65536), round(math.sin(a) * 65536)
    return [c, -s, 0, s, c, 0, 0, 0, 1 << 30]


# --- readers ----------------------------------------------------------------------------------

class VideoReader(abc.ABC):
    """Frames of one video file or image folder; made by `open_video`. Use as a context manager
    (or call `close()`); iteration is `frames()`. Each `frames()` / `frame()` call decodes
    independently, so several iterations may run one after another or interleaved."""

    info: VideoInfo
    times: np.ndarray  # (N,) float64 seconds after the first frame, ascending

    def __iter__(self) -> Iterator[Frame]:
        return self.frames()

    def __len__(self) -> int:
        return self.info.frame_count

    def __enter__(self) -> "VideoReader":
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def close(self) -> None:
        """Nothing stays open between calls; kept for the context-manager protocol."""

    def check_range(self, start: int = 0, end: int | None = None) -> tuple[int, int]:
        """(start, end) of frames start..end-1, checked against the video; InputError naming the
        file when the range is empty or reaches outside it (end None: to the last frame)."""
        n = self.info.frame_count
        end = n if end is None else end
        for name, v in (("start", start), ("end", end)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise InputError(f"frame {name} must be an integer, got {v!r}", self.info.path)
        if not 0 <= start < n:
            raise InputError(f"frame {start} is outside the video's {n} frames (0..{n - 1})",
                             self.info.path)
        if not start < end <= n:
            raise InputError(f"frame range {start}..{end - 1} is outside the video's {n} frames "
                             f"or empty", self.info.path)
        return int(start), int(end)

    @abc.abstractmethod
    def frames(self, start: int = 0, end: int | None = None) -> Iterator[Frame]:
        """Frames start..end-1 (end None: to the last), in order, one at a time."""

    def frame(self, index: int) -> Frame:
        """Frame `index` (0-based)."""
        start, _ = self.check_range(index, index + 1)
        for f in self.frames(start, start + 1):
            return f
        raise FormatError(f"frame {index} does not decode", self.info.path)


class _FFmpegVideo(VideoReader):
    def __init__(self, path: Path):
        self.path = path
        container = _open_container(path)
        try:
            stream = _video_stream(container, path)
            self._stream_index = stream.index
            self._time_base = stream.time_base
            pts = _packet_times(container, stream, path)
        finally:
            container.close()
        # presentation order; B-frames make decode order differ
        self._pts = np.sort(pts)  # (N,) int64 in stream time-base units
        self.times = (self._pts - self._pts[0]).astype(np.float64) * float(self._time_base)
        self._index_of = {int(p): i for i, p in enumerate(self._pts)}
        first, transform, rotation, mirrored, codec, rates = self._probe_first_frame()
        self._transform = transform
        h, w = first.shape[:2]
        self._size = read_size(w, h)                     # (width, height) the frames are read at
        n = len(self._pts)
        fps = _average_fps(self.times, rates)
        self.info = VideoInfo(path=path, kind="video", width=self._size[0], height=self._size[1], fps=fps,
                              frame_count=n, duration=float(self.times[-1] + 1.0 / fps), codec=codec,
                              rotation=rotation, mirrored=mirrored,
                              variable_frame_rate=_is_variable(self.times, float(self._time_base)),
                              scale=self._size[0] / w)

    def _open_stream(self):
        container = _open_container(self.path)
        stream = container.streams[self._stream_index]
        stream.thread_type = "AUTO"  # frame threads: several frames decode at once
        return container, stream

    def _probe_first_frame(self):
        import av

        container, stream = self._open_stream()
        try:
            try:
                frame = next(container.decode(stream), None)
            except (av.FFmpegError, OSError) as e:
                raise FormatError(f"the video stream does not decode ({_reason(e)})", self.path) from None
            if frame is None:
                raise FormatError("no frame of the video stream decodes", self.path)
            matrix = _display_matrix(frame)
            if matrix is None:
                # Matroska upper-cases tag names
                tag = next((v for k, v in stream.metadata.items() if k.lower() == "rotate"), None)
                matrix = _rotate_tag_matrix(tag)
            transform, rotation, mirrored = display_transform(matrix) if matrix else ("none", 0, False)
            rgb = apply_transform(frame.to_ndarray(format="rgb24"), transform)
            rates = [stream.average_rate, stream.guessed_rate]
            return rgb, transform, rotation, mirrored, stream.codec_context.name, rates
        finally:
            container.close()

    def frames(self, start: int = 0, end: int | None = None) -> Iterator[Frame]:
        start, end = self.check_range(start, end)
        return self._frames(start, end, seek=start > 0)

    def frames_from_start(self, start: int = 0, end: int | None = None) -> Iterator[Frame]:
        """`frames` decoding everything from the first frame (no seek): the slow obvious
        reference the seeking path is tested against."""
        start, end = self.check_range(start, end)
        return self._frames(start, end, seek=False)

    def _frames(self, start: int, end: int, seek: bool) -> Iterator[Frame]:
        import av

        container, stream = self._open_stream()
        try:
            if seek:
                container.seek(int(self._pts[start]), stream=stream, backward=True, any_frame=False)
            expected = None  # index the next decoded frame has when its own pts is missing
            try:
                for frame in container.decode(stream):
                    idx = self._index_of.get(frame.pts) if frame.pts is not None else None
                    if idx is None:
                        if expected is None:  # no timestamp to place the first frame: start over
                            if seek:
                                yield from self._frames(start, end, seek=False)
                                return
                            expected = 0
                        idx = expected
                    elif expected is not None and idx < expected:  # repeated timestamps
                        idx = expected
                    if seek and expected is None and idx > start:
                        # the seek landed past the frame asked for (a file without a proper
                        # index): decode from the beginning instead
                        yield from self._frames(start, end, seek=False)
                        return
                    expected = idx + 1
                    if idx < start:
                        continue
                    if idx >= end:
                        break
                    rgb = fit_frame(apply_transform(frame.to_ndarray(format="rgb24"), self._transform), self._size)
                    yield Frame(index=idx, time=float(self.times[idx]), rgb=rgb)
            except (av.FFmpegError, OSError) as e:  # FFmpeg errors mid-stream: a damaged file
                raise FormatError(f"the video stops decoding at frame {expected or 0} "
                                  f"({_reason(e)})", self.path) from None
        finally:
            container.close()


class _ImageFolder(VideoReader):
    def __init__(self, path: Path, fps):
        if fps is None:
            raise InputError("an image folder is read as a video at a frame rate you give "
                             "(e.g. --fps 30)", path)
        fps = _check_fps(fps, path)
        try:
            entries = [p for p in path.iterdir()
                       if p.suffix.lower() in IMAGE_EXTENSIONS and not p.name.startswith(".")
                       and p.is_file()]
        except OSError as e:
            raise InputError(f"cannot list the folder ({_reason(e)})", path) from None
        if not entries:
            raise FormatError(f"no image files ({', '.join(IMAGE_EXTENSIONS)}) in the folder", path)
        self.path = path
        self.files = sorted(entries, key=_natural_key)
        n = len(self.files)
        self.times = np.arange(n, dtype=np.float64) / fps
        first = self._load(0)
        h, w = first.shape[:2]
        self._full = (w, h)
        self._size = read_size(w, h)
        self.info = VideoInfo(path=path, kind="images", width=self._size[0], height=self._size[1], fps=fps,
                              frame_count=n, duration=n / fps, codec="images", rotation=0, mirrored=False,
                              variable_frame_rate=False, scale=self._size[0] / w)

    def _load(self, i: int) -> np.ndarray:
        from avatarkit.recon.image_io import load_image

        return load_image(self.files[i], max_side=0).rgb

    def frames(self, start: int = 0, end: int | None = None) -> Iterator[Frame]:
        start, end = self.check_range(start, end)
        return self._frames(start, end)

    def _frames(self, start: int, end: int) -> Iterator[Frame]:
        for i in range(start, end):
            rgb = self._load(i)
            if (rgb.shape[1], rgb.shape[0]) != self._full:
                raise FormatError(f"is {rgb.shape[1]}x{rgb.shape[0]}, the folder's first image is "
                                  f"{self._full[0]}x{self._full[1]}", self.files[i])
            yield Frame(index=i, time=float(self.times[i]), rgb=fit_frame(rgb, self._size))


def open_video(path: str | os.PathLike, fps: float | None = None) -> VideoReader:
    """Open a video file or an image folder (then `fps` is required; for files it must be None:
    a file has its own timing; `resample` changes it). Reads the packet headers and decodes
    the first frame, so a file that is not a video fails here, not mid-way."""
    p = Path(path)
    if not p.exists():
        raise InputError("video file or image folder not found", p)
    if p.is_dir():
        return _ImageFolder(p, fps)
    if fps is not None:
        raise InputError("a frame rate is given only for image folders: a video file has its own "
                         "(use resample() for another)", p)
    if not os.access(p, os.R_OK):
        raise InputError("cannot read the file: permission denied", p)
    return _FFmpegVideo(p)


def read_frame(path: str | os.PathLike, index: int, fps: float | None = None) -> Frame:
    """Frame `index` of a video file or image folder (what `build VIDEO --frame N` needs)."""
    with open_video(path, fps) as video:
        return video.frame(index)


def inspect_video(path: Path):
    """A `Summary` of a video file for `avatarkit inspect`."""
    from avatarkit.inspect import Summary

    with open_video(path) as video:
        info, times = video.info, video.times
    s = Summary("video", str(path))
    s.add("codec", info.codec).add("size", f"{info.width}x{info.height}" if info.scale == 1.0 else
                                   f"{round(info.width / info.scale)}x{round(info.height / info.scale)} "
                                   f"(read at {info.width}x{info.height}, `video.MAX_SIDE`)")
    s.add("frames", info.frame_count).add("fps", round(info.fps, 4))
    s.add("duration (s)", round(info.duration, 4))
    turn = f"{info.rotation} degrees clockwise" if info.rotation else "none"
    s.add("rotation applied", turn + (", mirrored" if info.mirrored else ""))
    if info.variable_frame_rate:
        gaps = np.diff(times) * 1000.0
        s.add("frame rate", f"variable: frames {gaps.min():.1f}..{gaps.max():.1f} ms apart "
                            "(timestamps kept)")
    else:
        s.add("frame rate", "constant")
    return s


# --- constant frame rate ----------------------------------------------------------------------

def resample_indices(times: np.ndarray, fps: float) -> np.ndarray:
    """For a constant-rate grid t_k = times[0] + k / fps over the span of `times`, the index of
    the source frame nearest in time to each t_k (the earlier one on a tie): frames are repeated
    where the source is slower and dropped where it is faster, never blended.

    times: (N,) ascending seconds. Returns (K,) int64, K = floor((times[-1] - times[0]) * fps) + 1.
    """
    times = np.asarray(times, dtype=np.float64)
    if times.ndim != 1 or len(times) == 0:
        raise InputError(f"times must be a non-empty (N,) array, got shape {times.shape}")
    fps = _check_fps(fps)
    k = int(math.floor((times[-1] - times[0]) * fps + 1e-6)) + 1
    grid = times[0] + np.arange(k) / fps
    after = np.clip(np.searchsorted(times, grid, side="left"), 0, len(times) - 1)
    before = np.clip(after - 1, 0, len(times) - 1)
    take_before = np.abs(grid - times[before]) <= np.abs(times[after] - grid)
    return np.where(take_before, before, after).astype(np.int64)


def resample(frames: Iterable[Frame], fps: float) -> Iterator[Frame]:
    """Frames at a constant `fps`, streamed: the same choice as `resample_indices` over the
    frames' times, holding two source frames at a time. Output frame k has index k, time
    t0 + k / fps (t0: the first source frame's time) and `source_index` the frame shown;
    a repeated frame shares its pixel array with the previous output."""
    fps = _check_fps(fps)
    it = iter(frames)
    prev = next(it, None)
    if prev is None:
        return
    t0, k = prev.time, 0
    for cur in it:
        # a grid time up to cur's time has its nearest frame among prev and cur
        while (t := t0 + k / fps) <= cur.time:
            pick = prev if t - prev.time <= cur.time - t else cur
            yield Frame(index=k, time=t, rgb=pick.rgb, source_index=_source(pick))
            k += 1
        prev = cur
    last = int(math.floor((prev.time - t0) * fps + 1e-6))
    while k <= last:
        yield Frame(index=k, time=t0 + k / fps, rgb=prev.rgb, source_index=_source(prev))
        k += 1


def _source(f: Frame) -> int:
    return f.index if f.source_index is None else f.source_index


# --- helpers ----------------------------------------------------------------------------------

def _reason(e: BaseException) -> str:
    return getattr(e, "strerror", None) or str(e) or type(e).__name__


def _check_fps(fps, path=None) -> float:
    try:
        v = float(fps)
    except (TypeError, ValueError):
        raise InputError(f"fps must be a number, got {fps!r}", path) from None
    if not (math.isfinite(v) and 0 < v <= 1000):
        raise InputError(f"fps must be > 0 and <= 1000, got {fps!r}", path)
    return v


def _natural_key(p: Path):
    return [(0, int(t), "") if t.isdigit() else (1, 0, t.lower()) for t in re.split(r"(\d+)", p.name)]


def _open_container(path: Path):
    try:
        import av
    except ImportError:
        raise InputError("reading videos needs PyAV (`pip install av`)", path) from None
    try:
        return av.open(os.fspath(path), mode="r", metadata_errors="ignore")
    except PermissionError:
        raise InputError("cannot read the file: permission denied", path) from None
    except IsADirectoryError:
        raise InputError("is a folder", path) from None
    except (av.FFmpegError, OSError, UnicodeDecodeError, ValueError) as e:
        if _mp4_without_index(path):
            raise FormatError("an MP4/MOV without its index (no 'moov' box): cut short while "
                              "recording or copying?", path) from None
        raise FormatError(f"not a video FFmpeg can read ({_reason(e)})", path) from None


def _mp4_without_index(path: Path) -> bool:
    """Whether `path` starts like an MP4/MOV (an 'ftyp' box) but none of its top-level boxes is
    the 'moov' index, which a recorder writes last. Walks box headers only."""
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            pos, first = 0, True
            while pos + 8 <= size:
                f.seek(pos)
                head = f.read(16)
                n, kind = int.from_bytes(head[:4], "big"), head[4:8]
                if first and kind != b"ftyp":
                    return False
                first = False
                if kind == b"moov":
                    return False
                if n == 1 and len(head) == 16:
                    n = int.from_bytes(head[8:16], "big")
                elif n == 0:  # the box runs to the end of the file
                    break
                if n < 8:
                    return False  # not box structure after all
                pos += n
            return not first
    except OSError:
        return False


def _video_stream(container, path: Path):
    import av

    if not container.streams:
        raise FormatError("not a readable video: no streams found (a file cut short before its "
                          "index?)", path)
    pictures = av.stream.Disposition.attached_pic
    streams = [s for s in container.streams.video if not (s.disposition & pictures)]
    if not streams:
        raise FormatError("has no video stream", path)
    cc = streams[0].codec_context
    if cc is None or not cc.name or not cc.width or not cc.height:
        raise FormatError("the video stream is damaged or cut short: it has no codec or picture "
                          "size", path)
    return streams[0]


class TruncatedVideoWarning(UserWarning):
    """A video file ends before all the frames its index lists."""


def _packet_times(container, stream, path: Path) -> np.ndarray:
    """(N,) int64 pts of every frame's packet (dts where a packet has no pts), read without
    decoding; packets an edit list discards are left out."""
    import av

    pts: list[int] = []
    try:
        for packet in container.demux(stream):
            if packet.size == 0 or packet.is_discard:
                continue
            t = packet.pts if packet.pts is not None else packet.dts
            pts.append(len(pts) if t is None else t)  # no timestamp at all: count (rare)
    except (av.FFmpegError, OSError) as e:
        if not pts:
            raise FormatError(f"not a readable video ({_reason(e)})", path) from None
        # a truncated file: keep the packets before the damage
    if not pts:
        raise FormatError("the video stream has no frames", path)
    listed = int(stream.frames or 0)
    if listed > len(pts):
        warnings.warn(TruncatedVideoWarning(
            f"{path}: the file is cut short: {len(pts)} of the {listed} frames its index lists are "
            "there; reading those"), stacklevel=4)
    return np.asarray(pts, dtype=np.int64)


def _display_matrix(frame) -> list[int] | None:
    from av.sidedata.sidedata import Type

    try:
        data = frame.side_data.get(Type.DISPLAYMATRIX)
    except (AttributeError, KeyError):
        return None
    if data is None:
        return None
    raw = bytes(data)
    if len(raw) < 36:
        return None
    return np.frombuffer(raw[:36], dtype="=i4").tolist()


def _average_fps(times: np.ndarray, rates) -> float:
    """Frames per second over the timestamps ((N - 1) / span: exact for a constant rate, the
    mean rate otherwise). The stream's own rate (e.g. exactly 30000/1001) is used when it agrees
    within 0.5%; containers' rates alone mislead (an AVI of variable timing says 1000 fps, its
    time base; Matroska repeats the rate it was muxed with)."""
    rates = [float(r) for r in rates if r is not None and float(r) > 0 and math.isfinite(float(r))]
    if len(times) > 1 and times[-1] > 0:
        measured = (len(times) - 1) / float(times[-1])
        return next((r for r in rates if abs(r - measured) <= 0.005 * measured), measured)
    return rates[0] if rates else 1.0


def _is_variable(times: np.ndarray, tick: float) -> bool:
    """Whether the frame spacing varies by more than timestamp rounding (two ticks of the time
    base) and 1% of the median spacing."""
    if len(times) < 3:
        return False
    d = np.diff(times)
    tol = max(2.0 * tick, 0.01 * float(np.median(d)))
    return bool(d.max() - d.min() > tol)
