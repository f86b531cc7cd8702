"""The header of a PLY file: `read_ply_header(path) -> PlyHeader`, `parse_header(bytes, path)`.

Any PLY header (ascii / binary little or big endian, any scalar type and the numpy-style aliases
plyfile and others write, list properties, comments, obj_info) is parsed into elements and
properties; `check_element_sizes` checks the counts against the file size before anything is
allocated. Everything a header can get wrong is a FormatError naming the file.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import FormatError, InputError

#: the header (up to and including `end_header`) must fit in this many bytes
MAX_HEADER_BYTES = 64 * 1024

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
_FORMATS = {"ascii": "ascii", "binary_little_endian": "<", "binary_big_endian": ">"}


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
    with open_ply(path) as f:
        return parse_header(f.read(MAX_HEADER_BYTES), path)


def open_ply(path):
    try:
        return open(path, "rb")
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a file", path) from None
    except OSError as e:
        raise InputError(f"cannot open: {e.strerror or e}", path) from None


__all__ = ["MAX_HEADER_BYTES", "PLY_TYPES", "PlyElement", "PlyHeader", "PlyProperty", "check_element_sizes",
           "open_ply", "parse_header", "read_ply_header"]
