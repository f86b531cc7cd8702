"""Writing `GaussianSet`s into OpenUSD prims: `SplatPrimWriter` (`UsdVol.ParticleField3DGaussianSplat`,
the one USD splat writer) and `PointsPrimWriter` (a `UsdGeom.Points` stand-in); the schema's
attribute names. Reading is `gaussians.usd_read`; files (atomic output stages, `save_usd`) are
`gaussians.usd`.

Conventions (OpenUSD 26.x schema, and identical to NVIDIA's `usd-convert-gsplat`):
- `positions` point3f[], `orientations` quatf[] (real part first in USD text; `Vt.QuatfArray`
  takes x, y, z, w from numpy: converted here only), `scales` float3[] *linear*,
  `opacities` float[] *linear* in [0, 1];
- `radiance:sphericalHarmonicsDegree` (uniform int) and `radiance:sphericalHarmonicsCoefficients`
  float3[] of N * (degree+1)^2 entries, per particle and coefficient-major (DC first, then the
  3DGS `f_rest` order), tagged `elementSize` = (degree+1)^2 and `interpolation` = vertex;
- `primvars:displayColor` color3f[] (vertex) = clamp(0.5 + SH_C0 * DC, 0, 1);
- `extent` = min/max of the positions (what NVIDIA writes; the kernels' 3-sigma support is not
  added, so a renderer's culling box is the particle centres' box);
- half variants (`positionsh`, `orientationsh`, `scalesh`, `opacitiesh`,
  `radiance:sphericalHarmonicsCoefficientsh`) instead of the float ones when `half=True`.

Frames: data in memory is metres, +Y up. The writer authors in the *stage's* frame: on a stage
whose `upAxis` is Z, splats are turned +90 degrees about X ((x, y, z) -> (x, -z, y)); SH bands
are rotated with them. The reader (`usd_read`) undoes the stage's `upAxis`, `metersPerUnit` and the prim's
local-to-world transform (a similarity), so what comes back is metres, +Y up.

`SplatPrimWriter` serves both a one-shot file (`save_usd`) and animated stages (the bake
writer): static attributes are written once, positions/orientations/scales (+extent) as time
samples; a "static" attribute that changes later is promoted to time samples. Its split form,
`write_static` once plus `write_samples(time, means, quats, scales)` per frame, lets the static
part live in a stage's root layer and the samples in other layers (value clips).
`PointsPrimWriter` has the same split interface for a `UsdGeom.Points` stand-in.
"""
from __future__ import annotations

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdVol, Vt

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.sh import SH_C0, SH_COUNTS

DEFAULT_PRIM_PATH = "/Splats"
SH_DEGREE_ATTR = "radiance:sphericalHarmonicsDegree"

#: logical field -> (float attribute, half attribute)
ATTRIBUTE_NAMES = {
    "positions": ("positions", "positionsh"),
    "orientations": ("orientations", "orientationsh"),
    "scales": ("scales", "scalesh"),
    "opacities": ("opacities", "opacitiesh"),
    "sh": ("radiance:sphericalHarmonicsCoefficients", "radiance:sphericalHarmonicsCoefficientsh"),
}
#: fields time-sampled by default when a writer is given a time code (what rigid/skinned motion changes)
ANIMATED_FIELDS = ("positions", "orientations", "scales")
_FIELDS = ("positions", "orientations", "scales", "opacities", "sh")

_HALF_MAX = 65504.0

# Data (metres, +Y up) -> a Z-up stage: +90 degrees about X. Integer entries keep it exact.
Y_TO_Z = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _vt_array(field: str, values: np.ndarray, half: bool):
    """A numpy field array -> the matching Vt array (float or half)."""
    if half:
        with np.errstate(over="ignore"):
            v = values.astype(np.float16)
        if not np.isfinite(v).all():
            raise InputError(f"{field} has values beyond the half-float range (+-{_HALF_MAX:g}); "
                             "write float attributes instead (drop --half)")
    else:
        v = values
    if field == "opacities":
        return (Vt.HalfArray if half else Vt.FloatArray).FromNumpy(np.ascontiguousarray(v))
    if field == "orientations":
        return (Vt.QuathArray if half else Vt.QuatfArray).FromNumpy(np.ascontiguousarray(v))
    return (Vt.Vec3hArray if half else Vt.Vec3fArray).FromNumpy(np.ascontiguousarray(v))


def _field_values(gs: GaussianSet, field: str) -> np.ndarray:
    """GaussianSet -> the array USD stores for `field` (orientations as x, y, z, w; sh flattened)."""
    if field == "positions":
        return gs.means
    if field == "orientations":
        return gs.quats[:, [1, 2, 3, 0]]
    if field == "scales":
        return gs.scales
    if field == "opacities":
        return gs.opacities
    return gs.sh.reshape(-1, 3)


def bounding_box(points: np.ndarray) -> np.ndarray:
    """(min, max) (2, 3) float32 of points (N, 3); zeros when empty. On a contiguous copy of the
    transpose: numpy's axis-0 reduction over 3 columns is ~50x slower, which showed per frame."""
    if len(points) == 0:
        return np.zeros((2, 3), np.float32)
    cols = np.ascontiguousarray(np.asarray(points).T)
    return np.stack([cols.min(axis=1), cols.max(axis=1)]).astype(np.float32)


def _extent(means: np.ndarray) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(bounding_box(means))


def stage_up_axis(stage: Usd.Stage) -> str:
    """'Y' or 'Z' (USD's fallback is Y when the stage does not say)."""
    return str(UsdGeom.GetStageUpAxis(stage)).upper()



def check_prim_path(prim_path: str) -> Sdf.Path:
    if not isinstance(prim_path, str) or not Sdf.Path.IsValidPathString(prim_path):
        raise InputError(f"prim path {prim_path!r} is not a valid USD path")
    path = Sdf.Path(prim_path)
    if not path.IsAbsolutePath() or not path.IsPrimPath() or path == Sdf.Path.absoluteRootPath:
        raise InputError(f"prim path {prim_path!r} must be an absolute prim path such as /Splats")
    return path


class SplatPrimWriter:
    """Defines a `ParticleField3DGaussianSplat` prim at `prim_path` and writes GaussianSets into it.

    `write(gs)` with `time=None` authors every attribute as a default (non-animated) value: a
    one-shot file. `write(gs, time=t)` authors the `animated` fields (+extent) as samples at t and
    the other fields once, as defaults; if such a static field later changes, it is promoted to
    time samples (samples at the first and last unchanged frame keep the earlier frames exact
    under USD's linear interpolation). Every write must have the same Gaussian count and SH
    degree: per-particle attributes of one prim share one count.

    Data are given in metres, +Y up; on a Z-up stage they are turned to Z up here. Missing
    ancestors of `prim_path` are defined as Xforms; the stage's defaultPrim is set to the root
    ancestor if it has none.
    """

    def __init__(self, stage: Usd.Stage, prim_path: str | None = None, *, half: bool = False,
                 animated: tuple[str, ...] | None = None):
        prim_path = DEFAULT_PRIM_PATH if prim_path is None else prim_path
        animated = ANIMATED_FIELDS if animated is None else animated
        path = check_prim_path(prim_path)
        unknown = set(animated) - set(_FIELDS)
        if unknown:
            raise InputError(f"unknown animated fields {sorted(unknown)}; choose from {_FIELDS}")
        self.stage = stage
        self.half = bool(half)
        self.animated = tuple(animated)
        self._rotation = Y_TO_Z if stage_up_axis(stage) == "Z" else None
        for ancestor in reversed(path.GetParentPath().GetPrefixes()):
            if not stage.GetPrimAtPath(ancestor):
                UsdGeom.Xform.Define(stage, ancestor)
        self.prim = UsdVol.ParticleField3DGaussianSplat.Define(stage, path)
        if not stage.HasDefaultPrim():
            stage.SetDefaultPrim(stage.GetPrimAtPath(path.GetPrefixes()[0]))
        p = self.prim.GetPrim()
        which = 1 if half else 0
        self._attrs = {f: p.GetAttribute(ATTRIBUTE_NAMES[f][which]) for f in _FIELDS}
        self._extent = self.prim.GetExtentAttr()
        self._degree = self.prim.GetRadianceSphericalHarmonicsDegreeAttr()
        self._color = UsdGeom.PrimvarsAPI(p).CreatePrimvar(
            "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex)
        self._count: int | None = None
        self._sh_degree: int | None = None
        self._one_shot = False
        self._split = False   # write_static was used: frames come through write_samples
        self._first_time: float | None = None
        self._last_time: float | None = None
        self._static: dict[str, np.ndarray] = {}   # first frame's arrays of still-static fields
        self._sampled: set[str] = set()

    @property
    def path(self) -> str:
        return str(self.prim.GetPath())

    def _to_stage_frame(self, gs: GaussianSet) -> GaussianSet:
        return gs if self._rotation is None else gs.transform(rotation=self._rotation)

    def _check_shape(self, gs: GaussianSet):
        if self._count is None:
            self._count, self._sh_degree = len(gs), gs.sh_degree
            return
        if len(gs) != self._count:
            raise InputError(f"{self.path}: a frame has {len(gs)} Gaussians but the first had "
                             f"{self._count}; every frame of one splat prim needs the same count")
        if gs.sh_degree != self._sh_degree:
            raise InputError(f"{self.path}: a frame has SH degree {gs.sh_degree} but the first had "
                             f"{self._sh_degree}; the degree is uniform on the prim")

    def _set(self, field: str, values: np.ndarray, time: Usd.TimeCode):
        attr = self._attrs[field]
        attr.Set(_vt_array(field, values, self.half), time)
        if field == "positions":
            self._extent.Set(_extent(values), time)
        elif field == "sh":
            self._color.Set(_display_color_from_sh(values, self._sh_degree), time)

    def write(self, gs: GaussianSet, time: float | None = None) -> None:
        """Author `gs` (metres, +Y up) at `time` (None: as default values, once)."""
        if self._split:
            raise InputError(f"{self.path}: after write_static, frames go through write_samples")
        if self._one_shot or (time is None and self._count is not None):
            raise InputError(f"{self.path}: a default-time (time=None) write must be the prim's only write")
        self._check_shape(gs)
        data = self._to_stage_frame(gs)
        values = {f: _field_values(data, f) for f in _FIELDS}
        first = self._first_time is None and not self._one_shot
        with Sdf.ChangeBlock():
            if first:
                self._degree.Set(int(self._sh_degree))
                sh_attr = UsdGeom.Primvar(self._attrs["sh"])
                sh_attr.SetElementSize(SH_COUNTS[self._sh_degree])
                sh_attr.SetInterpolation(UsdGeom.Tokens.vertex)
            if time is None:
                self._one_shot = True
                for f in _FIELDS:
                    self._set(f, values[f], Usd.TimeCode.Default())
                return
            t = float(time)
            for f in _FIELDS:
                if f in self.animated or f in self._sampled:
                    self._set(f, values[f], Usd.TimeCode(t))
                elif first:
                    self._set(f, values[f], Usd.TimeCode.Default())
                    self._static[f] = values[f]
                elif not np.array_equal(values[f], self._static[f]):
                    # promote: pin the old value at the first and last frames that had it
                    old = self._static.pop(f)
                    self._set(f, old, Usd.TimeCode(self._first_time))
                    if self._last_time != self._first_time:
                        self._set(f, old, Usd.TimeCode(self._last_time))
                    self._set(f, values[f], Usd.TimeCode(t))
                    self._sampled.add(f)
            if first:
                self._first_time = t
            self._last_time = t

    # Split writing: static part once (root layer), per-frame part anywhere (e.g. value clips).
    def write_static(self, gs: GaussianSet) -> None:
        """Author only the fields that are not `animated` (by default opacities, SH with its
        degree and `primvars:displayColor`) as default values, and fix the prim's count and SH
        degree. The per-frame part then comes through `write_samples`, on this stage or on
        another layer's writer (a value clip).

        The animated attributes (and `extent`) are *declared* here, with their type and no
        value: OpenUSD before 26.3 has no splat schema, so this declaration is the only place
        its reader learns that the attributes exist and what type they hold (without it, an
        attribute that only clips supply is missing from `GetAttributes()`, a read at a
        fractional time fails with "Unknown value type ''" and flattening drops it). No
        default is written: one authored in the layer that anchors the clips is stronger than
        the clips' samples, and every time would read it."""
        if self._count is not None or self._one_shot or self._split:
            raise InputError(f"{self.path}: write_static must be the prim's first write")
        self._check_shape(gs)
        data = self._to_stage_frame(gs)
        with Sdf.ChangeBlock():
            declare_attributes([self._attrs[f] for f in self.animated] + [self._extent])
            self._degree.Set(int(self._sh_degree))
            sh_attr = UsdGeom.Primvar(self._attrs["sh"])
            sh_attr.SetElementSize(SH_COUNTS[self._sh_degree])
            sh_attr.SetInterpolation(UsdGeom.Tokens.vertex)
            for f in _FIELDS:
                if f not in self.animated:
                    self._set(f, _field_values(data, f), Usd.TimeCode.Default())
        self._split = True

    def write_samples(self, time: float, means: np.ndarray, quats: np.ndarray, scales: np.ndarray) -> None:
        """Author positions, orientations and scales (+ extent) at `time` and nothing else.

        means: (N, 3) metres, +Y up; quats: (N, 4) unit w x y z; scales: (N, 3) linear.
        N must equal the count of earlier writes on this writer (the first call fixes it).
        Cheaper than `write` (no GaussianSet per frame) and usable on a layer that holds only
        samples, such as a value clip."""
        means, quats, scales = check_frame_arrays(self.path, self._count, means, quats, scales)
        if self._count is None:
            self._count = len(means)
        if self._rotation is not None:
            means, quats = _rotate_frame(self._rotation, means, quats)
        t = Usd.TimeCode(float(time))
        with Sdf.ChangeBlock():
            self._set("positions", means, t)
            self._set("orientations", quats[:, [1, 2, 3, 0]], t)
            self._set("scales", scales, t)


def declare_attributes(attrs) -> None:
    """Author each attribute's type (and variability) on the edit target without a value.

    For attributes that value clips animate: see `SplatPrimWriter.write_static`."""
    for attr in attrs:
        prim = attr.GetPrim()
        prim.CreateAttribute(attr.GetName(), attr.GetTypeName(), False, attr.GetVariability())


def check_frame_arrays(path: str, count: int | None, means, quats, scales):
    """Check one frame's moving arrays: shapes, one count, finite, scales > 0 -> float32 arrays."""
    out = []
    for name, a, width in (("means", means, 3), ("quats", quats, 4), ("scales", scales, 3)):
        a = np.ascontiguousarray(a, dtype=np.float32)
        if a.ndim != 2 or a.shape[1] != width:
            raise InputError(f"{path}: {name} must have shape (N, {width}), got {a.shape}")
        if out and len(a) != len(out[0]):
            raise InputError(f"{path}: {name} has {len(a)} rows but means has {len(out[0])}")
        with np.errstate(over="ignore", invalid="ignore"):
            finite = np.isfinite(a.sum()) or np.isfinite(a).all()
        if not finite:
            bad = int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0])
            raise InputError(f"{path}: {name} has a non-finite value (Gaussian {bad})")
        out.append(a)
    if count is not None and len(out[0]) != count:
        raise InputError(f"{path}: a frame has {len(out[0])} Gaussians but the prim has {count}; "
                         "every frame of one splat prim needs the same count")
    if len(out[2]) and not (out[2] > 0).all():
        bad = int(np.flatnonzero(~(out[2] > 0).all(axis=1))[0])
        raise InputError(f"{path}: scales must be > 0 (Gaussian {bad} has {out[2][bad].tolist()})")
    return out


def _rotate_frame(r: np.ndarray, means: np.ndarray, quats: np.ndarray):
    """Turn a frame's means (N, 3) and wxyz quats (N, 4) by rotation r (3, 3); as GaussianSet.transform."""
    from avatarkit.rotations import matrix_to_quat, quat_multiply

    m = (means.astype(np.float64) @ r.T).astype(np.float32)
    q = quat_multiply(matrix_to_quat(r)[None], quats.astype(np.float64))
    return m, (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)


class PointsPrimWriter:
    """Splats as a plain `UsdGeom.Points` prim, for tools that do not read the splat schema yet.

    Same split interface as `SplatPrimWriter` (`write_static` once, `write_samples` per frame).
    Layout (our convention; no standard exists for splats on Points):
    - `points` point3f[] (time-sampled) and `extent` = the box of the points grown by half
      their widths (what `UsdGeom.Points.ComputeExtent` gives);
    - `orientations` quatf[] (quath[] with half), w x y z in USD's text form, time-sampled
      (a custom attribute: Points has none; PointInstancer uses the same name and type);
    - `widths` float[] (vertex) = 2 x the largest scale, the 1-sigma diameter (time-sampled);
    - `primvars:scales` float3[] (half3[] with half), vertex, linear (time-sampled);
    - static: `primvars:displayColor` color3f[] and `primvars:displayOpacity` float[] (vertex),
      `primvars:radiance:sphericalHarmonicsCoefficients` float3[] (half3[]), vertex, elementSize
      (degree+1)^2, in the splat schema's order, and constant int
      `primvars:radiance:sphericalHarmonicsDegree`.
    Only +Y-up stages are supported (the bake writes nothing else).
    """

    def __init__(self, stage: Usd.Stage, prim_path: str, *, half: bool = False):
        path = check_prim_path(prim_path)
        if stage_up_axis(stage) != "Y":
            raise InputError("PointsPrimWriter writes +Y-up stages only")
        self.stage = stage
        self.half = bool(half)
        for ancestor in reversed(path.GetParentPath().GetPrefixes()):
            if not stage.GetPrimAtPath(ancestor):
                UsdGeom.Xform.Define(stage, ancestor)
        self.prim = UsdGeom.Points.Define(stage, path)
        if not stage.HasDefaultPrim():
            stage.SetDefaultPrim(stage.GetPrimAtPath(path.GetPrefixes()[0]))
        p, names = self.prim.GetPrim(), Sdf.ValueTypeNames
        pv = UsdGeom.PrimvarsAPI(p)
        # Declared on every writer's layer: clips only supply samples of attributes that exist,
        # and interpolation metadata must come from the layer that declares them.
        self._orient = p.CreateAttribute("orientations", names.QuathArray if half else names.QuatfArray)
        self._scales = pv.CreatePrimvar("scales", names.Half3Array if half else names.Float3Array,
                                        UsdGeom.Tokens.vertex)
        self._widths = self.prim.CreateWidthsAttr()
        self.prim.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        self._count: int | None = None

    @property
    def path(self) -> str:
        return str(self.prim.GetPath())

    def write_static(self, gs: GaussianSet) -> None:
        """Colour, opacity and SH primvars as default values; fixes the count."""
        if self._count is not None:
            raise InputError(f"{self.path}: write_static must be the prim's first write")
        self._count = len(gs)
        pv, names = UsdGeom.PrimvarsAPI(self.prim.GetPrim()), Sdf.ValueTypeNames
        k = SH_COUNTS[gs.sh_degree]
        with Sdf.ChangeBlock():
            # points and extent are Points schema attributes that every OpenUSD knows; declared
            # anyway so the root layer lists every attribute the clips animate
            declare_attributes([self.prim.GetPointsAttr(), self.prim.GetExtentAttr()])
            pv.CreatePrimvar("displayColor", names.Color3fArray, UsdGeom.Tokens.vertex).Set(
                Vt.Vec3fArray.FromNumpy(gs.colors.astype(np.float32)))
            pv.CreatePrimvar("displayOpacity", names.FloatArray, UsdGeom.Tokens.vertex).Set(
                Vt.FloatArray.FromNumpy(gs.opacities))
            sh = pv.CreatePrimvar("radiance:sphericalHarmonicsCoefficients",
                                  names.Half3Array if self.half else names.Float3Array,
                                  UsdGeom.Tokens.vertex, k)
            sh.Set(_vt_array("sh", gs.sh.reshape(-1, 3), self.half))
            pv.CreatePrimvar("radiance:sphericalHarmonicsDegree", names.Int,
                             UsdGeom.Tokens.constant).Set(int(gs.sh_degree))

    def write_samples(self, time: float, means: np.ndarray, quats: np.ndarray, scales: np.ndarray) -> None:
        """Points, orientations, widths, scales and extent at `time` (arrays as in SplatPrimWriter)."""
        means, quats, scales = check_frame_arrays(self.path, self._count, means, quats, scales)
        if self._count is None:
            self._count = len(means)
        # column-wise maximum: numpy's axis-1 reduction over 3 values is ~30x slower
        widths = 2.0 * np.maximum(np.maximum(scales[:, 0], scales[:, 1]), scales[:, 2])
        r = widths[:, None] / 2
        extent = np.stack([bounding_box(means - r)[0], bounding_box(means + r)[1]])
        t = Usd.TimeCode(float(time))
        with Sdf.ChangeBlock():
            self.prim.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(means), t)
            self._orient.Set(_vt_array("orientations", quats[:, [1, 2, 3, 0]], self.half), t)
            self._widths.Set(Vt.FloatArray.FromNumpy(widths.astype(np.float32)), t)
            self._scales.Set(_vt_array("scales", scales, self.half), t)
            self.prim.GetExtentAttr().Set(Vt.Vec3fArray.FromNumpy(extent.astype(np.float32)), t)


def _display_color_from_sh(sh_flat: np.ndarray, degree: int) -> Vt.Vec3fArray:
    """sh_flat: (N*K, 3) in the stage frame -> clamp(0.5 + SH_C0 * DC) (N, 3); DC is rotation invariant."""
    dc = sh_flat.reshape(-1, SH_COUNTS[degree], 3)[:, 0]
    return Vt.Vec3fArray.FromNumpy(np.clip(dc * np.float32(SH_C0) + np.float32(0.5), 0, 1).astype(np.float32))


__all__ = ["ATTRIBUTE_NAMES", "ANIMATED_FIELDS", "DEFAULT_PRIM_PATH", "SH_DEGREE_ATTR", "Y_TO_Z",
           "PointsPrimWriter", "SplatPrimWriter", "bounding_box", "check_frame_arrays", "check_prim_path",
           "declare_attributes", "stage_up_axis"]
