"""Load and save GaussianSets by file extension (trimesh-style dispatch tables).

Each format module owns its reader/writer; this module only maps extensions to them. Another
module adds a format with one call, e.g. in `gaussians/spz.py`:

    register_format(".spz", loader=read_spz, saver=write_spz)

A loader or saver may also be given as a "module:function" string, imported on first use, so
a heavy optional dependency (usd-core) is only imported when that format is actually used.
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Callable, Union

from avatarkit.errors import InputError, OutputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.ply import read_ply, write_ply

Loader = Callable[..., GaussianSet]
Saver = Callable[..., None]

_loaders: dict[str, Union[Loader, str]] = {".ply": read_ply}
_savers: dict[str, Union[Saver, str]] = {".ply": write_ply}


def _norm_ext(ext: str) -> str:
    ext = ext.lower()
    return ext if ext.startswith(".") else "." + ext


def register_format(ext: str, loader: Union[Loader, str, None] = None,
                    saver: Union[Saver, str, None] = None) -> None:
    """Make `load_gaussians`/`save_gaussians` handle files ending in `ext` (e.g. ".spz").

    loader(path, **kw) -> GaussianSet; saver(path, gs, **kw) -> None; either may be a
    "module:function" string resolved on first use. Registering again replaces the old one.
    """
    if loader is None and saver is None:
        raise ValueError("register_format needs a loader, a saver or both")
    ext = _norm_ext(ext)
    if loader is not None:
        _loaders[ext] = loader
    if saver is not None:
        _savers[ext] = saver


def _resolve(fn):
    if isinstance(fn, str):
        module, attr = fn.split(":")
        return getattr(importlib.import_module(module), attr)
    return fn


def _suffix(path) -> str:
    suffixes = Path(path).suffixes
    return suffixes[-1].lower() if suffixes else ""


def loadable_extensions() -> list[str]:
    return sorted(_loaders)


def savable_extensions() -> list[str]:
    return sorted(_savers)


def load_gaussians(path: str | os.PathLike, **kw) -> GaussianSet:
    """Read Gaussians from `path`, choosing the reader by extension."""
    ext = _suffix(path)
    if ext not in _loaders:
        raise InputError(f"cannot read Gaussians from a {ext or 'extensionless'!s} file; known "
                         f"formats: {', '.join(loadable_extensions())}", path)
    return _resolve(_loaders[ext])(path, **kw)


def save_gaussians(path: str | os.PathLike, gs: GaussianSet, **kw) -> None:
    """Write `gs` to `path`, choosing the writer by extension."""
    ext = _suffix(path)
    if ext not in _savers:
        raise OutputError(f"cannot write Gaussians as a {ext or 'extensionless'!s} file; known "
                          f"formats: {', '.join(savable_extensions())}", path)
    _resolve(_savers[ext])(path, gs, **kw)


# Formats whose modules import heavy or optional dependencies register lazily by name.
for _ext in (".usd", ".usda", ".usdc", ".usdz"):
    register_format(_ext, loader="avatarkit.gaussians.usd_read:load_usd", saver="avatarkit.gaussians.usd:save_usd")
register_format(".spz", loader="avatarkit.gaussians.spz:read_spz", saver="avatarkit.gaussians.spz:write_spz")

__all__ = ["load_gaussians", "save_gaussians", "register_format", "loadable_extensions",
           "savable_extensions"]
