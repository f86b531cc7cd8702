"""3DGS PLY files: `read_ply(path) -> GaussianSet`, `write_ply(path, gs)`.

On disk (the INRIA layout every splat tool reads), one `vertex` element whose properties are

    x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2 rot_0..3 [extras]

with log scales, logit opacity, channel-major `f_rest` (index = channel*(K-1) + (k-1)), raw
(unnormalised) wxyz quaternions and normals that nobody uses (we write zeros).

We *write* exactly that order, binary little endian, atomically; extras follow, one column
`name` for an (N,) extra or `name_0..name_{m-1}` for an (N, m) one.

We *read* by property name in any order, from binary little/big endian or ASCII files, with any
PLY scalar type. Decisions (documented in docs/converting-and-formats.md, "3DGS PLY files"):
- position (`x y z`), rotation (`rot_0..3`), scale (`scale_0..2`) and `opacity` are required:
  a file without them is not a splat file, and a silent default would hide the problem.
- colour is `f_dc_0..2`, or failing that `red green blue` (integer types are divided by their
  maximum, so uchar c -> c/255; float colours are taken as [0, 1]).
- the SH degree follows from the number of `f_rest_*` properties: 0, 9, 24 or 45.
- quaternions are normalised; a zero quaternion becomes the identity (1, 0, 0, 0).
- every other vertex property becomes an extra with its on-disk dtype: `foo_0..foo_{m-1}`
  (same type) -> (N, m) extra `foo`, a lone `foo_0` -> (N,) extra `foo`. Normals are dropped.
- other elements (faces, cameras...) are skipped. In a binary file an element *before* the
  vertex element that has list properties can only be skipped if its lists have a constant
  length (checked); otherwise that is a FormatError. Elements after the vertex element are not
  read at all, so a file truncated inside them still loads.
- everything a file can get wrong is a FormatError naming the file: counts are checked against
  the file size before anything is allocated.

Frames (`frame=` on both `read_ply` and `write_ply`; docs/converting-and-formats.md, "Axis conventions"): a PLY file
carries no axes, and two conventions are in use. "yup" (default) is ours: metres, +Y up, the
face toward +Z, what every other avatarkit file holds. "ydown" is the 3DGS/COLMAP frame
(OpenCV camera axes: x right, y down, z forward, Niantic's "RDF") that trainers write and that
PlayCanvas tools and Niantic's SPZ library assume for PLY: ours turned 180 degrees about X.
Converting is exact and its own inverse: y and z of positions are negated, quaternion
(w, x, y, z) -> (w, x, -y, -z) (R q R^T: the same covariance as R q, since R is diagonal),
and each SH coefficient's sign flips with the parity of its basis function in y and z
(`FLIP_SH_SIGNS`; band 0 never changes). Writing converts from ours to the file's frame,
reading converts back.
"""
from __future__ import annotations

import os
import re
import sys

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.ply_table import VertexTable, open_vertex_table
from avatarkit.gaussians.sh import SH_COUNTS, rgb_to_dc

#: opacities are clipped to [OPACITY_EPS, 1 - OPACITY_EPS] before the logit, so 0 and 1 stay finite
OPACITY_EPS = 1e-6

#: numpy dtype -> the PLY name we write for it
_WRITE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
                "u4": "uint", "f4": "float", "f8": "double"}

POSITION = ("x", "y", "z")
NORMAL = ("nx", "ny", "nz")
DC = ("f_dc_0", "f_dc_1", "f_dc_2")
SCALE = ("scale_0", "scale_1", "scale_2")
ROT = ("rot_0", "rot_1", "rot_2", "rot_3")
RGB = ("red", "green", "blue")


# --- frames ----------------------------------------------------------------------------------
#: "yup": ours (+Y up, face toward +Z); "ydown": the 3DGS/COLMAP (OpenCV, RDF) frame
PLY_FRAMES = ("yup", "ydown")
#: sign of each SH coefficient (3DGS order, DC first) under (x, y, z) -> (x, -y, -z): the basis
#: function's parity in y and z (band 1: -y, z, -x; band 2: xy, yz, 3z^2-1, xz, x^2-y^2; band 3:
#: y(3x^2-y^2), xyz, y(5z^2-1), z(5z^2-3), x(5z^2-1), z(x^2-y^2), x(x^2-3y^2)). Checked in the
#: tests against `sh.rotate_sh` and against Niantic's sign table for RDF <-> RUB.
FLIP_SH_SIGNS = np.array([1, -1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1], np.float32)
_FLIP_POS = np.array([1, -1, -1], np.float32)
_FLIP_QUAT = np.array([1, 1, -1, -1], np.float32)


def check_ply_frame(frame: str) -> str:
    """`frame` if it is one of PLY_FRAMES, else InputError."""
    if frame not in PLY_FRAMES:
        raise InputError(f"PLY frame must be one of {', '.join(PLY_FRAMES)}, got {frame!r}")
    return frame


def flip_y_down(gs: GaussianSet) -> GaussianSet:
    """`gs` turned 180 degrees about X, exactly (sign flips only): ours <-> the y-down frame.
    Its own inverse. Extras are kept as they are."""
    k = gs.sh.shape[1]
    return GaussianSet.from_checked(gs.means * _FLIP_POS, gs.quats * _FLIP_QUAT, gs.scales,
                                    gs.opacities, gs.sh * FLIP_SH_SIGNS[:k, None], gs.extras)


# --- PLY columns -> GaussianSet ------------------------------------------------------------
#: `decoder="auto"` weighs the kernel's one-time costs in a process (measured on our 2-core
#: machine: starting Taichi ~0.25 s, loading the compiled kernel for a row layout ~0.12 s)
#: against what it saves on the file at hand (~0.28 ns per byte of rows: 1M SH-3 splats read in
#: ~0.04 s instead of ~0.11 s), and takes it when the saving pays what is still unpaid. So one
#: read of a 1M-splat file in a fresh process stays with numpy; a file of ~5M, or any file of
#: >= KERNEL_MIN_ROWS once the kernel is loaded (`decoder="kernel"` loads it), takes the kernel.
TAICHI_START_S = 0.25
KERNEL_LOAD_S = 0.12
KERNEL_SAVES_S_PER_BYTE = 0.28e-9
#: below this many rows a launch costs about what the kernel saves
KERNEL_MIN_ROWS = 16_384
#: the row layouts (`_kernel_offsets`, SH count) the kernel has been compiled for in this process
_loaded_layouts: set[tuple] = set()
DECODERS = ("auto", "kernel", "numpy")


def read_ply(path: str | os.PathLike, *, decoder: str = "auto", frame: str = "yup") -> GaussianSet:
    """Read a 3DGS PLY file (any property order, binary LE/BE or ASCII) into a GaussianSet.

    `frame`: the axes the file is in ("yup": ours, "ydown": the 3DGS/COLMAP frame; see the
    module notes); the result is always in ours.

    `decoder`: "numpy" is the reference (every layout the reader accepts); "kernel" decodes
    binary little-endian float32 files whose property groups each lie in one run (the INRIA
    layout and its variants without normals or with extras) in one parallel Taichi pass, and
    falls back to numpy for other layouts and for rows it finds invalid (so errors read the
    same); "auto" takes the kernel where it is faster, start-up included (see TAICHI_START_S).
    Both give the same bits.
    """
    if decoder not in DECODERS:
        raise ValueError(f"decoder must be one of {DECODERS}, got {decoder!r}")
    check_ply_frame(frame)
    _, table = open_vertex_table(path)
    gs = _table_to_gaussians(table, path, decoder)
    return flip_y_down(gs) if frame == "ydown" else gs


def _indexed(names, prefix: str) -> dict[int, str]:
    """{i: name} for names `prefix_<i>`."""
    pat = re.compile(re.escape(prefix) + r"_(0|[1-9]\d*)$")
    return {int(m.group(1)): s for s in names if (m := pat.match(s))}


def _require(table: VertexTable, names, what: str, path) -> None:
    missing = [n for n in names if n not in table.dtypes]
    if missing:
        raise FormatError(f"missing {what} propert{'y' if len(missing) == 1 else 'ies'} "
                          f"{' '.join(missing)} (a 3DGS PLY has x y z f_dc_0..2 opacity "
                          "scale_0..2 rot_0..3)", path)


def _all_finite(a: np.ndarray) -> bool:
    """True when every value of a float array is finite.

    A NaN or inf anywhere makes the sum non-finite, so a finite sum proves the array finite in
    one cheap reduction; only a non-finite sum (which may also be an overflow) needs the exact
    elementwise test.
    """
    if a.dtype.kind != "f":
        return True
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(a.sum()):
            return True
    return bool(np.isfinite(a).all())


def _check_finite(table: VertexTable, names, values: np.ndarray, path) -> None:
    """FormatError naming the first non-finite property value among `names` (data `values`)."""
    if _all_finite(values):
        return
    for name in names:
        col = table.column(name)
        if col.dtype.kind != "f":
            continue
        bad = ~np.isfinite(col)
        if col.dtype.itemsize > 4:  # a finite double can still overflow float32
            with np.errstate(over="ignore"):
                bad |= ~np.isfinite(col.astype(np.float32))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise FormatError(f"property {name!r} has a non-finite value ({col[row]}) at vertex "
                              f"{row}", path)
    raise FormatError("non-finite value in " + " ".join(names), path)


def _table_to_gaussians(table: VertexTable, path, decoder: str = "numpy") -> GaussianSet:
    names = table.names
    _require(table, POSITION, "position", path)
    _require(table, ROT, "rotation", path)
    _require(table, SCALE, "scale", path)
    _require(table, ("opacity",), "opacity", path)
    for name in (*POSITION, *ROT, *SCALE, "opacity", *DC):
        if name in table.dtypes and table.dtypes[name].kind != "f":
            raise FormatError(f"property {name!r} has integer type {table.dtypes[name]}, "
                              "expected float or double", path)
    n = len(table)

    rest = _indexed(names, "f_rest")
    if len(rest) not in (0, 9, 24, 45) or sorted(rest) != list(range(len(rest))):
        raise FormatError(f"{len(rest)} f_rest_* properties (indices {_ranges(sorted(rest))}); "
                          "SH degree 0..3 needs none or f_rest_0..f_rest_{8, 23 or 44}", path)
    k = len(rest) // 3 + 1
    rest_names = [rest[i] for i in range(len(rest))]
    if any(table.dtypes[s].kind != "f" for s in rest_names):
        raise FormatError("f_rest_* properties must be float or double", path)
    if all(c in table.dtypes for c in DC):
        colour = DC
    elif all(c in table.dtypes for c in RGB):
        colour = RGB
    else:
        raise FormatError("no colour: need f_dc_0 f_dc_1 f_dc_2 (or red green blue)", path)

    used = {*POSITION, *NORMAL, *ROT, *SCALE, "opacity", *colour, *rest_names}
    extra_groups = _extra_groups(table, [s for s in names if s not in used], path)
    offsets = _kernel_offsets(table, rest_names) if colour is DC and decoder != "numpy" else None
    if offsets is not None:
        layout = (tuple(offsets.items()), k)
        if _kernel_pays(table, decoder, layout):
            gs = _decode_with_kernel(table, offsets, k, extra_groups, path)
            _loaded_layouts.add(layout)
            if gs is not None:
                return gs
            # a row the kernel flagged: the reference below finds it and names the problem
    # On disk f_rest is channel-major (index = channel*(K-1) + (k-1)). Asking for the names in
    # coefficient-major order makes the gather do the transpose, and with f_dc in front the
    # gathered (N, 3K) block already is the (N, K, 3) SH array.
    rest_cm = [rest_names[c * (k - 1) + j] for j in range(k - 1) for c in range(3)]
    groups = [list(POSITION), list(ROT), list(SCALE), ["opacity"]]
    if colour is DC:
        groups.append([*DC, *rest_cm])
    else:
        groups.append(list(RGB))
        groups += [rest_cm] if rest_cm else []
    arrays = table.gather(groups)
    with np.errstate(over="ignore"):  # a double beyond float32's range becomes inf: caught below
        arrays = [a.astype(np.float32, copy=False) if a.dtype.kind == "f" else a for a in arrays]
    # The core arrays are checked for NaN/inf by GaussianSet (and its failure is traced back
    # to a property and row below). Opacity and scales are checked here, as the sigmoid turns
    # +-inf into a valid 0 or 1 and exp turns NaN into an error that would mislead; extras
    # are not checked by GaussianSet at all.
    for i in (2, 3):
        _check_finite(table, groups[i], arrays[i], path)
    extras = _read_extras(table, extra_groups, path)
    means, quats, log_scales, logit = arrays[:4]

    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        scales = np.exp(log_scales.astype(np.float64)).astype(np.float32)
        opacities = (1.0 / (1.0 + np.exp(-logit[:, 0].astype(np.float64)))).astype(np.float32)
    if not ((scales > 0) & np.isfinite(scales)).all():
        bad = int(np.flatnonzero(~((scales > 0) & np.isfinite(scales)).all(axis=1))[0])
        raise FormatError(f"log scale at vertex {bad} ({log_scales[bad].tolist()}) is outside "
                          "float32's range once exponentiated", path)
    with np.errstate(invalid="ignore"):  # inf/inf: NaN, which GaussianSet reports
        quats = _normalize_quats(quats)

    if colour is DC:
        sh = arrays[4].reshape(n, k, 3)
    else:
        rgb = arrays[4].astype(np.float64)
        if arrays[4].dtype.kind in "iu":  # uchar 0..255 -> 0..1
            rgb /= np.iinfo(arrays[4].dtype).max
        sh = np.empty((n, k, 3), np.float32)
        sh[:, 0] = rgb_to_dc(rgb)
        if k > 1:
            sh[:, 1:] = arrays[5].reshape(n, k - 1, 3)
    try:
        return GaussianSet(means, quats, scales, opacities, sh, extras)
    except InputError as e:
        for g, a in zip(groups, arrays):
            _check_finite(table, g, a, path)
        raise FormatError(f"invalid Gaussian data: {e.message}", path) from None


def _kernel_repays(nbytes: int, layout: tuple | None = None) -> bool:
    """Does the kernel save, over `nbytes` of rows, what its start still costs in this process
    (see TAICHI_START_S)? layout: the row layout, if known (None: not loaded yet)."""
    from avatarkit._taichi import taichi_running

    unpaid = 0.0 if layout in _loaded_layouts else KERNEL_LOAD_S
    if not taichi_running():
        unpaid += TAICHI_START_S
    return nbytes * KERNEL_SAVES_S_PER_BYTE >= unpaid


def _kernel_pays(table: VertexTable, decoder: str, layout: tuple) -> bool:
    """Is the kernel worth it for this table?"""
    if decoder == "kernel":
        return True
    return len(table) >= KERNEL_MIN_ROWS and _kernel_repays(table.raw.nbytes, layout)


def sequence_decoder(paths) -> str:
    """The decoder for reading these PLY files one after another (a sequence): "kernel" when
    what it saves over all of them pays its one-time costs (see TAICHI_START_S), else "auto"."""
    total = sum(os.path.getsize(p) for p in paths if os.path.isfile(p))
    return "kernel" if _kernel_repays(total) else "auto"


def _kernel_offsets(table: VertexTable, rest_names: list[str]) -> dict[str, int] | None:
    """Word offset of each property group in a row and the span `lo`..`hi` of words they lie
    in, or None when the kernel cannot read the rows: not little-endian float32 words, or a
    group not stored as one run in our order."""
    raw = table.raw
    if (table.byte_order != "<" or sys.byteorder != "little" or raw.ndim != 2
            or raw.shape[1] % 4 or not raw.flags.c_contiguous):
        return None
    f4 = np.dtype("<f4")
    groups = {"pos": POSITION, "dc": DC, "rest": rest_names, "opacity": ("opacity",),
              "scale": SCALE, "rot": ROT}
    offsets, spans = {}, []
    for key, group in groups.items():
        if not group:  # SH degree 0: no f_rest
            offsets[key] = 0
            continue
        start = table.offsets[group[0]]
        if start % 4 or any(table.dtypes[name] != f4 or table.offsets[name] != start + 4 * i
                            for i, name in enumerate(group)):
            return None
        offsets[key] = start // 4
        spans.append((start // 4, start // 4 + len(group)))
    offsets["lo"] = min(a for a, _ in spans)
    offsets["hi"] = max(b for _, b in spans)
    return offsets


def _decode_with_kernel(table: VertexTable, offsets: dict[str, int], k: int,
                        extra_groups: list[tuple[str, list[str]]], path) -> GaussianSet | None:
    """The fast path: one Taichi pass over the rows. None when a row is invalid."""
    from avatarkit.gaussians import _ply_kernels

    n, row = table.raw.shape
    words = table.raw.reshape(-1).view(np.float32)  # unaligned when the header length is odd
    means, quats, scales, opacities, sh, first_bad = _ply_kernels.decode(words, row // 4,
                                                                         offsets, k)
    if first_bad < n:
        return None
    # The kernel enforced every rule GaussianSet checks (finite values, scales > 0 and
    # representable, opacities in [0, 1], unit quaternions): skip checking them again.
    return GaussianSet.from_checked(means, quats, scales, opacities, sh,
                                    _read_extras(table, extra_groups, path))


def _read_extras(table: VertexTable, extra_groups: list[tuple[str, list[str]]], path) -> dict:
    """The extras of `_extra_groups` as arrays with their on-disk dtypes ((N,) for a lone
    column), checked for NaN/inf (GaussianSet does not check extras)."""
    if not extra_groups:
        return {}
    extras = {}
    for (key, cols), a in zip(extra_groups, table.gather([cols for _, cols in extra_groups])):
        _check_finite(table, cols, a, path)
        extras[key] = a[:, 0] if len(cols) == 1 else a
    return extras


def _ranges(idx: list[int]) -> str:
    if not idx:
        return "none"
    # idx is sorted: a run of consecutive indices spans exactly len(idx) values (never built as a
    # list: a damaged header may name f_rest_99999999999)
    contiguous = idx[-1] - idx[0] + 1 == len(idx) and len(set(idx)) == len(idx)
    return f"{idx[0]}..{idx[-1]}" if contiguous else \
        ",".join(map(str, idx[:12])) + ("..." if len(idx) > 12 else "")


def _normalize_quats(q: np.ndarray) -> np.ndarray:
    """q: (N, 4) float32 -> unit wxyz; rows already unit to float32 precision keep their bits,
    a zero quaternion becomes the identity."""
    norms = np.sqrt(np.einsum("ij,ij->i", q, q, dtype=np.float64))
    fix = np.abs(norms - 1.0) > 4 * np.finfo(np.float32).eps
    if fix.any():
        zero = norms == 0
        q64 = q[fix].astype(np.float64) / np.where(zero[fix], 1.0, norms[fix])[:, None]
        q64[zero[fix]] = (1.0, 0.0, 0.0, 0.0)
        q = q.copy()
        q[fix] = q64
    return q


def _sanitize(name: str) -> str:
    s = re.sub(r"\W", "_", name)
    return "_" + s if not s or s[0].isdigit() else s


def _extra_groups(table: VertexTable, names: list[str], path) -> list[tuple[str, list[str]]]:
    """(extra name, its properties) for leftover properties, in file order.

    `foo_0..foo_{m-1}` of one dtype form one (N, m) extra `foo` ((N,) when m == 1); anything
    else (gaps, mixed types, a clash with a plain `foo`) stays one extra per property."""
    groups: dict[str, dict[int, str]] = {}
    singles: list[str] = []
    for s in names:
        m = re.match(r"(.+)_(0|[1-9]\d*)$", s)
        if m:
            groups.setdefault(m.group(1), {})[int(m.group(2))] = s
        else:
            singles.append(s)
    found = []
    for prefix, members in groups.items():
        idx = sorted(members)
        cols = [members[i] for i in idx]
        same_type = len({table.dtypes[c] for c in cols}) == 1
        if idx == list(range(len(idx))) and same_type and prefix not in singles:
            found.append((table.names.index(cols[0]), prefix, cols))
        else:
            singles.extend(cols)
    found += [(table.names.index(s), s, [s]) for s in singles]
    out, seen = [], set()
    for _, key, cols in sorted(found):
        name = _sanitize(key)
        if name in seen:
            raise FormatError(f"vertex property {key!r} and another map to the same extra "
                              f"name {name!r}", path)
        seen.add(name)
        out.append((name, cols))
    return out


# --- GaussianSet -> PLY ----------------------------------------------------------------------
def ply_property_names(sh_degree: int) -> list[str]:
    """The INRIA vertex property order for an SH degree (extras not included)."""
    k = SH_COUNTS[sh_degree]
    return [*POSITION, *NORMAL, *DC, *(f"f_rest_{i}" for i in range(3 * (k - 1))), "opacity",
            *SCALE, *ROT]


def _extra_columns(gs: GaussianSet) -> list[tuple[str, list[str], np.dtype, np.ndarray]]:
    """(extra name, column names, little-endian dtype, (N, m) values) for each extra."""
    out = []
    for key, value in gs.extras.items():
        arr = np.asarray(value)
        if arr.ndim > 2:
            raise InputError(f"extra {key!r} has shape {arr.shape}; PLY extras must be (N,) or (N, m)")
        if arr.dtype == bool:
            arr = arr.astype(np.uint8)
        elif arr.dtype.kind in "iu" and arr.dtype.itemsize == 8:
            small = np.int32 if arr.dtype.kind == "i" else np.uint32
            info = np.iinfo(small)
            if arr.size and (arr.min() < info.min or arr.max() > info.max):
                raise InputError(f"extra {key!r} holds values outside {np.dtype(small).name}, "
                                 "the widest integer PLY has")
            arr = arr.astype(small)
        elif arr.dtype == np.float16:
            arr = arr.astype(np.float32)
        code = arr.dtype.kind + str(arr.dtype.itemsize)
        if code not in _WRITE_NAMES:
            raise InputError(f"extra {key!r} has dtype {arr.dtype}, which PLY cannot store")
        cols = [key] if arr.ndim == 1 else [f"{key}_{i}" for i in range(arr.shape[1])]
        if not cols:
            raise InputError(f"extra {key!r} has shape {arr.shape}: no columns to write")
        out.append((key, cols, np.dtype("<" + code), arr.reshape(len(arr), len(cols))))
    return out


def write_ply(path: str | os.PathLike, gs: GaussianSet, *, frame: str = "yup") -> None:
    """Write `gs` as a binary little-endian 3DGS PLY in the exact INRIA property order, extras
    after; atomically (a failure leaves no file). Opacities are clipped to
    [OPACITY_EPS, 1 - OPACITY_EPS] before the logit so 0 and 1 stay finite on disk.

    `frame`: the axes to write in ("yup": ours, as `gs` is; "ydown": the 3DGS/COLMAP frame
    splat viewers assume; see the module notes)."""
    if check_ply_frame(frame) == "ydown":
        gs = flip_y_down(gs)
    n, k = len(gs), gs.sh.shape[1]
    names = ply_property_names(gs.sh_degree)
    extras = _extra_columns(gs)
    taken = set(names)
    for key, cols, _, _ in extras:
        clash = taken.intersection(cols)
        if clash:
            raise InputError(f"extra {key!r} would write property {sorted(clash)[0]!r}, "
                             "which is already in the file")
        taken.update(cols)

    # SH (N, K, 3) coefficient-major -> on-disk f_dc_0..2 then channel-major f_rest:
    # disk column 3 + i (i = c*(K-1) + j-1) holds coefficient j of channel c
    disk = [0, 1, 2] + [(1 + i % (k - 1)) * 3 + i // (k - 1) for i in range(3 * (k - 1))]
    sh = np.take(gs.sh.reshape(n, 3 * k), disk, axis=1)
    o = np.clip(gs.opacities.astype(np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    parts = [gs.means, np.zeros((n, 3), np.float32), sh, (np.log(o) - np.log1p(-o))[:, None],
             np.log(gs.scales.astype(np.float64)), gs.quats]
    parts = [np.asarray(a, "<f4") for a in parts] + [v.astype(dt) for _, _, dt, v in extras]

    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    lines += [f"property float {s}" for s in names]
    for _, cols, dt, _ in extras:
        lines += [f"property {_WRITE_NAMES[dt.kind + str(dt.itemsize)]} {c}" for c in cols]
    lines.append("end_header")
    header = ("\n".join(lines) + "\n").encode("ascii")

    rows = np.empty((n, sum(a.shape[1] * a.itemsize for a in parts)), np.uint8)
    off = 0
    for a in parts:  # each part's row is copied as one opaque item (a 1-D strided copy)
        width = a.shape[1] * a.itemsize
        if n:
            item = np.dtype(f"V{width}")
            rows[:, off:off + width].view(item)[:, 0] = np.ascontiguousarray(a).view(item)[:, 0]
        off += width
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(header)
        f.write(rows.reshape(-1).data)


__all__ = ["read_ply", "write_ply", "sequence_decoder", "PLY_FRAMES", "FLIP_SH_SIGNS", "check_ply_frame",
           "flip_y_down", "ply_property_names", "OPACITY_EPS"]
