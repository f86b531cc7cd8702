"""USD splat files: `save_usd(path, gs)` (one prim), `open_output_stage` (a new stage that becomes
the file only when the block ends without an error: atomic; `.usdc` stages page their samples
out with `flush_stage`), `create_stage` (in memory), `validate_stage` (OpenUSD's validators),
and `register()` (the USD suffixes in `gaussians.io`'s dispatch). The prims are written by
`gaussians.usd_prims` and read by `gaussians.usd_read` (`load_usd`).
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, UsdUtils

from avatarkit.errors import InputError, OutputError, last_line
from avatarkit.fileio import atomic_path, temp_prefix
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.usd_prims import DEFAULT_PRIM_PATH, SplatPrimWriter
from avatarkit.gaussians.usd_read import load_usd

USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")

def create_stage(up_axis: str = "Y", meters_per_unit: float = 1.0, fps: float | None = None,
                 start: float | None = None, end: float | None = None) -> Usd.Stage:
    """An in-memory stage with our metadata: `upAxis`, `metersPerUnit` and, for animation,
    `timeCodesPerSecond` = `framesPerSecond` = fps and start/end time codes."""
    return _init_stage(Usd.Stage.CreateInMemory(), up_axis, meters_per_unit, fps, start, end)


@dataclass
class UsdWriteOptions:
    """How `save_usd` writes: stage up axis, prim path, half-precision attributes."""

    up_axis: str = "Y"
    prim_path: str = DEFAULT_PRIM_PATH
    half: bool = False


def _check_usd_extension(path: Path):
    if path.suffix.lower() not in USD_EXTENSIONS:
        raise OutputError(f"unknown USD extension {path.suffix!r}; use one of {', '.join(USD_EXTENSIONS)}", path)


def _init_stage(stage: Usd.Stage, up_axis: str, meters_per_unit: float, fps, start, end) -> Usd.Stage:
    up_axis = str(up_axis).upper()
    if up_axis not in ("Y", "Z"):
        raise InputError(f"up axis must be Y or Z, got {up_axis!r}")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up_axis == "Y" else UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    if fps is not None:
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"fps must be a positive number, got {fps}")
        stage.SetTimeCodesPerSecond(float(fps))
        stage.SetFramesPerSecond(float(fps))
    if start is not None:
        stage.SetStartTimeCode(float(start))
    if end is not None:
        stage.SetEndTimeCode(float(end))
    return stage


@contextlib.contextmanager
def open_output_stage(path: str | os.PathLike, *, up_axis: str = "Y", meters_per_unit: float = 1.0,
                      fps: float | None = None, start: float | None = None, end: float | None = None,
                      comment: str | None = None) -> Iterator[Usd.Stage]:
    """A new stage that becomes the file `path` when the block ends without an error.

    `.usd`/`.usdc` (and the layer inside a `.usdz`) are file-backed crate layers: call
    `flush_stage(stage)` every few frames and the samples written so far leave memory.
    `.usda` stages live in memory until exported. Written atomically; on an error nothing is
    left under `path`.
    """
    path = Path(path)
    _check_usd_extension(path)
    ext = path.suffix.lower()
    # scratch (a .usdz's layer) beside the target, where a re-run sweeps one a killed run left
    with atomic_path(path) as tmp, tempfile.TemporaryDirectory(prefix=temp_prefix(path.name),
                                                               dir=tmp.parent) as scratch:
        if ext == ".usda":
            stage = Usd.Stage.CreateInMemory()
        else:
            target = Path(scratch) / (Tf.MakeValidIdentifier(path.stem) + ".usdc") if ext == ".usdz" else tmp
            try:
                stage = Usd.Stage.CreateNew(str(target))
            except Tf.ErrorException as e:  # a full disk as the new layer is first written
                raise OutputError(f"could not write the USD file ({_write_error(e)})", path) from None
            if stage is None:
                raise OutputError("could not create the USD layer", path)
        _init_stage(stage, up_axis, meters_per_unit, fps, start, end)
        layer = stage.GetRootLayer()
        if comment:
            layer.comment = comment
        try:
            yield stage
        except OutputError as e:
            raise e.with_path(path) from None
        try:
            if ext == ".usda":
                ok = layer.Export(str(tmp))
            else:
                ok = layer.Save(force=True)
                if ok and ext == ".usdz":
                    ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(layer.realPath), str(tmp))
        except Tf.ErrorException as e:  # a full disk: OpenUSD reports the failed write this way
            raise OutputError(f"could not write the USD file ({_write_error(e)})", path) from None
        if not ok:
            raise OutputError("could not write the USD file", path)


def _write_error(e: Exception) -> str:
    """The first line of a Tf error about a failed write (the OS's reason is in it)."""
    text = last_line(e, "write failed")
    try:
        lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    except Exception:  # noqa: BLE001 - undecodable text
        return text
    for ln in lines:
        if "writing file" in ln or "Failed to write" in ln:
            return ln.rsplit(":", 1)[-1].strip(" '")
    return text


def flush_stage(stage: Usd.Stage) -> None:
    """Save a file-backed stage so the time samples written so far are paged out of memory."""
    if not stage.GetRootLayer().anonymous:
        try:
            stage.Save()
        except Tf.ErrorException as e:  # the caller's `open_output_stage` names the file
            raise OutputError(f"could not write the USD file ({_write_error(e)})") from None


def save_usd(path: str | os.PathLike, gs: GaussianSet, options: UsdWriteOptions | None = None) -> None:
    """Write one GaussianSet as a single-prim USD file (atomically)."""
    options = options or UsdWriteOptions()
    with open_output_stage(path, up_axis=options.up_axis, comment="written by avatarkit") as stage:
        SplatPrimWriter(stage, options.prim_path, half=options.half).write(gs)


def validate_stage(stage_or_path) -> list[str]:
    """Run every registered `UsdValidation` validator; return the error messages (warnings skipped)."""
    from pxr import UsdValidation

    stage = stage_or_path if isinstance(stage_or_path, Usd.Stage) else Usd.Stage.Open(str(stage_or_path))
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    return [f"{e.GetValidator().GetMetadata().name if e.GetValidator() else '?'}: {e.GetMessage()}"
            for e in context.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]


def register() -> None:
    """Add the USD extensions to `avatarkit.gaussians.io`'s dispatch tables."""
    from avatarkit.gaussians import io

    for ext in USD_EXTENSIONS:
        io.register_format(ext, loader=load_usd, saver=save_usd)


__all__ = ["USD_EXTENSIONS", "UsdWriteOptions", "create_stage", "flush_stage", "open_output_stage", "register",
           "save_usd", "validate_stage"]
