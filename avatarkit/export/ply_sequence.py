"""A bake as a folder of 3DGS PLY files, one per frame, plus a `sequence.json` sidecar.

    with PlySequenceWriter("frames/", split=False) as ply:
        ply.begin(static)
        for frame in frames:
            ply.write(frame)

Files (INRIA property order, binary little endian, via `gaussians.ply.write_ply`):
- merged (default): `frame_00000.ply ...`, face then hair Gaussians in one file with an extra
  property `part` (0 face, 1 hair), a float (0.0, 1.0) so every column of the row is a
  float32 and readers that map rows as float arrays (gsply and others) read it; SH padded to
  the higher degree of the two. `split_parts` gives a merged frame's face and hair back, from
  a float or an integer `part` (earlier avatarkit versions wrote uchar);
- `split=True`: `face_00000.ply` and `hair_00000.ply` per frame, no extras.
`ply_frame` ("yup", ours, or "ydown", the 3DGS/COLMAP frame splat viewers assume for PLY;
see `gaussians.ply`) picks the axes every file is written in; the sidecar says which.
A bake without hair (a hairless avatar) writes the face only: merged files hold just the face
Gaussians (all `part` 0), split writes no hair files, and the sidecar lists the face part only.
The number is the frame's `index` (its USD time code). Other extras (e.g. `binding`) are not
written: they describe the rig, not the splats a viewer shows.

`sequence.json` (written last, atomically): format/version, fps, frame count, frame indices,
parts (count, SH degree, part id), file names, `ply_frame` ("yup"/"ydown"; absent in
older sidecars: "yup"), provenance.

Frames are written into a hidden `.frames.partial-<host>-<pid>-*` folder inside the target
folder (one left by a killed bake is removed by the next, `fileio.make_temp_folder`) and moved into
place by `close()`, so a failed or interrupted bake leaves the folder as it was (an older
sequence there stays whole). `close()` removes the files of an older sequence's sidecar that
the new one does not reuse.
"""
from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from avatarkit.baked import BakeFrame, BakeStatic, StreamingWriter, check_fps
from avatarkit.errors import AvatarKitError, FormatError, InputError, OutputError
from avatarkit.fileio import atomic_path, json_loads, make_temp_folder
from avatarkit.gaussians import GaussianSet
from avatarkit.gaussians.ply import check_ply_frame, write_ply

SIDECAR = "sequence.json"
FORMAT_NAME = "avatarkit.ply-sequence"
FORMAT_VERSION = 1
PART_IDS = {"face": 0, "hair": 1}


@dataclass(frozen=True)
class PlySequenceResult:
    """What `close()` wrote."""

    folder: Path
    sidecar: Path
    frames: int
    files: int
    bytes: int


def frame_name(prefix: str, index: int) -> str:
    return f"{prefix}_{index:05d}.ply"


class PlySequenceWriter(StreamingWriter):
    """Streams a bake into per-frame PLY files; `begin`, `write` per frame, `close` (or `abort`)."""

    def __init__(self, folder: str | os.PathLike, split: bool = False, ply_frame: str = "yup"):
        self.folder = Path(folder)
        self.split = bool(split)
        self.ply_frame = check_ply_frame(ply_frame)
        self._tmp: Path | None = None
        self._created_folder = False
        self._state = "new"
        self._static: BakeStatic | None = None
        self._merged: GaussianSet | None = None   # static attributes of the merged file
        self._parts: dict[str, int] = dict(PART_IDS)  # the parts written (no hair without hair)
        self._indices: list[int] = []
        self._bytes = 0

    @property
    def sidecar(self) -> Path:
        return self.folder / SIDECAR

    def begin(self, static: BakeStatic) -> None:
        """Create the folder (if needed) and the temporary folder inside it."""
        if self._state != "new":
            raise InputError("begin() must be called once, before write()")
        check_fps(static.fps)
        if self.folder.exists() and not self.folder.is_dir():
            raise OutputError("is a file, not a folder", self.folder)
        try:
            if not self.folder.exists():
                self.folder.mkdir(parents=True)
                self._created_folder = True
            self._tmp = make_temp_folder(self.folder / "frames", inside=False)
        except OSError as e:
            raise OutputError(f"cannot write to this folder ({e.strerror})", self.folder) from None
        self._state = "open"
        self._static = static
        self._parts = {p: i for p, i in PART_IDS.items() if p == "face" or len(getattr(static, p))}
        if not self.split:
            face = static.face.replace(extras={"part": np.full(len(static.face), PART_IDS["face"], np.float32)})
            hair = static.hair.replace(extras={"part": np.full(len(static.hair), PART_IDS["hair"], np.float32)})
            self._merged = GaussianSet.concat([face, hair])

    def write(self, frame: BakeFrame) -> None:
        """Write one frame's file(s) into the temporary folder. Indices must increase."""
        if self._state != "open":
            raise InputError("write() needs begin() first and no close()/abort() before it")
        if not isinstance(frame.index, (int, np.integer)) or isinstance(frame.index, bool):
            raise InputError(f"frame index must be an integer, got {frame.index!r}")
        if self._indices and frame.index <= self._indices[-1]:
            raise InputError(f"frames must come in increasing index order; {frame.index} follows "
                             f"{self._indices[-1]}")
        for part in PART_IDS:
            want, got = len(getattr(self._static, part)), len(np.asarray(getattr(frame, part).means))
            if got != want:
                raise InputError(f"frame {frame.index}: {part} has {got} Gaussians but the bake's static "
                                 f"data has {want}")
        try:
            if self.split:
                for part in self._parts:
                    gs = frame.gaussians(self._static, part).replace(extras={})
                    self._write(frame_name(part, frame.index), gs)
            else:
                parts = (frame.face, frame.hair)
                gs = self._merged.replace(means=np.concatenate([p.means for p in parts]),
                                          quats=np.concatenate([p.quats for p in parts]),
                                          scales=np.concatenate([p.scales for p in parts]))
                self._write(frame_name("frame", frame.index), gs)
        except AvatarKitError as e:
            raise type(e)(f"frame {frame.index}: {e.message}", e.path) from None
        except ValueError as e:  # concatenating parts of the wrong shape
            raise InputError(f"frame {frame.index}: {e}") from None
        self._indices.append(int(frame.index))

    def _write(self, name: str, gs: GaussianSet) -> None:
        try:
            write_ply(self._tmp / name, gs, frame=self.ply_frame)
        except OSError as e:
            raise OutputError(f"could not write {name} ({e.strerror})", self.folder) from None
        except OutputError as e:  # named the temporary file: name the folder asked for
            raise OutputError(f"could not write {name} ({e.message})", self.folder) from None
        self._bytes += (self._tmp / name).stat().st_size

    def _files(self) -> dict[str, list[str]]:
        prefixes = list(self._parts) if self.split else ["frame"]
        return {p: [frame_name(p, i) for i in self._indices] for p in prefixes}

    def close(self) -> PlySequenceResult:
        """Move the frames into the folder, then write `sequence.json`."""
        if self._state != "open":
            raise InputError("close() needs begin() first and no earlier close()/abort()")
        try:
            if not self._indices:
                raise InputError("no frames were written; a bake needs at least one", self.folder)
            files = self._files()
            old = _old_files(self.sidecar)
            # the old sidecar goes first: from here on the folder is not a complete old sequence
            if self.sidecar.exists():
                self.sidecar.unlink()
            for names in files.values():
                for name in names:
                    os.replace(self._tmp / name, self.folder / name)
            s = self._static
            parts = {p: {"gaussians": len(getattr(s, p)), "sh_degree": getattr(s, p).sh_degree, "part": i}
                     for p, i in self._parts.items()}
            doc = {
                "format": FORMAT_NAME, "version": FORMAT_VERSION, "layout": "3dgs-inria-ply",
                "fps": float(s.fps), "frame_count": len(self._indices), "frames": self._indices,
                "split": self.split, "parts": parts, "ply_frame": self.ply_frame,
                "files": files if self.split else files["frame"],
                "provenance": s.provenance or {},
            }
            with atomic_path(self.sidecar) as tmp:
                tmp.write_text(json.dumps(doc, indent=1, default=str) + "\n")
            keep = {n for names in files.values() for n in names}
            for name in old - keep:
                (self.folder / name).unlink(missing_ok=True)
        except OSError as e:
            self.abort()
            raise OutputError(f"could not finish the PLY sequence ({e.strerror})", self.folder) from None
        except BaseException:
            self.abort()
            raise
        self._state = "closed"
        shutil.rmtree(self._tmp, ignore_errors=True)
        n_files = sum(len(v) for v in files.values())
        return PlySequenceResult(self.folder, self.sidecar, len(self._indices), n_files, self._bytes)

    def abort(self) -> None:
        """Delete the frames written so far; the folder is left as it was."""
        self._state = "closed"
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
        if self._created_folder:
            try:
                self.folder.rmdir()  # only if still empty
            except OSError:
                pass


def _old_files(sidecar: Path) -> set[str]:
    """File names an existing sidecar lists (plain names only; anything unreadable: none)."""
    try:
        doc = read_sidecar(sidecar)
    except (InputError, OSError):
        return set()
    files = doc["files"]
    names = [n for v in files.values() for n in v] if isinstance(files, dict) else files
    return {n for n in names if isinstance(n, str) and Path(n).name == n and n.endswith(".ply")}


def read_sidecar(path: str | os.PathLike) -> dict:
    """Read and check a `sequence.json` (or the folder holding one); FormatError names what is wrong."""
    path = Path(path)
    if path.is_dir():
        path = path / SIDECAR
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        doc = json_loads(path.read_text(), path)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise FormatError(f"not valid JSON ({e})", path) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        raise FormatError(f"not an avatarkit PLY-sequence sidecar (format is not {FORMAT_NAME!r})", path)
    if doc.get("version") != FORMAT_VERSION:
        raise FormatError(f"unsupported sidecar version {doc.get('version')!r} (this avatarkit reads "
                          f"{FORMAT_VERSION})", path)
    need = {"fps": (int, float), "frame_count": int, "frames": list, "split": bool, "parts": dict,
            "files": (list, dict)}
    for key, kind in need.items():
        if not isinstance(doc.get(key), kind):
            raise FormatError(f"{key!r} is missing or has the wrong type", path)
    files = doc["files"]
    lists = list(files.values()) if isinstance(files, dict) else [files]
    for names in lists:
        if not isinstance(names, list) or len(names) != doc["frame_count"] or \
                not all(isinstance(n, str) for n in names):
            raise FormatError(f"'files' must list {doc['frame_count']} file names per part", path)
    if doc.get("ply_frame", "yup") not in ("yup", "ydown"):
        raise FormatError(f"'ply_frame' is {doc['ply_frame']!r}, expected 'yup' or 'ydown'", path)
    if len(doc["frames"]) != doc["frame_count"]:
        raise FormatError(f"'frames' has {len(doc['frames'])} entries but frame_count is {doc['frame_count']}", path)
    return doc


def split_parts(gs: GaussianSet, path: str | os.PathLike | None = None) -> dict[str, GaussianSet]:
    """A merged frame's Gaussians by part: {"face": ..., "hair": ...} (no hair key when none),
    each without the `part` extra. `part` may be float (what we write) or any integer type
    (older files); FormatError (naming `path`) when it is missing or holds another value."""
    part = gs.extras.get("part")
    if part is None or np.asarray(part).ndim != 1:
        raise FormatError("no 'part' property: not a merged avatarkit frame", path)
    part = np.asarray(part)
    ids = {name: np.flatnonzero(part == i) for name, i in PART_IDS.items()}
    if sum(len(v) for v in ids.values()) != len(part):
        bad = part[~np.isin(part, list(PART_IDS.values()))][0].item()
        raise FormatError(f"'part' holds {bad!r}; merged frames use {PART_IDS}", path)
    rest = {k: v for k, v in gs.extras.items() if k != "part"}
    out = {}
    for name, rows in ids.items():
        if name == "face" or len(rows):
            out[name] = GaussianSet(gs.means[rows], gs.quats[rows], gs.scales[rows], gs.opacities[rows],
                                    gs.sh[rows], {k: v[rows] for k, v in rest.items()})
    return out


# --- inspection ------------------------------------------------------------------------------
def inspect_ply_sequence(path: Path):
    """Summary of a PLY-sequence folder (or its sequence.json): fps, frames, parts, files, size,
    and whether every listed file is there with the expected Gaussian count (first frame)."""
    from avatarkit.gaussians.ply_header import read_ply_header
    from avatarkit.inspect import ByteCount, Summary

    path = Path(path)
    doc = read_sidecar(path)
    folder = path if path.is_dir() else path.parent
    s = Summary("PLY sequence", str(folder))
    s.add("fps", doc["fps"]).add("frames", doc["frame_count"])
    if doc["frames"]:
        s.add("frame range", [doc["frames"][0], doc["frames"][-1]])
    s.add("layout", "split (face_*.ply, hair_*.ply)" if doc["split"] else "merged (frame_*.ply, extra 'part')")
    s.add("PLY frame", {"yup": "yup (avatarkit: +Y up)", "ydown": "ydown (3DGS/COLMAP: y down, z forward)"}
          [doc.get("ply_frame", "yup")])
    s.add("parts", [{"name": name, **{k: v for k, v in p.items() if isinstance(v, (int, float, str))}}
                    for name, p in doc["parts"].items() if isinstance(p, dict)])
    files = doc["files"]
    groups = files if isinstance(files, dict) else {"frame": files}
    names = [n for v in groups.values() for n in v]
    present = [n for n in names if (folder / n).is_file()]
    s.add("files", len(names))
    if names:
        s.add("first file", names[0]).add("last file", names[-1])
    s.add("total size", ByteCount(sum((folder / n).stat().st_size for n in present)))
    missing = [n for n in names if n not in set(present)]
    s.add("missing files", missing if missing else "none")
    counts = {p: v.get("gaussians") for p, v in doc["parts"].items() if isinstance(v, dict)}
    checks = []
    for prefix, group in groups.items():
        if group and (folder / group[0]).is_file():
            want = sum(c for c in counts.values() if isinstance(c, int)) if prefix == "frame" else counts.get(prefix)
            element = read_ply_header(folder / group[0]).element("vertex")
            got = element.count if element is not None else 0
            note = "" if want in (None, got) else f" (sidecar says {want:,})"
            checks.append(f"{group[0]}: {got:,} Gaussians{note}")
    if checks:
        s.add("first frame", checks)
    if doc.get("provenance"):
        s.add("provenance", json.dumps(doc["provenance"], sort_keys=True, default=str))
    return s


__all__ = ["PlySequenceWriter", "PlySequenceResult", "read_sidecar", "inspect_ply_sequence", "frame_name",
           "split_parts",
           "SIDECAR", "PART_IDS"]
