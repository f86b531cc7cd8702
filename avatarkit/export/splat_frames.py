"""Read any bake output back as frames of splat parts: `open_splat_frames(path) -> SplatFrames`.

What a player or a converter of baked splats needs, from any of:
- a bake's USD stage (`.usd/.usda/.usdc/.usdz`, one file or chunked into value clips): every
  `ParticleField3DGaussianSplat` prim is a part (the bake's /Avatar/Face and /Avatar/Hair),
  frames are the integer time codes from the stage's start to its end (or the positions'
  time samples when no range is authored; a stage without samples is one frame);
- a PLY sequence folder with the bake's `sequence.json` (merged files split on their `part`
  extra into face and hair; split files read per part), or any folder of PLY files (natural
  order, one part, `fps` from the caller);
- an avatar folder (its bald and hair Gaussians at rest: one frame);
- one splat file (`.ply`, `.spz`, or a USD file as above).

Everything comes back in our frame (metres, +Y up, the face toward +Z): the project's readers
(`gaussians.usd`, `gaussians.ply`, `gaussians.spz`) do that conversion; this module only walks
frames and parts. Opacities and SH are taken from the first frame (a bake writes them once);
means, quaternions and scales are read per frame, one frame in memory at a time. `frames()`
can be iterated more than once (each pass reads the files again).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from avatarkit.errors import AvatarKitError, FormatError, InputError
from avatarkit.gaussians.gaussian_set import GaussianSet

USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")
SPLAT_FILE_EXTENSIONS = (".ply", ".spz") + USD_EXTENSIONS
#: frame rate of a folder of PLY files that carries none of its own
DEFAULT_FPS = 24.0

#: one part at one frame: (means (N, 3), quats (N, 4) wxyz, scales (N, 3)), float32
PartFrame = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass
class SplatFrames:
    """A splat animation: parts with fixed counts, `n_frames` frames at `fps`.

    rest: part name -> its GaussianSet at the first frame (opacities and SH hold for every frame).
    kind: what was read ("usd stage", "ply sequence", "ply folder", "avatar", "splat file").
    """

    source: Path
    kind: str
    fps: float
    n_frames: int
    rest: dict[str, GaussianSet]
    _frames: Callable[[], Iterator[dict[str, PartFrame]]]

    def frames(self) -> Iterator[dict[str, PartFrame]]:
        """One dict part -> (means, quats, scales) per frame, in order."""
        return self._frames()

    @property
    def sh_degree(self) -> int:
        return max((g.sh_degree for g in self.rest.values()), default=0)

    @property
    def count(self) -> int:
        return sum(len(g) for g in self.rest.values())


def open_splat_frames(path: str | os.PathLike, fps: float | None = None) -> SplatFrames:
    """Open a bake's USD stage, a PLY sequence folder, an avatar folder or one splat file.

    fps: the frame rate of a folder of PLY files without a sidecar (default 24); ignored where
    the input carries its own.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("not found", path)
    if path.is_dir():
        from avatarkit.avatar import is_avatar_folder
        from avatarkit.export.ply_sequence import SIDECAR

        if is_avatar_folder(path):
            return _avatar(path)
        if (path / SIDECAR).is_file():
            return _ply_sequence(path)
        return _ply_folder(path, fps)
    ext = path.suffix.lower()
    if ext in USD_EXTENSIONS:
        return _usd(path)
    if ext in (".ply", ".spz"):
        from avatarkit.convert import ConvertOptions, load_any

        gs = load_any(path, ConvertOptions())
        return _static(path, "splat file", {"splats": gs})
    if path.name == "sequence.json":
        return _ply_sequence(path.parent)
    raise InputError(f"cannot view a {path.suffix or 'extensionless'} file; give a bake's USD stage "
                     f"or PLY folder, an avatar folder, or a splat file ({', '.join(SPLAT_FILE_EXTENSIONS)})",
                     path)


def _static(path: Path, kind: str, rest: dict[str, GaussianSet]) -> SplatFrames:
    rest = {k: v for k, v in rest.items() if len(v)}
    if not rest:
        raise FormatError("holds no splats", path)

    def frames():
        yield {k: (g.means, g.quats, g.scales) for k, g in rest.items()}

    return SplatFrames(path, kind, DEFAULT_FPS, 1, rest, frames)


def _avatar(path: Path) -> SplatFrames:
    from avatarkit.avatar import PART_BALD, load_rest_splats

    gs = load_rest_splats(path)
    part = gs.extras["part"]
    rest = {"bald": gs.subset(part == PART_BALD), "hair": gs.subset(part != PART_BALD)}
    return _static(path, "avatar", {k: v.replace(extras={}) for k, v in rest.items()})


# --- USD ---------------------------------------------------------------------------------------
def _usd(path: Path) -> SplatFrames:
    from avatarkit.gaussians.usd_read import find_splat_prims, open_usd_stage, read_splat_prim, to_metres_y_up

    stage = open_usd_stage(path)
    prims = find_splat_prims(stage)
    if not prims:
        raise FormatError("has no ParticleField3DGaussianSplat prim", path)
    names = _unique_names([p.GetName() for p in prims])
    times = _usd_times(stage, prims)

    def read(prim, t, world=True) -> GaussianSet:
        try:
            gs = read_splat_prim(prim, t)
            return to_metres_y_up(stage, prim, gs, t) if world and len(gs) else gs
        except AvatarKitError as e:
            raise e.with_path(path) from None

    rest = {n: read(p, times[0]) for n, p in zip(names, prims)}
    rest = {n: g for n, g in rest.items() if len(g)}
    if not rest:
        raise FormatError("its splat prims hold no splats", path)
    live = [(n, p) for n, p in zip(names, prims) if n in rest]

    def frames():
        for t in times:
            out = {}
            for n, p in live:
                gs = read(p, t)
                if len(gs) != len(rest[n]):
                    raise FormatError(f"splat prim {p.GetPath()} has {len(gs)} splats at time {t:g} but "
                                      f"{len(rest[n])} at the first frame; a player needs a fixed count", path)
                out[n] = (gs.means, gs.quats, gs.scales)
            yield out

    fps = float(stage.GetTimeCodesPerSecond()) or DEFAULT_FPS
    kind = "usd stage" if len(times) > 1 else "splat file"
    return SplatFrames(path, kind, fps, len(times), rest, frames)


def _usd_times(stage, prims) -> list[float | None]:
    """Integer time codes start..end when the stage has a range, else the positions' samples."""
    if stage.HasAuthoredTimeCodeRange():
        start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
        if end >= start:
            return [float(t) for t in np.arange(start, end + 0.5, 1.0)]
    samples: set[float] = set()
    for prim in prims:
        for name in ("positions", "positionsh"):
            attr = prim.GetAttribute(name)
            if attr:
                samples.update(attr.GetTimeSamples())
    return sorted(samples) if samples else [None]


def _unique_names(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        key = n.lower()
        seen[key] = seen.get(key, 0) + 1
        out.append(key if seen[key] == 1 else f"{key}{seen[key]}")
    return out


# --- PLY -----------------------------------------------------------------------------------------
def _read_ply(path: Path, decoder: str) -> GaussianSet:
    from avatarkit.gaussians.ply import read_ply

    try:
        return read_ply(path, decoder=decoder)
    except AvatarKitError as e:
        raise e.with_path(path) from None


def _ply_sequence(folder: Path) -> SplatFrames:
    from avatarkit.export.ply_sequence import PART_IDS, read_sidecar
    from avatarkit.gaussians.ply import sequence_decoder

    doc = read_sidecar(folder)
    if doc["frame_count"] < 1:
        raise FormatError("the sequence has no frames", folder / "sequence.json")
    files = doc["files"]
    if isinstance(files, dict):
        groups = {part: [folder / n for n in names] for part, names in files.items()}
    else:
        groups = {"frame": [folder / n for n in files]}
    for paths in groups.values():
        for p in paths:
            if not p.is_file():
                raise InputError("file listed in sequence.json is missing", p)
    decoder = sequence_decoder([p for paths in groups.values() for p in paths])

    def split(gs: GaussianSet, name: str, path: Path) -> dict[str, GaussianSet]:
        if name != "frame":
            return {name: gs.replace(extras={})}
        part = gs.extras.get("part")
        if part is None:
            return {"splats": gs.replace(extras={})}
        out = {}
        for pname, pid in PART_IDS.items():
            sel = part == pid
            if sel.any():
                out[pname] = gs.subset(sel).replace(extras={})
        unknown = ~np.isin(part, list(PART_IDS.values()))
        if unknown.any():
            raise FormatError(f"{int(unknown.sum())} splats have a part id other than "
                              f"{sorted(PART_IDS.values())}", path)
        return out

    def read_frame(i: int) -> dict[str, GaussianSet]:
        out = {}
        for name, paths in groups.items():
            out.update(split(_read_ply(paths[i], decoder), name, paths[i]))
        return out

    rest = {k: v for k, v in read_frame(0).items() if len(v)}
    if not rest:
        raise FormatError("the sequence holds no splats", folder)

    def frames():
        for i in range(doc["frame_count"]):
            parts = rest if i == 0 else read_frame(i)
            for name, gs in parts.items():
                if name in rest and len(gs) != len(rest[name]):
                    raise FormatError(f"{name} has {len(gs)} splats in frame {i} but {len(rest[name])} "
                                      "in the first; a player needs a fixed count", folder)
            yield {k: (parts[k].means, parts[k].quats, parts[k].scales) for k in rest}

    return SplatFrames(folder, "ply sequence", float(doc["fps"]), int(doc["frame_count"]), rest, frames)


def _ply_folder(folder: Path, fps: float | None) -> SplatFrames:
    from avatarkit.convert import resolve_inputs
    from avatarkit.gaussians.ply import sequence_decoder

    paths = resolve_inputs(folder)
    decoder = sequence_decoder(paths)
    first = _read_ply(paths[0], decoder).replace(extras={})
    if not len(first):
        raise FormatError("holds no splats", paths[0])
    rest = {"splats": first}

    def frames():
        for i, p in enumerate(paths):
            gs = first if i == 0 else _read_ply(p, decoder)
            if len(gs) != len(first):
                raise FormatError(f"has {len(gs)} splats but {paths[0].name} has {len(first)}; a player "
                                  "needs a fixed count", p)
            yield {"splats": (gs.means, gs.quats, gs.scales)}

    return SplatFrames(folder, "ply folder", float(fps or DEFAULT_FPS), len(paths), rest, frames)


__all__ = ["SplatFrames", "PartFrame", "open_splat_frames", "SPLAT_FILE_EXTENSIONS"]
