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

import io
import mmap
import os
import re
import sys
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.sh import SH_COUNTS, rgb_to_dc

#: the header (up to and including `end_header`) must fit in this many bytes
MAX_HEADER_BYTES = 64 * 1024
#: opacities are clipped to [OPACITY_EPS, 1 - OPACITY_EPS] before the logit, so 0 and 1 stay finite
OPACITY_EPS = 1e-6

#: PLY type name (and the numpy-style aliases plyfile and others write) -> numpy type code
PLY_TYPES: dict[str, str] = {
    "char": "i1", "int8": "i1",
    "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4",
    "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}
#: numpy dtype -> the PLY name we write for it
_WRITE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int",
                "u4": "uint", "f4": "float", "f8": "double"}
_FORMATS = {"ascii": "ascii", "binary_little_endian": "<", "binary_big_endian": ">"}

POSITION = ("x", "y", "z")
NORMAL = ("nx", "ny", "nz")
DC = ("f_dc_0", "f_dc_1", "f_dc_2")
SCALE = ("scale_0", "scale_1", "scale_2")
ROT = ("rot_0", "rot_1", "rot_2", "rot_3")
RGB = ("red", "green", "blue")


# --- header ------------------------------------------------------------------------------
@dataclass
class PlyProperty:
    name: str
    dtype: str                     # numpy type code without byte order, e.g. "f4"
    count_dtype: str | None = None  # set for list properties: the type of the length prefix

    @property
    def is_list(self) -> bool:
        return self.count_dtype is not None


@dataclass
class PlyElement:
    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)

    def property_names(self) -> list[str]:
        return [p.name for p in self.properties]


@dataclass
class PlyHeader:
    format: str          # "ascii", "binary_little_endian" or "binary_big_endian"
    version: str
    elements: list[PlyElement]
    comments: list[str]
    data_offset: int     # byte offset of the first data byte

    @property
    def byte_order(self) -> str:
        """'<' or '>' for binary files, '' for ASCII."""
        return "" if self.format == "ascii" else _FORMATS[self.format]

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)

    def describe_format(self) -> str:
        return {"ascii": "ascii", "binary_little_endian": "binary little endian",
                "binary_big_endian": "binary big endian"}[self.format] + f" {self.version}"


def parse_header(head: bytes, path: str | os.PathLike) -> PlyHeader:
    """Parse the header at the start of `head` (the first bytes of the file)."""
    if not head:
        raise FormatError("empty file, not a PLY file", path)
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise FormatError("not a PLY file (it does not start with the 'ply' magic line)", path)
    end = re.search(rb"(^|\n)end_header[ \t]*\r?\n", head)
    if end is None:
        if len(head) >= MAX_HEADER_BYTES:
            raise FormatError(f"no 'end_header' in the first {MAX_HEADER_BYTES // 1024} KiB "
                              "(header too long or corrupt)", path)
        raise FormatError("header has no 'end_header' line (truncated file?)", path)
    raw = head[:end.start()]
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise FormatError("header contains non-ASCII bytes", path) from None
    fmt = version = None
    elements: list[PlyElement] = []
    comments: list[str] = []
    for lineno, line in enumerate(text.split("\n")[1:], start=2):
        words = line.split()
        if not words:
            continue
        key = words[0]
        if key in ("comment", "obj_info"):
            comments.append(line.strip()[len(key):].strip())
        elif key == "format":
            if fmt is not None:
                raise FormatError(f"header line {lineno}: a second 'format' line", path)
            if len(words) != 3 or words[1] not in _FORMATS:
                raise FormatError(f"header line {lineno}: bad format line {line.strip()!r} "
                                  f"(expected one of {', '.join(_FORMATS)})", path)
            fmt, version = words[1], words[2]
        elif key == "element":
            if len(words) != 3:
                raise FormatError(f"header line {lineno}: bad element line {line.strip()!r}", path)
            try:
                count = int(words[2])
            except ValueError:
                raise FormatError(f"header line {lineno}: element {words[1]!r} count "
                                  f"{words[2]!r} is not an integer", path) from None
            if count < 0:
                raise FormatError(f"header line {lineno}: element {words[1]!r} has a negative "
                                  f"count ({count})", path)
            if any(e.name == words[1] for e in elements):
                raise FormatError(f"header line {lineno}: element {words[1]!r} declared twice", path)
            elements.append(PlyElement(words[1], count))
        elif key == "property":
            if not elements:
                raise FormatError(f"header line {lineno}: property before any element", path)
            prop = _parse_property(words, lineno, line, path)
            if prop.name in elements[-1].property_names():
                raise FormatError(f"header line {lineno}: property {prop.name!r} declared twice "
                                  f"in element {elements[-1].name!r}", path)
            elements[-1].properties.append(prop)
        else:
            raise FormatError(f"header line {lineno}: unknown keyword {key!r}", path)
    if fmt is None:
        raise FormatError("header has no 'format' line", path)
    return PlyHeader(fmt, version, elements, comments, end.end())


def _parse_property(words: list[str], lineno: int, line: str, path) -> PlyProperty:
    def dtype_of(name: str) -> str:
        if name not in PLY_TYPES:
            raise FormatError(f"header line {lineno}: unknown property type {name!r}", path)
        return PLY_TYPES[name]

    if len(words) >= 2 and words[1] == "list":
        if len(words) != 5:
            raise FormatError(f"header line {lineno}: bad list property {line.strip()!r}", path)
        count_dtype, item_dtype = dtype_of(words[2]), dtype_of(words[3])
        if count_dtype[0] not in "iu":
            raise FormatError(f"header line {lineno}: list length type {words[2]!r} is not an "
                              "integer type", path)
        return PlyProperty(words[4], item_dtype, count_dtype)
    if len(words) != 3:
        raise FormatError(f"header line {lineno}: bad property line {line.strip()!r}", path)
    return PlyProperty(words[2], dtype_of(words[1]))


def check_element_sizes(header: PlyHeader, file_size: int, path) -> None:
    """FormatError unless the file is long enough for the element counts its header claims.

    Lists count as empty and ASCII values as one digit plus a separator, so this is a lower
    bound that can be checked before anything is allocated."""
    need = 0
    for e in header.elements:
        if header.format == "ascii":
            row = max(1, 2 * len(e.properties))
        else:
            row = sum(np.dtype(p.count_dtype if p.is_list else p.dtype).itemsize
                      for p in e.properties)
        need += e.count * row
        if need > file_size - header.data_offset + (header.format == "ascii"):
            raise FormatError(f"truncated: element {e.name!r} claims {e.count} rows, more than "
                              f"the {file_size - header.data_offset} bytes after the header "
                              "can hold", path)


def read_ply_header(path: str | os.PathLike) -> PlyHeader:
    """The parsed header of a PLY file (reads at most MAX_HEADER_BYTES)."""
    with _open(path) as f:
        return parse_header(f.read(MAX_HEADER_BYTES), path)


def _open(path):
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a file", path) from None
    except OSError as e:
        raise InputError(f"cannot open: {e.strerror or e}", path) from None


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


# --- the vertex table --------------------------------------------------------------------
#: rows per block when gathering columns: ~2 MB of input, so a block is read from memory once
#: and every column is copied out of cache
_GATHER_BLOCK_BYTES = 2 << 20


class VertexTable:
    """The vertex element as raw rows: `raw` (N, row_bytes) uint8 and per-property byte offsets.

    `column`/`columns` give strided views (no copy); `gather` copies groups of properties into
    contiguous arrays in one blocked pass over the rows (the fast path for big files).
    """

    def __init__(self, raw: np.ndarray, properties: list[PlyProperty], byte_order: str):
        self.raw = raw  # (N, row_bytes) uint8, possibly a read-only memory map
        self.byte_order = byte_order
        self.dtypes: dict[str, np.dtype] = {}
        self.offsets: dict[str, int] = {}
        off = 0
        for p in properties:
            dt = np.dtype(byte_order + p.dtype)
            self.dtypes[p.name], self.offsets[p.name] = dt, off
            off += dt.itemsize
        self.names = [p.name for p in properties]

    def __len__(self) -> int:
        return len(self.raw)

    def column(self, name: str) -> np.ndarray:
        """(N,) view of one property, on-disk byte order."""
        dt, off = self.dtypes[name], self.offsets[name]
        return self.raw[:, off:off + dt.itemsize].view(dt)[:, 0]

    def columns(self, names) -> np.ndarray:
        """(N, k) array of the named properties (a view when they are adjacent and same-typed)."""
        names = list(names)
        dt, off = self.dtypes[names[0]], self.offsets[names[0]]
        adjacent = all(self.dtypes[n] == dt and self.offsets[n] == off + i * dt.itemsize
                       for i, n in enumerate(names))
        if adjacent:
            return self.raw[:, off:off + len(names) * dt.itemsize].view(dt)
        out_dt = np.result_type(*[self.dtypes[n].newbyteorder("=") for n in names])
        out = np.empty((len(self), len(names)), out_dt)
        for i, n in enumerate(names):  # a loop over properties, never over rows
            out[:, i] = self.column(n)
        return out

    def gather(self, groups: list[list[str]]) -> list[np.ndarray]:
        """Contiguous (N, k) copies of each group of properties, in native byte order.

        Same result as `np.array(self.columns(g))` per group (the reference path,
        used for rows mixing value sizes). When every property of the row has the same byte
        size the rows are an (N, P) matrix of unsigned words, and `np.take` along axis 1 picks
        any columns in any order in one call whose cost is mostly per row, not per column. So
        each block of rows (~2 MB, read from memory once) gets one take of every wanted column,
        and each group's k words per row are then copied out of cache as one opaque k-word
        item: a 1-D strided copy instead of N tiny row copies.
        """
        n = len(self)
        sizes = {dt.itemsize for dt in self.dtypes.values()}
        uniform = len(sizes) == 1 and all(len({self.dtypes[c] for c in g}) == 1 for g in groups)
        if not uniform or n == 0:  # always a copy: nothing returned may view the file mapping
            return [_native(np.array(self.columns(g), order="C")) for g in groups]
        word = np.dtype(f"u{sizes.pop()}")
        matrix = self.raw.view(word)  # (N, P): one unsigned word per property
        col = {name: i for i, name in enumerate(self.names)}
        flat = np.array([col[c] for g in groups for c in g], np.intp)
        bounds = np.cumsum([0] + [len(g) for g in groups])
        outs = [np.empty((n, len(g)), word) for g in groups]
        items = [np.dtype(f"V{len(g) * word.itemsize}") for g in groups]
        out_items = [o.view(item)[:, 0] for o, item in zip(outs, items)]  # (N,) views
        block = max(1, _GATHER_BLOCK_BYTES // self.raw.shape[1])
        for a in range(0, n, block):  # a loop over blocks of ~8k rows, not over rows
            buf = np.take(matrix[a:a + block], flat, axis=1)  # (rows, sum of k)
            for dst, item, lo, hi in zip(out_items, items, bounds[:-1], bounds[1:]):
                dst[a:a + block] = buf[:, lo:hi].view(item)[:, 0]
        return [_native(o.view(self.dtypes[g[0]])) for o, g in zip(outs, groups)]


def _native(a: np.ndarray) -> np.ndarray:
    """The same values in native byte order (a copy only for big-endian data)."""
    return a if a.dtype.isnative else a.astype(a.dtype.newbyteorder("="))


def _row_dtype(props: list[PlyProperty], byte_order: str) -> np.dtype:
    return np.dtype([(f"p{i}", byte_order + p.dtype) for i, p in enumerate(props)])


def _binary_element_bytes(f, element: PlyElement, offset: int, file_size: int, byte_order: str,
                          path) -> int:
    """Byte size of a binary element we only skip. Lists must have a constant length."""
    if not any(p.is_list for p in element.properties):
        return element.count * _row_dtype(element.properties, byte_order).itemsize
    if element.count == 0:
        return 0
    # Read the list lengths of the first row, assume every row has the same, then check that.
    layout, pos = [], offset
    for p in element.properties:
        if p.is_list:
            cdt = np.dtype(byte_order + p.count_dtype)
            f.seek(pos)
            b = f.read(cdt.itemsize)
            if len(b) < cdt.itemsize:
                raise FormatError(f"truncated in element {element.name!r}", path)
            n = int(np.frombuffer(b, cdt)[0])
            if n < 0:
                raise FormatError(f"element {element.name!r}: negative list length {n} in "
                                  f"property {p.name!r}", path)
            layout.append((p, pos - offset, cdt, n))
            pos += cdt.itemsize + n * np.dtype(p.dtype).itemsize
        else:
            pos += np.dtype(p.dtype).itemsize
    row = pos - offset
    total = element.count * row
    if offset + total > file_size:
        raise FormatError(f"truncated: element {element.name!r} ({element.count} rows) needs "
                          f"{total} bytes but only {file_size - offset} remain", path)
    f.seek(offset)
    rows = np.fromfile(f, dtype=np.uint8, count=total)
    if len(rows) != total:
        raise FormatError(f"truncated in element {element.name!r}", path)
    rows = rows.reshape(element.count, row)
    for p, off, cdt, n in layout:
        lengths = rows[:, off:off + cdt.itemsize].view(cdt)[:, 0]
        if (lengths != n).any():
            raise FormatError(f"element {element.name!r} comes before 'vertex' and its list "
                              f"property {p.name!r} varies in length, which this reader cannot "
                              "skip; write the vertex element first", path)
    return total


def _map_bytes(f, offset: int, nbytes: int) -> np.ndarray:
    """`nbytes` bytes of `f` from `offset` as a uint8 array, memory-mapped when possible.

    Mapping skips the copy np.fromfile makes; the caller has already checked the file is long
    enough. (A file truncated by another process *while* we read it would fault; we accept
    that: our own writers replace files by rename, never in place.)
    """
    if nbytes == 0:
        return np.zeros(0, np.uint8)
    try:
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        return np.frombuffer(mm, dtype=np.uint8, count=nbytes, offset=offset)
    except (OSError, ValueError):  # not mappable (pipes, some network file systems)
        f.seek(offset)
        return np.fromfile(f, dtype=np.uint8, count=nbytes)


def _read_vertex_table(path, header: PlyHeader, file_size: int) -> VertexTable:
    vertex = header.element("vertex")
    for p in vertex.properties:
        if p.is_list:
            raise FormatError(f"vertex property {p.name!r} is a list; 3DGS PLY vertex "
                              "properties must be scalars", path)
    n = vertex.count
    if header.format == "ascii":
        return _read_ascii_vertices(path, header, file_size)
    order = header.byte_order
    row = _row_dtype(vertex.properties, order).itemsize
    with _open(path) as f:
        offset = header.data_offset
        for e in header.elements:
            if e is vertex:
                break
            offset += _binary_element_bytes(f, e, offset, file_size, order, path)
            if offset > file_size:
                raise FormatError(f"truncated: element {e.name!r} ({e.count} rows) runs past "
                                  "the end of the file", path)
        need = n * row
        if need > file_size - offset:
            raise FormatError(f"truncated: {n} vertices of {row} bytes need {need} bytes but only "
                              f"{file_size - offset} remain", path)
        raw = _map_bytes(f, offset, need)
    if len(raw) != need:  # the file shrank under us
        raise FormatError("truncated vertex data", path)
    return VertexTable(raw.reshape(n, row), vertex.properties, order)


def _read_ascii_vertices(path, header: PlyHeader, file_size: int) -> VertexTable:
    vertex = header.element("vertex")
    n, nprops = vertex.count, len(vertex.properties)
    remaining = file_size - header.data_offset
    # Every value needs at least one digit and one separator: reject absurd counts up front.
    if n * max(2 * nprops, 1) > remaining + 1:
        raise FormatError(f"truncated: {n} ASCII vertices of {nprops} values cannot fit in the "
                          f"{remaining} bytes after the header", path)
    skip = 0
    for e in header.elements:
        if e is vertex:
            break
        skip += e.count
        if skip > remaining:
            raise FormatError(f"truncated: element {e.name!r} has more rows than the file has "
                              "lines", path)
    dtype = _row_dtype(vertex.properties, "<")
    if n == 0:
        return VertexTable(np.zeros((0, dtype.itemsize), np.uint8), vertex.properties, "<")
    with _open(path) as f:
        f.seek(header.data_offset)
        data = f.read()
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        raise FormatError("ASCII PLY data contains non-ASCII bytes", path) from None
    try:
        rows = np.loadtxt(io.StringIO(text), dtype=dtype, comments=None, skiprows=skip,
                          max_rows=n, ndmin=1)
    except (ValueError, OverflowError, TypeError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise FormatError(f"bad ASCII vertex data: {msg}", path) from None
    if len(rows) != n:
        raise FormatError(f"truncated: header promises {n} vertices, the file has {len(rows)}", path)
    return VertexTable(np.ascontiguousarray(rows).view(np.uint8).reshape(n, dtype.itemsize),
                       vertex.properties, "<")


def _open_vertex_table(path) -> tuple[PlyHeader, VertexTable]:
    with _open(path) as f:
        head = f.read(MAX_HEADER_BYTES)
        file_size = os.fstat(f.fileno()).st_size
    header = parse_header(head, path)
    if header.element("vertex") is None:
        names = ", ".join(repr(e.name) for e in header.elements) or "none"
        raise FormatError(f"no 'vertex' element (elements: {names})", path)
    return header, _read_vertex_table(path, header, file_size)


def read_ply_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every vertex property of a PLY file as on disk: name -> (N,) array (native byte order).

    Values are raw (log scales, logit opacity, channel-major f_rest); `read_ply` activates them.
    """
    _, table = _open_vertex_table(path)
    return {name: table.column(name).astype(table.dtypes[name].newbyteorder("="))
            for name in table.names}


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
    _, table = _open_vertex_table(path)
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
    return f"{idx[0]}..{idx[-1]}" if idx == list(range(idx[0], idx[-1] + 1)) else \
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


__all__ = ["read_ply", "write_ply", "read_ply_arrays", "sequence_decoder", "read_ply_header",
           "PLY_FRAMES", "FLIP_SH_SIGNS", "check_ply_frame", "flip_y_down",
           "parse_header", "check_element_sizes",
           "ply_property_names", "PlyHeader", "PlyElement", "PlyProperty", "PLY_TYPES",
           "OPACITY_EPS", "MAX_HEADER_BYTES"]
