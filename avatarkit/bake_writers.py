"""The bake's outputs: `make_writer(kind, target, options)` for the three kinds (`WRITER_KINDS`: a USD
stage, a PLY sequence, a preview video), `PreviewWriter` (the CPU renderer's turntable or fixed
view into a video), and the checks and sizes of output paths the CLI and batch use
(`check_output`, `output_bytes`, `usd_clips_folder`). Each writer has the shape `begin(static)`,
`write(frame)`, `close()`, `abort()` that `bake.run_bake` drives.
"""
from __future__ import annotations

import os
from pathlib import Path

from avatarkit.baked import BakeFrame, BakeStatic
from avatarkit.errors import InputError, OutputError
from avatarkit.fileio import check_output_folder


class PreviewWriter:
    """Renders each baked frame (bald + hair) with the CPU splat renderer into an .mp4/.gif.

    The camera frames the head of the first frame (the mesh's bounds, with room for hair around
    it) from the front; with `orbit` it turns once around the head over the clip. Same shape as
    the other bake writers: `begin(static)`, `write(frame)`, `close()`, `abort()`."""

    def __init__(self, path: str | os.PathLike, size: int = 384, orbit: bool = False,
                 background=(1.0, 1.0, 1.0), elevation_deg: float = 5.0, margin: float = 1.3):
        from avatarkit.export.video import video_format

        self.path = Path(path)
        video_format(self.path)  # OutputError for anything but .mp4/.gif
        if int(size) != size or size < 16:
            raise InputError(f"preview size must be an integer >= 16 pixels, got {size!r}")
        self.size, self.orbit, self.background = int(size), bool(orbit), background
        self.elevation_deg, self.margin = float(elevation_deg), float(margin)
        self._video = None
        self._static: BakeStatic | None = None
        self._target = self._distance = None
        self.frames = 0

    def __enter__(self) -> "PreviewWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            self.abort()
        elif self._video is not None:
            self.close()
        return False

    def begin(self, static: BakeStatic) -> None:
        from avatarkit.export.video import VideoWriter

        self._static = static
        self._video = VideoWriter(self.path, fps=static.fps)

    def camera(self, frame: BakeFrame):
        from avatarkit.render import Camera, framing

        if self._target is None:
            v = frame.head_vertices
            self._target, self._distance = framing((v.min(0), v.max(0)), 30.0, self.size, self.size,
                                                   self.margin)
        n = max(self._static.n_frames, 1)
        azimuth = 360.0 * frame.index / n if self.orbit else 0.0
        return Camera.orbit(self._target, azimuth, self.elevation_deg, self._distance, 30.0,
                            self.size, self.size)

    def write(self, frame: BakeFrame) -> None:
        from avatarkit.render import render

        if self._video is None:
            raise InputError("write() needs begin() first")
        s = self._static
        self._video.append(render(frame.person(s), self.camera(frame), self.background).rgb)
        self.frames += 1

    def close(self) -> Path:
        video, self._video = self._video, None
        if video is not None:
            video.close()
        return self.path

    def abort(self) -> None:
        video, self._video = self._video, None
        if video is not None:  # leaving its block with an exception deletes the partial file
            video.__exit__(RuntimeError, RuntimeError("bake aborted"), None)


WRITER_KINDS = ("usd", "ply", "preview")


def make_writer(kind: str, target: str | os.PathLike, options: dict | None = None):
    """The bake writer of one output kind: "usd" -> `UsdStageWriter` (options: the fields of
    `UsdWriteOptions`), "ply" -> `PlySequenceWriter` (split, ply_frame), "preview" -> `PreviewWriter`
    (size, orbit). Options left out take the writer's defaults."""
    options = dict(options or {})
    if kind == "usd":
        from avatarkit.export.usd_stage import UsdStageWriter, UsdWriteOptions

        return UsdStageWriter(target, UsdWriteOptions(**options))
    if kind == "ply":
        from avatarkit.export.ply_sequence import PlySequenceWriter

        return PlySequenceWriter(target, **options)
    if kind == "preview":
        return PreviewWriter(target, **options)
    raise InputError(f"unknown bake output kind {kind!r}; use one of {', '.join(WRITER_KINDS)}")


def check_output(kind: str, path: str | os.PathLike) -> Path:
    """Raise OutputError unless `path` can receive a bake output of `kind` (see `make_writer`):
    a known extension (usd, preview), not a folder (usd, preview) or not a file (ply), and a
    writable folder to go in. Cheap: meant to run before anything is loaded or baked."""
    p = Path(path)
    if kind == "ply":
        if p.exists() and not p.is_dir():
            raise OutputError("is a file, not a folder", p)
        check_output_folder(p if p.exists() else p.parent)
        return p
    if kind == "usd":
        from avatarkit.gaussians.usd import USD_EXTENSIONS as extensions
        what = "USD"
    elif kind == "preview":
        from avatarkit.export.video import VIDEO_EXTENSIONS as extensions
        what = "preview"
    else:
        raise InputError(f"unknown bake output kind {kind!r}; use one of {', '.join(WRITER_KINDS)}")
    if p.suffix.lower() not in extensions:
        raise OutputError(f"unknown {what} extension {p.suffix or '(none)'!r}; use one of "
                          f"{', '.join(extensions)}", p)
    if p.is_dir():
        raise OutputError("is a folder, not a file name", p)
    check_output_folder(p.parent)
    return p


def output_bytes(kind: str, path: str | os.PathLike) -> int:
    """Bytes on disk of a written output: its file or its folder's files, plus for "usd" the
    stage's `<name>_clips/` folder of value-clip layers (not for .usdz, which holds them)."""
    p = Path(path)
    size = _tree_bytes(p)
    clips = usd_clips_folder(p) if kind == "usd" else None
    return size + (_tree_bytes(clips) if clips is not None else 0)


def usd_clips_folder(path: str | os.PathLike) -> Path | None:
    """The `<name>_clips/` folder written beside a USD stage, if there is one."""
    from avatarkit.export.usd_stage import CLIP_FOLDER_SUFFIX

    p = Path(path)
    clips = p.parent / (p.stem + CLIP_FOLDER_SUFFIX)
    return clips if p.suffix.lower() != ".usdz" and clips.is_dir() else None


def _tree_bytes(path: Path) -> int:
    if path.is_dir():
        return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    return path.stat().st_size if path.exists() else 0


__all__ = ["PreviewWriter", "WRITER_KINDS", "check_output", "make_writer", "output_bytes", "usd_clips_folder"]
