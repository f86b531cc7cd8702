"""`convert`: splats between 3DGS PLY, OpenUSD and SPZ, by file extension; PLY sequences to one USD stage.

One input file -> one output file of any supported format. A folder of PLY files (natural
sort: `f2.ply` before `f10.ply`), or several input files, -> one time-sampled USD stage: frame i
at time code i, `timeCodesPerSecond` = `framesPerSecond` = fps, start 0, end frames-1.
Positions, orientations, scales (+extent) are time samples; opacities and SH are written once
and become time samples only if a frame changes them. Every frame must have the same Gaussian
count and SH degree: a splat prim's per-particle attributes share one count, and a varying
count would defeat USD's interpolation between samples (a clear InputError names the frame).

Axes: USD and SPZ files say theirs (USD's upAxis; SPZ is RUB by its specification, which is
ours), a PLY file does not, so `ply_frame` says which frame PLY files are in: "yup" (ours, the
default) or "ydown" (the 3DGS/COLMAP frame trainers write and splat viewers assume). It applies
to PLY input and output alike (`input_ply_frame` sets the input's apart), so reading a trainer's
y-down PLY and writing SPZ or USD gives an upright result, and `--ply-frame ydown` turns our
files into what viewers expect.
"""
from __future__ import annotations

import math
import os
import re
import time as _time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from avatarkit.errors import AvatarKitError, InputError, OutputError
from avatarkit.limits import MAX_FPS, MIN_FPS
from avatarkit.gaussians.gaussian_set import GaussianSet

PLY_EXTENSIONS = (".ply",)
USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")
SPZ_EXTENSIONS = (".spz",)
KNOWN_EXTENSIONS = PLY_EXTENSIONS + USD_EXTENSIONS + SPZ_EXTENSIONS


@dataclass
class ConvertOptions:
    """What `convert` does beyond picking formats by extension.

    up_axis: "Y" or "Z", the USD output stage's up axis (data are turned +90 degrees about X
        for Z). Only for USD output.
    prim_path: the splat prim to read from a USD input (None: its only splat prim) and the
        prim to write in a USD output (None: /Splats).
    half: write USD's half-precision attributes (positionsh, ...). Only for USD output.
    sh_degree: keep SH bands up to this degree (0..3); None keeps all. Never adds bands.
    fps: frames per second of a sequence stage.
    time: the time code to read a USD input at (None: its earliest sample).
    spz_version: SPZ version to write (2, 3 or 4). The default, 3, is the newest that NVIDIA's
        converter and Niantic's reader as shipped on npm (`@spz-loader/core`) read; 4 (zstd
        streams, needs the zstandard package) is for readers that know it.
    ply_frame: the axes of PLY files written, and read unless input_ply_frame says otherwise:
        "yup" (ours) or "ydown" (the 3DGS/COLMAP frame; see `gaussians.ply`).
    input_ply_frame: the axes of PLY input files (None: ply_frame).
    """

    up_axis: str = "Y"
    prim_path: str | None = None
    half: bool = False
    sh_degree: int | None = None
    fps: float = 24.0
    time: float | None = None
    spz_version: int = 3
    ply_frame: str = "yup"
    input_ply_frame: str | None = None

    @property
    def ply_read_frame(self) -> str:
        """The frame PLY input is read in."""
        return self.ply_frame if self.input_ply_frame is None else self.input_ply_frame

    def check(self) -> None:
        if str(self.up_axis).upper() not in ("Y", "Z"):
            raise InputError(f"up axis must be Y or Z, got {self.up_axis!r}")
        if self.sh_degree is not None and self.sh_degree not in range(4):
            raise InputError(f"SH degree must be 0..3, got {self.sh_degree}")
        if not (isinstance(self.fps, (int, float)) and MIN_FPS <= self.fps <= MAX_FPS):
            raise InputError(f"fps must be a number between {MIN_FPS:g} and {MAX_FPS:g}, got {self.fps}")
        # nan compares false with every sample time: it read as "no sample" and wrote 0 Gaussians
        if self.time is not None and not (isinstance(self.time, (int, float)) and math.isfinite(self.time)):
            raise InputError(f"time code must be a finite number, got {self.time!r}")
        from avatarkit.gaussians.ply import check_ply_frame

        check_ply_frame(self.ply_frame)
        check_ply_frame(self.ply_read_frame)


@dataclass
class ConvertResult:
    """What was written: output path, Gaussians per frame, SH degree, frames, bytes, seconds."""

    output: Path
    count: int
    sh_degree: int
    frames: int
    bytes: int
    seconds: float


def _ext(path: Path) -> str:
    return path.suffix.lower()


def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def resolve_inputs(inputs: str | os.PathLike | Sequence[str | os.PathLike]) -> list[Path]:
    """One file, a folder of PLY files (natural order) or a list of files -> the frame files."""
    items = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs)
    if not items:
        raise InputError("no input given")
    paths = [Path(p) for p in items]
    if len(paths) == 1 and paths[0].is_dir():
        frames = sorted((p for p in paths[0].iterdir() if p.is_file() and _ext(p) in PLY_EXTENSIONS),
                        key=_natural_key)
        if not frames:
            raise InputError("folder holds no .ply files", paths[0])
        return frames
    for p in paths:
        if p.is_dir():
            raise InputError("a folder can only be converted on its own (as a PLY sequence)", p)
        if not p.is_file():
            raise InputError("file not found", p)
        if _ext(p) not in KNOWN_EXTENSIONS:
            raise InputError(f"unknown input format {p.suffix or '(no extension)'!r}; known: "
                             f"{', '.join(KNOWN_EXTENSIONS)}", p)
    return paths


def load_any(path: Path, options: ConvertOptions, ply_decoder: str = "auto") -> GaussianSet:
    """Read one splat file by extension (USD with the options' prim path and time code)."""
    ext = _ext(path)
    if ext in PLY_EXTENSIONS:
        from avatarkit.gaussians.ply import read_ply
        return read_ply(path, decoder=ply_decoder, frame=options.ply_read_frame)
    if ext in SPZ_EXTENSIONS:
        from avatarkit.gaussians.spz import read_spz
        return read_spz(path)
    if ext in USD_EXTENSIONS:
        from avatarkit.gaussians.usd_read import load_usd
        return load_usd(path, prim_path=options.prim_path, time=options.time)
    raise InputError(f"unknown input format {path.suffix or '(no extension)'!r}; known: "
                     f"{', '.join(KNOWN_EXTENSIONS)}", path)


def _reduce(gs: GaussianSet, options: ConvertOptions) -> GaussianSet:
    if options.sh_degree is not None and gs.sh_degree > options.sh_degree:
        return gs.with_sh_degree(options.sh_degree)
    return gs


def _check_output(output: Path, options: ConvertOptions, frames: list[Path]) -> None:
    ext = _ext(output)
    ply_in = any(_ext(p) in PLY_EXTENSIONS for p in frames)
    if options.ply_frame != "yup" and ext not in PLY_EXTENSIONS and not ply_in:
        raise InputError("--ply-frame applies to PLY input or output; neither is PLY here")
    if options.input_ply_frame is not None and not ply_in:
        raise InputError("--input-ply-frame applies to PLY input; no input is PLY here")
    if ext not in KNOWN_EXTENSIONS:
        raise OutputError(f"unknown output format {output.suffix or '(no extension)'!r}; known: "
                          f"{', '.join(KNOWN_EXTENSIONS)}", output)
    if ext not in USD_EXTENSIONS:
        if len(frames) > 1:
            raise OutputError(f"{len(frames)} input frames make a sequence, which only USD holds; "
                              f"write {output.with_suffix('.usdc').name} instead", output)
        if str(options.up_axis).upper() != "Y":
            raise InputError(f"--up-axis applies to USD output only; {ext} files have no up axis")
        if options.half:
            raise InputError(f"--half applies to USD output only, not {ext}")
    if output.is_dir():
        raise OutputError("is a folder, not a file name", output)


def convert(inputs: str | os.PathLike | Sequence[str | os.PathLike], output: str | os.PathLike,
            options: ConvertOptions | None = None,
            progress: Callable[[int, int], None] | None = None) -> ConvertResult:
    """Convert splat files by extension (see the module notes); returns what was written.

    `progress(done, total)` is called after each frame of a sequence.
    """
    t0 = _time.perf_counter()
    options = options or ConvertOptions()
    options.check()
    output = Path(output)
    frames = resolve_inputs(inputs)
    _check_output(output, options, frames)
    ext = _ext(output)
    if len(frames) == 1:
        gs = _reduce(load_any(frames[0], options), options)
        if ext in PLY_EXTENSIONS:
            from avatarkit.gaussians.ply import write_ply
            write_ply(output, gs, frame=options.ply_frame)
        elif ext in SPZ_EXTENSIONS:
            from avatarkit.gaussians.spz import write_spz
            write_spz(output, gs, version=options.spz_version)
        else:
            from avatarkit.gaussians.usd import UsdWriteOptions, save_usd
            from avatarkit.gaussians.usd_prims import DEFAULT_PRIM_PATH
            save_usd(output, gs, UsdWriteOptions(up_axis=options.up_axis.upper(),
                                                 prim_path=options.prim_path or DEFAULT_PRIM_PATH,
                                                 half=options.half))
        if progress:
            progress(1, 1)
        count, degree = len(gs), gs.sh_degree
    else:
        count, degree = _write_sequence(frames, output, options, progress)
    return ConvertResult(output, count, degree, len(frames), output.stat().st_size,
                         _time.perf_counter() - t0)


#: save a file-backed stage after this many bytes of samples, so memory stays bounded
_FLUSH_BYTES = 256 << 20


def _write_sequence(frames: list[Path], output: Path, options: ConvertOptions,
                    progress: Callable[[int, int], None] | None) -> tuple[int, int]:
    from avatarkit.gaussians.ply import sequence_decoder
    from avatarkit.gaussians.usd import flush_stage, open_output_stage
    from avatarkit.gaussians.usd_prims import DEFAULT_PRIM_PATH, SplatPrimWriter

    decoder = sequence_decoder([p for p in frames if _ext(p) in PLY_EXTENSIONS])
    count = degree = 0
    with open_output_stage(output, up_axis=options.up_axis.upper(), fps=options.fps, start=0,
                           end=len(frames) - 1, comment=f"avatarkit convert: {len(frames)} frames") as stage:
        writer = SplatPrimWriter(stage, options.prim_path or DEFAULT_PRIM_PATH, half=options.half)
        pending = 0
        for i, path in enumerate(frames):
            try:
                gs = _reduce(load_any(path, options, decoder), options)
                writer.write(gs, time=i)
            except AvatarKitError as e:
                raise e.with_path(path) from None
            count, degree = len(gs), gs.sh_degree
            pending += len(gs) * 40  # positions, orientations, scales
            if pending > _FLUSH_BYTES:
                flush_stage(stage)
                pending = 0
            if progress:
                progress(i + 1, len(frames))
    return count, degree


__all__ = ["ConvertOptions", "ConvertResult", "convert", "resolve_inputs", "load_any", "KNOWN_EXTENSIONS"]
