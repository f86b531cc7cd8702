"""The animated OpenUSD stage of a bake: `UsdStageWriter(path, options)`.

    with UsdStageWriter("clip.usdc", UsdWriteOptions(half=True)) as usd:
        usd.begin(static)
        for frame in frames:
            usd.write(frame)
    # leaving the block calls close(); an exception calls abort()

Stage layout (metres, +Y up, frame i at time code i, `timeCodesPerSecond` = `framesPerSecond` = fps):

    /Avatar   Xform, defaultPrim, kind = component
      Head    Mesh: static triangles, time-sampled points and smooth normals
              (`primvars:normals`, see `UsdWriteOptions.head_normals`), subdivisionScheme none,
              constant skin displayColor; without `head_normals` no normals and
              subdivisionScheme loop (the renderer makes the smooth surface)
      Face    ParticleField3DGaussianSplat (bald head splats)  } positions, orientations, scales
      Hair    ParticleField3DGaussianSplat (hair splats)       } time-sampled; opacities, SH static
      Cage    Mesh, purpose guide, time-sampled points and uniform (per-face) normals: a
              flat-shaded polyhedron, the shape the hair's mean value coordinates follow
    every boundable prim has an `extent` sample per frame; provenance in the root layer's
    customLayerData["avatarkit"].

A bake without hair (a hairless avatar: `BakeStatic.hair` has 0 Gaussians and no cage faces)
has no Hair and no Cage prim.

With `usd_points`, Face and Hair are `UsdGeom.Points` instead (see `PointsPrimWriter`).

Memory: a bake longer than `chunk_frames` writes its samples into one crate layer per chunk,
`<name>_clips/chunk_00000.usdc ...`, stitched onto /Avatar as value clips (`Usd.ClipsAPI`:
assetPaths, active, times (identity), primPath, manifestAssetPath = `<name>_clips/manifest.usda`);
the root file holds topology and static attributes only, and *declares* every animated
attribute with its type (no value: a default in the anchoring layer would hide the clips), so
readers without the splat schema (OpenUSD < 26.3) still list, interpolate and flatten them. Each chunk also holds the first frame of
the next one, so motion interpolates across chunk boundaries. A chunk layer is saved when full
(and every `flush_bytes` of samples), then released. A shorter bake writes one self-contained
file. `.usdz` packages the root layer and its clip layers (`UsdUtils.CreateNewUsdzPackage`).

Everything is built in a sibling temporary folder `.<name>.partial-<host>-<pid>-<random>/`
(`fileio.make_temp_folder`: one left by a killed bake is removed by the next); `close()` moves
the clips folder and then the root file into place, `abort()` deletes the folder.

An existing `<name>_clips` is replaced only if a bake wrote it: a folder holding our marker file
`.avatarkit-clips` and nothing but chunk layers and the manifest. Anything else of that name (the
user's folder, a plain file, a link, the clip folder being baked) is refused before the bake
starts (`check_clips_folder`), and checked again just before the replacement.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Kind, Sdf, Tf, Usd, UsdGeom, UsdUtils, UsdVol, Vt

from avatarkit.baked import BakeFrame, BakeStatic, StreamingWriter, check_fps
from avatarkit.errors import AvatarKitError, InputError, OutputError, last_line
from avatarkit.fileio import make_temp_folder, write_failed
from avatarkit.gaussians.usd import USD_EXTENSIONS, validate_stage
from avatarkit.gaussians.usd_prims import (PointsPrimWriter, SplatPrimWriter, bounding_box, check_frame_arrays,
                                           declare_attributes)
from avatarkit.gaussians.usd_read import attribute_value, find_splat_prims, open_usd_stage, usd_errors
from avatarkit.head.regions import vertex_normals

ROOT_PATH = "/Avatar"
HEAD_PATH, FACE_PATH, HAIR_PATH, CAGE_PATH = (f"{ROOT_PATH}/{n}" for n in ("Head", "Face", "Hair", "Cage"))
#: sRGB-ish skin tone for the head mesh's displayColor, and a light blue for the guide cage
SKIN_COLOR = (0.80, 0.62, 0.52)
CAGE_COLOR = (0.35, 0.65, 0.95)
CLIP_FOLDER_SUFFIX = "_clips"
#: written into every `<name>_clips/` folder we make: what lets a later bake replace it
CLIPS_MARKER = ".avatarkit-clips"
_CLIPS_ENTRY = re.compile(r"^(chunk_\d{5,}\.usdc|manifest\.usda|\.avatarkit-clips)$")


def clips_folder_for(path: str | os.PathLike) -> Path:
    """`<name>_clips/` beside the stage `path`: where a long bake's value-clip layers go."""
    path = Path(path)
    return path.parent / (path.stem + CLIP_FOLDER_SUFFIX)


def check_clips_folder(clips_dir: str | os.PathLike) -> None:
    """OutputError unless `clips_dir` is absent or a value-clip folder a bake wrote (the marker
    `.avatarkit-clips` and nothing but chunk layers and the manifest): a bake never replaces
    what it did not create."""
    clips_dir = Path(clips_dir)
    if not os.path.lexists(clips_dir):
        return
    advice = "move it away or choose another -o"
    if clips_dir.is_symlink() or not clips_dir.is_dir():
        raise OutputError(f"a long bake writes its value clips here, and this {'link' if clips_dir.is_symlink() else 'file'} "
                          f"was not made by avatarkit; {advice}", clips_dir)
    if not (clips_dir / CLIPS_MARKER).is_file():
        raise OutputError(f"a long bake writes its value clips here, and this folder was not made by "
                          f"avatarkit bake (no {CLIPS_MARKER} marker); {advice}", clips_dir)
    foreign = sorted(e.name for e in os.scandir(clips_dir)
                     if not (_CLIPS_ENTRY.match(e.name) and e.is_file(follow_symlinks=False)))
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise OutputError(f"this value-clip folder also holds files avatarkit did not write ({shown}); "
                          f"{advice}", clips_dir)


@dataclass
class UsdWriteOptions:
    """How `UsdStageWriter` writes a bake.

    half: half-precision splat attributes (`positionsh`, `orientationsh`, `scalesh`, ...;
        with usd_points: quath orientations, half3 scales and SH). Meshes stay float.
    usd_points: Face and Hair as `UsdGeom.Points` (+ orientations, widths, colour, opacity,
        scale and SH primvars) for tools that do not read the splat schema yet.
    chunk_frames: frames per value-clip layer; a bake of at most this many frames (or 0/None)
        is written as one layer.
    head_normals: time-sampled smooth normals on the head mesh (subdivision scheme none):
        `primvars:normals`, faceVarying and indexed by the faces' vertex indices, so its values
        are the area-weighted vertex normals (V per frame, as vertex interpolation would
        store) and the index array is written once. (Plain vertex interpolation holds the same
        data, but NVIDIA's NormalsValidChecker counts the points at the default time, which an
        animated mesh does not have, and fails it.) False writes no normals and declares the
        head a Loop subdivision surface instead, so the renderer smooths it; either satisfies
        validators that want one or the other on every mesh (NVIDIA's NormalsExistChecker).
    flush_bytes: save the layer receiving samples after this many bytes of them, so memory
        stays bounded inside a chunk too.
    """

    half: bool = False
    usd_points: bool = False
    chunk_frames: int | None = 50
    head_normals: bool = True
    flush_bytes: int = 128 << 20

    def check(self) -> None:
        if self.chunk_frames is not None and (not isinstance(self.chunk_frames, (int, np.integer))
                                              or self.chunk_frames < 0):
            raise InputError(f"chunk_frames must be a non-negative integer or None, got {self.chunk_frames!r}")
        if not (isinstance(self.flush_bytes, (int, np.integer)) and self.flush_bytes > 0):
            raise InputError(f"flush_bytes must be a positive integer, got {self.flush_bytes!r}")


@dataclass(frozen=True)
class UsdStageResult:
    """What `close()` wrote."""

    path: Path                 # the stage to open
    clips_dir: Path | None     # `<name>_clips/` when the samples live in value clips
    frames: int
    first_frame: int
    last_frame: int
    bytes: int                 # on disk, clip layers included


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit face normals (F, 3) float32 of a triangle mesh; (0, 0, 0) for a degenerate face.

    vertices: (V, 3); faces: (F, 3) int, counter-clockwise seen from outside.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0).astype(np.float32)


def _box(points: np.ndarray) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(bounding_box(points))


def _vt_dict(value):
    """A JSON-able value -> something a VtDictionary (customLayerData) stores faithfully.

    Lists become typed arrays when uniform (str, bool, int, float); mixed or nested lists become
    JSON text, since untyped lists do not survive a USD file. A key whose value is None is left
    out (VtDictionary has no null; the text "null" would read back as a string)."""
    if isinstance(value, dict):
        return {str(k): _vt_dict(v) for k, v in value.items() if v is not None}
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value) if -2**63 <= int(value) < 2**63 else str(int(value))
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, str):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, (list, tuple, np.ndarray)):
        items = list(np.asarray(value).tolist() if isinstance(value, np.ndarray) else value)
        if items and all(isinstance(x, str) for x in items):
            return Vt.StringArray(items)
        if items and all(isinstance(x, bool) for x in items):
            return Vt.BoolArray(items)
        if items and all(isinstance(x, int) and not isinstance(x, bool) and -2**31 <= x < 2**31 for x in items):
            return Vt.IntArray(items)
        if items and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in items):
            return Vt.DoubleArray([float(x) for x in items])
    return json.dumps(value, default=str)


# --- the prims of one layer ----------------------------------------------------------------
class _Prims:
    """The /Avatar prims on one stage (the root, or a chunk layer that only takes samples)."""

    def __init__(self, stage: Usd.Stage, options: UsdWriteOptions, hair: bool = True):
        """hair: False leaves the Hair and Cage prims out (a hairless avatar)."""
        self.options = options
        self.avatar = UsdGeom.Xform.Define(stage, ROOT_PATH)
        stage.SetDefaultPrim(self.avatar.GetPrim())
        self.head = UsdGeom.Mesh.Define(stage, HEAD_PATH)
        splat = PointsPrimWriter if options.usd_points else SplatPrimWriter
        self.face = splat(stage, FACE_PATH, half=options.half)
        self.hair = splat(stage, HAIR_PATH, half=options.half) if hair else None
        self.cage = UsdGeom.Mesh.Define(stage, CAGE_PATH) if hair else None
        # normals are declared (type, interpolation) on every layer; readers use the root's
        self.normals = None
        if options.head_normals:
            self.normals = UsdGeom.PrimvarsAPI(self.head).CreatePrimvar(
                UsdGeom.Tokens.normals, Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.faceVarying)
        self.cage_normals = None
        if self.cage is not None:
            self.cage_normals = self.cage.CreateNormalsAttr()
            self.cage.SetNormalsInterpolation(UsdGeom.Tokens.uniform)

    def write_static(self, static: BakeStatic) -> None:
        Usd.ModelAPI(self.avatar.GetPrim()).SetKind(Kind.Tokens.component)
        head_scheme = UsdGeom.Tokens.none if self.normals is not None else UsdGeom.Tokens.loop
        for mesh, faces, color, scheme in ((self.head, static.head_faces, SKIN_COLOR, head_scheme),
                                           (self.cage, static.cage_faces, CAGE_COLOR, UsdGeom.Tokens.none)):
            if mesh is None:
                continue
            mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
            mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1).astype(np.int32)))
            mesh.CreateSubdivisionSchemeAttr(scheme)
            mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([color]))
            # every attribute value clips animate is declared on the root layer (module notes)
            declare_attributes([mesh.GetPointsAttr(), mesh.GetExtentAttr()])
        if self.normals is not None:
            self.normals.SetIndices(Vt.IntArray.FromNumpy(static.head_faces.reshape(-1).astype(np.int32)))
        self.face.write_static(static.face)
        if self.hair is not None:
            self.cage.CreatePurposeAttr(UsdGeom.Tokens.guide)
            self.hair.write_static(static.hair)

    def write_frame(self, frame: BakeFrame, static: BakeStatic) -> None:
        t = Usd.TimeCode(float(frame.index))
        with Sdf.ChangeBlock():
            for mesh, points in ((self.head, frame.head_vertices), (self.cage, frame.cage_vertices)):
                if mesh is None:
                    continue
                p = np.ascontiguousarray(points, np.float32)
                mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(p), t)
                mesh.GetExtentAttr().Set(_box(p), t)
            if self.normals is not None:
                self.normals.Set(Vt.Vec3fArray.FromNumpy(vertex_normals(frame.head_vertices, static.head_faces).astype(np.float32)), t)
            if self.cage_normals is not None:
                self.cage_normals.Set(Vt.Vec3fArray.FromNumpy(face_normals(frame.cage_vertices, static.cage_faces)), t)
            for writer, part in ((self.face, frame.face), (self.hair, frame.hair)):
                if writer is None:
                    continue
                writer.write_samples(frame.index, part.means, part.quats, part.scales)


def _frame_bytes(frame: BakeFrame, options: UsdWriteOptions) -> int:
    """Roughly what one frame's samples weigh (for flushing)."""
    per_splat = 10 * (2 if options.half else 4) + (8 if options.usd_points else 0)
    return 12 * ((1 + options.head_normals) * len(frame.head_vertices) + 3 * len(frame.cage_vertices)) \
        + per_splat * (len(frame.face.means) + len(frame.hair.means))


def _save(layer_or_stage, path: Path) -> None:
    try:
        ok = layer_or_stage.Save()
    except Tf.ErrorException as e:
        raise OutputError(f"could not write the USD layer ({last_line(e)})", path) from None
    if ok is False:
        raise OutputError("could not write the USD layer", path)


# --- the writer -----------------------------------------------------------------------------
class UsdStageWriter(StreamingWriter):
    """Streams a bake into an animated USD stage; `begin`, `write` per frame, `close` (or `abort`).

    Nothing appears under `path` (nor `<name>_clips/`) until `close()` succeeds. See the module
    notes for the layout and the files written.
    """

    def __init__(self, path: str | os.PathLike, options: UsdWriteOptions | None = None):
        self.path = Path(path)
        self.options = options or UsdWriteOptions()
        self.options.check()
        ext = self.path.suffix.lower()
        if ext not in USD_EXTENSIONS:
            raise OutputError(f"unknown USD extension {self.path.suffix or '(none)'!r}; use one of "
                              f"{', '.join(USD_EXTENSIONS)}", self.path)
        self._ext = ext
        self._clips_name = self.path.stem + CLIP_FOLDER_SUFFIX
        self._tmp: Path | None = None
        self._state = "new"           # new -> open -> closed
        self._static: BakeStatic | None = None
        self._root: Usd.Stage | None = None
        self._root_prims: _Prims | None = None
        self._use_clips = False
        self._chunk: tuple[Usd.Stage, _Prims] | None = None
        self._chunk_paths: list[str] = []     # asset paths relative to the root layer
        self._chunk_starts: list[int] = []    # first frame index of each chunk
        self._manifest: Sdf.Layer | None = None
        self._frames = 0
        self._first: int | None = None
        self._last: int | None = None
        self._in_chunk = 0
        self._pending = 0
        self._vertex_counts: tuple[int, int] | None = None

    @property
    def clips_dir(self) -> Path:
        return clips_folder_for(self.path)

    def begin(self, static: BakeStatic) -> None:
        """Create the temporary folder and the root layer with every static attribute."""
        if self._state != "new":
            raise InputError("begin() must be called once, before write()")
        _check_static(static)
        folder = self.path.parent if str(self.path.parent) else Path(".")
        if not folder.is_dir():
            raise OutputError("output folder does not exist", folder)
        if self.path.is_dir():
            raise OutputError("is a folder, not a file name", self.path)
        use_clips = bool(self.options.chunk_frames) and static.n_frames > self.options.chunk_frames
        if use_clips and self._ext != ".usdz":
            check_clips_folder(self.clips_dir)  # before any work: never replace what we did not make
        self._tmp = make_temp_folder(self.path)
        self._state = "open"
        try:
            self._static = static
            self._use_clips = use_clips
            root_name = (Tf.MakeValidIdentifier(self.path.stem) + ".usdc") if self._ext == ".usdz" else self.path.name
            self._root = self._new_stage(self._tmp / root_name)
            UsdGeom.SetStageUpAxis(self._root, UsdGeom.Tokens.y)
            UsdGeom.SetStageMetersPerUnit(self._root, 1.0)
            self._root.SetFramesPerSecond(float(static.fps))
            self._root.SetStartTimeCode(0.0)
            self._root.SetEndTimeCode(float(max(static.n_frames - 1, 0)))
            from avatarkit import __version__
            layer = self._root.GetRootLayer()
            layer.comment = "avatarkit bake"
            layer.customLayerData = {"avatarkit": _vt_dict({
                "writer": f"avatarkit {__version__}", "fps": float(static.fps),
                "provenance": dict(static.provenance or {})})}
            self._root_prims = _Prims(self._root, self.options, has_hair(static))
            self._root_prims.write_static(static)
            if self._use_clips:
                (self._tmp / self._clips_name).mkdir()
                (self._tmp / self._clips_name / CLIPS_MARKER).write_text(
                    f"value clips of {self.path.name}, written by avatarkit bake\n")
        except BaseException:
            self.abort()
            raise

    def _new_stage(self, path: Path) -> Usd.Stage:
        try:
            stage = Usd.Stage.CreateNew(str(path))
        except Tf.ErrorException:
            stage = None
        if stage is None:
            raise OutputError("could not create the USD layer", path)
        stage.SetTimeCodesPerSecond(float(self._static.fps))
        return stage

    def write(self, frame: BakeFrame) -> None:
        """Author one frame's samples. Frames must come in increasing `index` order."""
        if self._state != "open":
            raise InputError("write() needs begin() first and no close()/abort() before it")
        try:
            self._check_frame(frame)
            if not self._use_clips:
                self._root_prims.write_frame(frame, self._static)
                self._account(frame, self._root)
            else:
                if self._chunk is not None and self._in_chunk == self.options.chunk_frames:
                    # the next chunk's first frame closes this one, so values interpolate across
                    self._chunk[1].write_frame(frame, self._static)
                    self._finish_chunk()
                if self._chunk is None:
                    self._start_chunk(frame.index)
                self._chunk[1].write_frame(frame, self._static)
                self._in_chunk += 1
                self._account(frame, self._chunk[0])
        except AvatarKitError as e:
            raise type(e)(f"frame {frame.index}: {e.message}", e.path) from None
        self._frames += 1
        self._first = frame.index if self._first is None else self._first
        self._last = frame.index

    def _account(self, frame: BakeFrame, stage: Usd.Stage) -> None:
        self._pending += _frame_bytes(frame, self.options)
        # text layers are written whole on every save: only crate layers page samples out
        if self._pending >= self.options.flush_bytes and \
                not stage.GetRootLayer().realPath.lower().endswith(".usda"):
            _save(stage, self.path)
            self._pending = 0

    def _start_chunk(self, index: int) -> None:
        name = f"chunk_{len(self._chunk_paths):05d}.usdc"
        stage = self._new_stage(self._tmp / self._clips_name / name)
        self._chunk = (stage, _Prims(stage, self.options, has_hair(self._static)))
        self._chunk_paths.append(f"./{self._clips_name}/{name}")
        self._chunk_starts.append(int(index))
        self._in_chunk = 0

    def _finish_chunk(self) -> None:
        stage, _ = self._chunk
        _save(stage, self.path)
        if self._manifest is None:
            # every chunk declares the same animated attributes: the first one describes them all
            self._manifest = Usd.ClipsAPI.GenerateClipManifestFromLayers([stage.GetRootLayer()], ROOT_PATH)
        self._chunk = None
        self._pending = 0

    def _check_frame(self, frame: BakeFrame) -> None:
        s = self._static
        if not isinstance(frame.index, (int, np.integer)) or isinstance(frame.index, bool):
            raise InputError(f"frame index must be an integer, got {frame.index!r}")
        if self._last is not None and frame.index <= self._last:
            raise InputError(f"frames must come in increasing index order; {frame.index} follows {self._last}")
        for name, points, faces in (("head_vertices", frame.head_vertices, s.head_faces),
                                    ("cage_vertices", frame.cage_vertices, s.cage_faces)):
            p = np.asarray(points)
            if p.ndim != 2 or p.shape[1] != 3:
                raise InputError(f"{name} must have shape (V, 3), got {p.shape}")
            if len(faces) and len(p) <= int(faces.max()):
                raise InputError(f"{name} has {len(p)} vertices but the faces use index {int(faces.max())}")
            if not np.isfinite(p).all():
                raise InputError(f"{name} has a non-finite value")
        for part in ("face", "hair"):
            moving = getattr(frame, part)
            want, got = len(getattr(s, part)), len(np.asarray(moving.means))
            if got != want:
                raise InputError(f"{part} has {got} Gaussians but the bake's static data has {want}")
            # checked before anything is authored, so a bad frame leaves no partial samples
            check_frame_arrays(part, want, moving.means, moving.quats, moving.scales)
        counts = (len(frame.head_vertices), len(frame.cage_vertices))
        if self._frames and counts != self._vertex_counts:
            raise InputError(f"head/cage vertex counts {counts} differ from the first frame's {self._vertex_counts}")
        self._vertex_counts = counts

    def close(self) -> UsdStageResult:
        """Finish the stage and move it (and `<name>_clips/`) into place."""
        if self._state != "open":
            raise InputError("close() needs begin() first and no earlier close()/abort()")
        try:
            if self._frames == 0:
                raise InputError("no frames were written; a bake needs at least one", self.path)
            if self._chunk is not None:
                self._finish_chunk()
            root = self._root
            root.SetStartTimeCode(float(self._first))
            root.SetEndTimeCode(float(self._last))
            layer = root.GetRootLayer()
            data = dict(layer.customLayerData)
            info = dict(data.get("avatarkit", {}))
            info.update(frames=int(self._frames), first_frame=int(self._first), last_frame=int(self._last),
                        value_clips=len(self._chunk_paths))
            data["avatarkit"] = info
            layer.customLayerData = data
            if self._use_clips:
                manifest_name = "manifest.usda"
                if not self._manifest.Export(str(self._tmp / self._clips_name / manifest_name)):
                    raise OutputError("could not write the value-clip manifest", self.path)
                clips = Usd.ClipsAPI(self._root_prims.avatar.GetPrim())
                clips.SetClipAssetPaths(Sdf.AssetPathArray(self._chunk_paths))
                clips.SetClipPrimPath(ROOT_PATH)
                clips.SetClipActive(Vt.Vec2dArray([(float(s), float(k)) for k, s in enumerate(self._chunk_starts)]))
                times = [(float(self._first),) * 2] + ([(float(self._last),) * 2] if self._last != self._first else [])
                clips.SetClipTimes(Vt.Vec2dArray(times))
                clips.SetClipManifestAssetPath(Sdf.AssetPath(f"./{self._clips_name}/{manifest_name}"))
            _save(root, self.path)
            root_file = Path(layer.realPath)
            self._root = self._root_prims = self._manifest = None
            try:
                result = self._move_into_place(root_file)
            except OSError as e:
                raise write_failed(e, self.path) from None
        except BaseException:
            self.abort()
            raise
        self._state = "closed"
        shutil.rmtree(self._tmp, ignore_errors=True)
        return result

    def _move_into_place(self, root_file: Path) -> UsdStageResult:
        if self._ext == ".usdz":
            packed = self._tmp / self.path.name
            try:
                ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root_file)), str(packed))
            except Tf.ErrorException:
                ok = False
            if not ok:
                raise OutputError("could not write the USDZ package", self.path)
            os.replace(packed, self.path)
            return UsdStageResult(self.path, None, self._frames, self._first, self._last,
                                  self.path.stat().st_size)
        total = 0
        clips_dir = None
        if self._use_clips:
            new = self._tmp / self._clips_name
            total = sum(f.stat().st_size for f in new.iterdir())
            clips_dir = self.clips_dir
            if os.path.lexists(clips_dir):
                check_clips_folder(clips_dir)  # again: something may have appeared while we baked
                # an older bake's clips: parked inside our temp folder, deleted with it
                os.replace(clips_dir, self._tmp / "replaced")
            os.replace(new, clips_dir)
        os.replace(root_file, self.path)
        return UsdStageResult(self.path, clips_dir, self._frames, self._first, self._last,
                              total + self.path.stat().st_size)

    def abort(self) -> None:
        """Drop everything written so far; nothing is left under the requested names."""
        self._state = "closed"
        self._chunk = None
        self._root = self._root_prims = self._manifest = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)


def has_hair(static: BakeStatic) -> bool:
    """Whether a bake has hair (and so a cage): a hairless avatar's has neither."""
    return len(static.hair) > 0 or len(static.cage_faces) > 0


def _check_static(static: BakeStatic) -> None:
    check_fps(static.fps)
    for name in ("head_faces", "cage_faces"):
        f = np.asarray(getattr(static, name))
        if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
            raise InputError(f"{name} must be an integer array of shape (F, 3), got {f.dtype} {f.shape}")
        if f.size and f.min() < 0:
            raise InputError(f"{name} has a negative vertex index")


# --- inspection --------------------------------------------------------------------------------
def _describe_format(path: Path) -> str:
    """By content, since `.usd` may hold either encoding."""
    with open(path, "rb") as f:
        magic = f.read(8)
    if magic.startswith(b"PK"):
        with zipfile.ZipFile(path) as z:
            return f"USDZ package ({len(z.namelist())} files)"
    if magic.startswith(b"PXR-USDC"):
        return "USD crate (binary)"
    if magic.startswith(b"#usda"):
        return "USD text"
    return "USD"


def _count(prim: Usd.Prim, names: tuple[str, ...], tc: Usd.TimeCode) -> int | None:
    for name in names:
        attr = prim.GetAttribute(name)
        if attr and attr.HasValue():
            value = attribute_value(attr, tc)
            if value is not None:
                return len(value)
    return None


def _max_samples(prim: Usd.Prim) -> int:
    return max((a.GetNumTimeSamples() for a in prim.GetAttributes()), default=0)


def _fmt_box(extent) -> str:
    if extent is None or len(extent) != 2:
        return "none"
    lo, hi = np.asarray(extent, np.float64)
    return "(" + ", ".join(f"{x:.4g}" for x in lo) + ") .. (" + ", ".join(f"{x:.4g}" for x in hi) + ")"


def inspect_usd(path: Path):
    """Summary of any USD file: stage metadata, time range, value clips, and the geometry prims
    (type, element count, time-sample count, extent at the first frame); splat prims add their
    SH degree and precision. Works for bake stages and `avatarkit convert`'s files alike."""
    path = Path(path)
    stage = open_usd_stage(path)
    # a damaged crate opens and fails only when a value or its sample count is read (found by
    # the fuzz tests' long run)
    with usd_errors(path):
        return _summarise(path, stage)


def _summarise(path: Path, stage: Usd.Stage):
    from avatarkit.inspect import ByteCount, Summary

    s = Summary("USD stage", str(path))
    s.add("format", _describe_format(path)).add("file size", ByteCount(path.stat().st_size))
    s.add("up axis", str(UsdGeom.GetStageUpAxis(stage))).add("meters per unit", UsdGeom.GetStageMetersPerUnit(stage))
    s.add("default prim", str(stage.GetDefaultPrim().GetPath()) if stage.HasDefaultPrim() else "none")
    tc = Usd.TimeCode.EarliestTime()
    clip_layers, clip_bytes, clip_prims = 0, 0, []
    geometry, splats, frames = [], 0, 0
    for prim in stage.Traverse():
        clips = Usd.ClipsAPI(prim).GetClipAssetPaths()
        if clips:
            clip_prims.append(str(prim.GetPath()))
            clip_layers += len(clips)
            for asset in Usd.ClipsAPI(prim).ComputeClipAssetPaths():
                resolved = asset.resolvedPath  # inside a .usdz these are package paths: not counted
                if resolved and os.path.isfile(resolved):
                    clip_bytes += os.path.getsize(resolved)
        if not prim.IsA(UsdGeom.Boundable):
            continue
        row = {"name": str(prim.GetPath()), "type": str(prim.GetTypeName())}
        if prim.IsA(UsdVol.ParticleField3DGaussianSplat):
            n = _count(prim, ("positions", "positionsh"), tc) or 0
            splats += n
            deg = prim.GetAttribute("radiance:sphericalHarmonicsDegree")
            degree = attribute_value(deg, tc) if deg and deg.HasValue() else None
            row.update(splats=n, sh_degree=3 if degree is None else int(degree),
                       precision="half" if prim.GetAttribute("positionsh").HasValue() else "float")
        elif prim.IsA(UsdGeom.PointBased):
            row["points"] = _count(prim, ("points",), tc) or 0
            if prim.IsA(UsdGeom.Points) and prim.HasAttribute("primvars:scales") and prim.HasAttribute("orientations"):
                splats += row["points"]  # our --usd-points stand-in for splats
            if prim.IsA(UsdGeom.Mesh):
                row["faces"] = _count(prim, ("faceVertexCounts",), tc) or 0
        purpose = UsdGeom.Imageable(prim).GetPurposeAttr().Get()
        if purpose and purpose != UsdGeom.Tokens.default_:
            row["purpose"] = str(purpose)
        samples = _max_samples(prim)
        frames = max(frames, samples)
        row["time_samples"] = samples
        extent = prim.GetAttribute("extent")
        row["extent"] = _fmt_box(attribute_value(extent, tc) if extent else None)
        geometry.append(row)
    if stage.HasAuthoredTimeCodeRange() or frames:
        s.add("fps", stage.GetTimeCodesPerSecond())
        s.add("frame range", [stage.GetStartTimeCode(), stage.GetEndTimeCode()])
        s.add("frames", frames)
    else:
        s.add("frames", "static (no time samples)")
    if clip_layers:
        clips = {"prims": ", ".join(clip_prims), "layers": clip_layers}
        if clip_bytes:
            clips["bytes"] = ByteCount(clip_bytes)
        s.add("value clips", clips)
    s.add("splats", splats)
    s.add("prims", geometry if geometry else "none")
    data = stage.GetRootLayer().customLayerData
    if data:
        s.add("custom layer data", json.dumps(_plain_dict(data), sort_keys=True, default=str))
    return s


def _plain_dict(value):
    if isinstance(value, dict):
        return {k: _plain_dict(v) for k, v in value.items()}
    if hasattr(value, "__len__") and not isinstance(value, str):
        return [_plain_dict(v) for v in value]
    return value


__all__ = ["UsdStageWriter", "UsdWriteOptions", "UsdStageResult", "validate_stage", "vertex_normals",
           "face_normals", "inspect_usd", "find_splat_prims", "ROOT_PATH", "HEAD_PATH", "FACE_PATH", "HAIR_PATH", "CAGE_PATH"]
