"""Reading OpenUSD splat prims into `GaussianSet`s: `load_usd(path)` (one prim of a file, in metres
+Y up), `open_usd_stage`, `find_splat_prims`, `read_splat_prim` and `to_metres_y_up` for callers
that walk a stage themselves (the web player, `inspect`).

The reader takes float or half attributes, any SH degree the prim declares, and undoes the
stage's `upAxis`, `metersPerUnit` and the prim's local-to-world transform (a similarity; a
shear or non-uniform scale is a FormatError), so what comes back is metres, +Y up.
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, UsdVol

from avatarkit.errors import AvatarKitError, FormatError, InputError, last_line
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.sh import SH_COUNTS
from avatarkit.gaussians.usd_probe import probe_usd_file
from avatarkit.gaussians.usd_prims import ATTRIBUTE_NAMES, SH_DEGREE_ATTR, Y_TO_Z, check_prim_path, stage_up_axis
from avatarkit.native_output import native_stderr_as_warnings

def find_splat_prims(stage: Usd.Stage) -> list[Usd.Prim]:
    """Every active, defined `ParticleField3DGaussianSplat` prim, in traversal order."""
    return [p for p in stage.Traverse() if p.IsA(UsdVol.ParticleField3DGaussianSplat)]


def attribute_value(attr: Usd.Attribute, time: Usd.TimeCode):
    """`attr`'s value at `time` (None if it has none); FormatError naming the attribute when the
    file holds something USD could not parse as the attribute's type (a damaged .usda makes USD
    hand back an `Sdf.UnregisteredValue`, found by the fuzz tests)."""
    value = attr.Get(time)
    if isinstance(value, Sdf.UnregisteredValue):
        raise FormatError(f"attribute {attr.GetPath()} does not hold {attr.GetTypeName()} values")
    return value


def _get(prim: Usd.Prim, names: tuple[str, str], time: Usd.TimeCode):
    """The float attribute's value if it has one (the schema says prefer it), else the half one."""
    for name in names:
        attr = prim.GetAttribute(name)
        if attr and attr.HasValue():
            value = attribute_value(attr, time)
            if value is not None:
                return _numbers(value, attr)
    return None


def _numbers(value, attr: Usd.Attribute) -> np.ndarray:
    """`value` as a float array; FormatError naming the attribute when it holds no numbers."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"attribute {attr.GetPath()} does not hold {attr.GetTypeName()} values") from None


def _integer(value, attr: Usd.Attribute) -> int:
    """`value` as one integer; FormatError naming the attribute otherwise."""
    a = _numbers(value, attr)
    if a.size != 1 or not np.isfinite(a).all() or a.reshape(()) != np.round(a.reshape(())):
        raise FormatError(f"attribute {attr.GetPath()} is not one integer")
    return int(a.reshape(()))


def _per_particle(values, n: int, width: int | None):
    """Schema rule: too long -> truncated to n; too short -> ignored (None: use the default)."""
    if values is None:
        return None
    a = np.asarray(values, dtype=np.float32)
    if width is not None:
        a = a.reshape(-1, width) if a.size else a.reshape(0, width)
    if len(a) < n:
        return None
    return a[:n]


def read_splat_prim(prim: Usd.Prim, time: float | None = None) -> GaussianSet:
    """The prim's data in *its own local space and stage units* (no transform applied).

    Missing or too-short attributes take the schema's defaults: identity orientation, unit
    scale, opacity 1, SH degree 0 with DC giving grey 0.5. SH degrees above 3 keep bands 0..3.
    `time=None` reads the earliest time sample (or the default value).
    """
    tc = Usd.TimeCode.EarliestTime() if time is None else Usd.TimeCode(float(time))
    path = str(prim.GetPath())
    positions = _get(prim, ATTRIBUTE_NAMES["positions"], tc)
    means = np.zeros((0, 3), np.float32) if positions is None else \
        np.asarray(positions, dtype=np.float32).reshape(-1, 3)
    n = len(means)
    xyzw = _per_particle(_get(prim, ATTRIBUTE_NAMES["orientations"], tc), n, 4)
    if xyzw is None:
        quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    else:
        quats = xyzw[:, [3, 0, 1, 2]]
        norms = np.linalg.norm(quats, axis=1, keepdims=True)
        bad = ~(norms[:, 0] > 0)
        quats = np.where(bad[:, None], np.array([1, 0, 0, 0], np.float32), quats)
        # DCC and half data are not exactly unit: renormalise only what is off by more than rounding
        off = np.abs(norms[:, 0] - 1) > 1e-6
        quats[off & ~bad] /= norms[off & ~bad]
    scales = _per_particle(_get(prim, ATTRIBUTE_NAMES["scales"], tc), n, 3)
    if scales is None:
        scales = np.ones((n, 3), np.float32)
    opacities = _per_particle(_get(prim, ATTRIBUTE_NAMES["opacities"], tc), n, None)
    if opacities is None:
        opacities = np.ones(n, np.float32)
    degree_attr = prim.GetAttribute(SH_DEGREE_ATTR)
    degree = attribute_value(degree_attr, tc) if degree_attr else None
    degree = 3 if degree is None else _integer(degree, degree_attr)  # 3: the schema's fallback
    sh = None
    if degree >= 0:
        k = (degree + 1) ** 2
        coeffs = _get(prim, ATTRIBUTE_NAMES["sh"], tc)
        if coeffs is not None and np.asarray(coeffs).size >= n * k * 3:
            sh = np.asarray(coeffs, np.float32).reshape(-1, 3)[: n * k].reshape(n, k, 3)
            sh = sh[:, : SH_COUNTS[min(degree, 3)]]
    if sh is None:
        sh = np.zeros((n, 1, 3), np.float32)  # DC 0 is grey 0.5, the schema's default radiance
    try:
        return GaussianSet(means, quats, scales, opacities, sh)
    except InputError as e:
        raise FormatError(f"splat prim {path}: {e.message}") from None


def _similarity(m: np.ndarray, what: str) -> tuple[np.ndarray, float, np.ndarray]:
    """Row-vector 4x4 (USD) -> (R (3,3), s, t (3,)) with x' = s R x + t; InputError if not a similarity."""
    a = m[:3, :3].T
    t = m[3, :3].copy()
    det = np.linalg.det(a)
    if not det > 0:
        raise InputError(f"{what} mirrors or collapses space (det {det:.3g}); splats cannot follow it")
    s = det ** (1.0 / 3.0)
    r = a / s
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-5):
        raise InputError(f"{what} has non-uniform scale or shear, which per-Gaussian scales "
                         "cannot represent; bake it out in the DCC first")
    return r, s, t


def load_usd(path: str | os.PathLike, prim_path: str | None = None, time: float | None = None,
             world: bool = True) -> GaussianSet:
    """Read one `ParticleField3DGaussianSplat` prim of a USD file into a GaussianSet.

    `prim_path=None` takes the only splat prim (InputError listing them if there are several).
    `time=None` reads the earliest sample. With `world=True` (default) the prim's
    local-to-world transform, the stage's metersPerUnit and upAxis are applied, so the result is
    metres, +Y up.
    """
    path = Path(path)
    stage = open_usd_stage(path)
    # a damaged crate file opens, and fails only when a value is read (found by the fuzz tests)
    with usd_errors(path):
        try:
            prims = find_splat_prims(stage)
            if prim_path is not None:
                sdf_path = check_prim_path(prim_path)
                prim = stage.GetPrimAtPath(sdf_path)
                if not prim or not prim.IsA(UsdVol.ParticleField3DGaussianSplat):
                    have = ", ".join(str(p.GetPath()) for p in prims) or "none"
                    raise InputError(f"no ParticleField3DGaussianSplat prim at {prim_path} "
                                     f"(splat prims in this file: {have})")
            elif not prims:
                raise FormatError("has no ParticleField3DGaussianSplat prim")
            elif len(prims) > 1:
                have = ", ".join(str(p.GetPath()) for p in prims)
                raise InputError(f"has {len(prims)} splat prims ({have}); choose one with a prim path")
            else:
                prim = prims[0]
            gs = read_splat_prim(prim, time)
            if world and len(gs):
                gs = to_metres_y_up(stage, prim, gs, time)
            return gs
        except AvatarKitError as e:
            raise e.with_path(path) from None


def open_usd_stage(path: str | os.PathLike) -> Usd.Stage:
    """The USD stage of `path`, fully loaded; FormatError/InputError naming the file when it
    is missing or unreadable (USD's own complaints about missing references become warnings).
    Binary files are read once in a child process first (`usd_probe`): one that crashes USD's
    reader is a FormatError here instead of a crash."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    probe_usd_file(path)  # a damaged crate can crash USD's reader: learn that in a child process
    with usd_errors(path), native_stderr_as_warnings(str(path)):  # missing references: warnings, not stray lines
        held = Sdf.Layer.Find(str(path))
        if held is not None:
            # USD's layer registry hands back a layer still alive as it was first read: a file
            # rewritten since reads stale, and one cut shorter crashes reading the old mapping
            held.Reload(force=True)
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    if stage is None:
        raise FormatError("not a readable USD file", path)
    return stage


@contextlib.contextmanager
def usd_errors(path: Path):
    """OpenUSD's own errors (`Tf.ErrorException`) inside the block become a FormatError naming
    `path`: "not a readable USD file (USD's last line)"."""
    try:
        yield
    except Tf.ErrorException as e:
        raise FormatError(f"not a readable USD file ({last_line(e)})", path) from None


def to_metres_y_up(stage: Usd.Stage, prim: Usd.Prim, gs: GaussianSet, time: float | None) -> GaussianSet:
    """`gs` read from `prim` at `time` (None: the earliest sample) moved into the world in
    metres, +Y up: the prim's local-to-world transform (a similarity), the stage's
    metersPerUnit and upAxis. Returned unchanged (bit-exact) when all three are identities."""
    tc = Usd.TimeCode.EarliestTime() if time is None else Usd.TimeCode(float(time))
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc)) \
        if prim.IsA(UsdGeom.Xformable) else np.eye(4)
    r, s, t = _similarity(m, f"the transform of {prim.GetPath()}")
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (np.isfinite(mpu) and mpu > 0):
        raise FormatError(f"metersPerUnit {mpu} is not a positive number")
    up = Y_TO_Z.T if stage_up_axis(stage) == "Z" else np.eye(3)
    r, s, t = up @ r, s * mpu, mpu * (up @ t)
    if np.array_equal(r, np.eye(3)) and s == 1.0 and not t.any():
        return gs  # keep float32 values bit-exact when nothing moves
    return gs.transform(rotation=r, translation=t, scale=s)


__all__ = ["find_splat_prims", "load_usd", "open_usd_stage", "read_splat_prim", "to_metres_y_up", "usd_errors"]
