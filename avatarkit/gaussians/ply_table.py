"""The vertex element of a PLY file as a table of named columns (`VertexTable`), read without
copying where it can (binary files are memory-mapped; ASCII is parsed), and
`read_ply_arrays(path)`: every vertex property as a numpy array of its on-disk type.
"""
from __future__ import annotations

import io
import mmap
import os

import numpy as np

from avatarkit.errors import FormatError
from avatarkit.gaussians.ply_header import (MAX_HEADER_BYTES, PlyElement, PlyHeader, PlyProperty, open_ply,
                                            parse_header)

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
    with open_ply(path) as f:
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
    with open_ply(path) as f:
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


def open_vertex_table(path) -> tuple[PlyHeader, VertexTable]:
    with open_ply(path) as f:
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
    _, table = open_vertex_table(path)
    return {name: table.column(name).astype(table.dtypes[name].newbyteorder("="))
            for name in table.names}


__all__ = ["VertexTable", "open_vertex_table", "read_ply_arrays"]
