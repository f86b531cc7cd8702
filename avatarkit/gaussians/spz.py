"""Niantic SPZ files (github.com/nianticlabs/spz): `read_spz(path) -> GaussianSet`, `write_spz(path, gs)`.

Layout (all little endian), versions 2 and 3: one gzip stream holding a 16-byte header

    uint32 magic 0x5053474e ("NGSP"), uint32 version, uint32 numPoints,
    uint8 shDegree, uint8 fractionalBits, uint8 flags (0x1 antialiased, 0x2 extensions), uint8 0

then the attributes one after another, each for all points: positions (3 x 24-bit signed
fixed point, `fractionalBits` fraction bits), alphas (uint8 = opacity * 255), colours (uint8 =
DC * 0.15 * 255 + 127.5), scales (uint8 = (ln s + 10) * 16), rotations (v2: 3 bytes, x y z as
(q + 1) * 127.5 of the quaternion with w >= 0; v3: 4 bytes "smallest three": 2-bit index of the
largest component, then three 10-bit (sign + 9-bit magnitude of |q| / sqrt(1/2)) fields, first
non-largest component in the highest bits), SH bands 1..degree (uint8 = x * 128 + 128, colour
channel fastest, coefficient next, in 3DGS coefficient order). Extension records, if the flag
says so, follow the attributes and are skipped here; other bytes after the attributes mean
the header's point count is wrong, and the file is refused.

Version 4 (Niantic's current library) is a plain 32-byte header (magic, version, numPoints,
shDegree, fractionalBits, flags, numStreams, uint32 tocByteOffset, 12 reserved bytes),
extension records up to `tocByteOffset`, a table of (uint64 compressed, uint64 uncompressed)
sizes and one zstd stream per non-empty attribute, same order and encoding as v3. Reading or
writing v4 needs the `zstandard` package (or Python 3.14's `compression.zstd`).

Coordinates: SPZ stores RUB (x right, y up, z back, OpenGL). Ours is +Y up with the face
looking toward +Z, the viewer's "back": the same axes, so no conversion happens either way.
(Niantic's tools flip y and z when packing a COLMAP/INRIA PLY in RDF; such a splat comes out
here upright, as our convention wants, and our y-down PLY (`write_ply(frame="ydown")`) is what
they unpack from our SPZ. PlayCanvas splat-transform 3.x departs from this: it takes SPZ bytes
in its PLY frame, unconverted.)

Default version: 3, the newest that NVIDIA's converter (usd-convert-gsplat 0.1.15: "Not a
gzipped file" on 4) and `@spz-loader/core` 0.3.1 ("divide by zero" on 4) read; 4 on request.

Quantisation of what we write (the error bounds the round-trip tests use): positions 2^-13 m
(half of 1/4096), ln-scale 1/32, opacity 0.5/255, DC 0.5/(0.15*255) ~ 0.0131 (range +-3.33),
rotation components ~ 0.5 * sqrt(1/2) / 511 ~ 7e-4 (v3), SH band 1 4/128 (5 bits), bands 2-3
8/128 (4 bits), both clamped to [-1, 127/128]. Opacities read back are clamped to
[1/255, 254/255] as in Niantic's reader. SH degree 4 files keep bands 0..3. Extras and the
antialiased flag are not carried over.
"""
from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from avatarkit.errors import AvatarKitError, FormatError, InputError, OutputError
from avatarkit.fileio import atomic_path
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.gaussians.sh import SH_COUNTS

SPZ_MAGIC = 0x5053474E
COLOR_SCALE = np.float32(0.15)
SUPPORTED_VERSIONS = (2, 3, 4)
DEFAULT_VERSION = 3
DEFAULT_SH1_BITS = 5
DEFAULT_SH_REST_BITS = 4
#: positions are 24-bit fixed point with this many fraction bits when we write (~0.24 mm)
FRACTIONAL_BITS = 12
FLAG_ANTIALIASED = 0x1
FLAG_EXTENSIONS = 0x2

_LEGACY_HEADER = struct.Struct("<IIIBBBB")          # 16 bytes
_NGSP_HEADER = struct.Struct("<IIIBBBBI12s")        # 32 bytes
_SQRT1_2 = np.float32(0.7071067811865476)
_MAX_FRACTIONAL_BITS = 24
_MAX_SH_DEGREE = 4
#: bytes allowed after the attributes of a v2/v3 stream (extension records)
_MAX_TRAILING_BYTES = 16 << 20
#: a deflate or zstd stream expands at most ~1032x; a header claiming more points than that is a lie
_MAX_RATIO = 1032


def _sh_dim(degree: int) -> int:
    """Coefficients per channel beyond DC."""
    return (degree + 1) ** 2 - 1


def _bytes_per_point(version: int, degree: int) -> list[int]:
    """Bytes per point of each attribute: positions, alphas, colours, scales, rotations, SH."""
    return [9, 1, 3, 3, 3 if version == 2 else 4, _sh_dim(degree) * 3]


# --- decoding (vectorised) ---------------------------------------------------------------------
def _decode(streams: list[bytes], n: int, version: int, degree: int, fractional_bits: int) -> GaussianSet:
    pos_b, alpha_b, color_b, scale_b, rot_b, sh_b = (np.frombuffer(s, np.uint8) for s in streams)
    b = pos_b.reshape(n * 3, 3).astype(np.int32)
    fixed = b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)
    fixed = (fixed ^ 0x800000) - 0x800000  # sign-extend 24 bits
    means = (fixed.astype(np.float32) * np.float32(1.0 / (1 << fractional_bits))).reshape(n, 3)

    opacities = np.clip(alpha_b.astype(np.float32) / np.float32(255), np.float32(1 / 255), np.float32(254 / 255))
    dc = (color_b.astype(np.float32).reshape(n, 3) / np.float32(255) - np.float32(0.5)) / COLOR_SCALE
    scales = np.exp(scale_b.astype(np.float32).reshape(n, 3) / np.float32(16) - np.float32(10))
    xyzw = _unpack_first_three(rot_b.reshape(n, 3)) if version == 2 else \
        _unpack_smallest_three(rot_b.reshape(n, 4))
    quats = xyzw[:, [3, 0, 1, 2]]
    # quantised components are not exactly unit (v2 by up to ~1e-2); GaussianSet wants unit
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)

    k = SH_COUNTS[min(degree, 3)]
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0] = dc
    if degree > 0:
        rest = (sh_b.astype(np.float32).reshape(n, _sh_dim(degree), 3) - np.float32(128)) / np.float32(128)
        sh[:, 1:] = rest[:, : k - 1]
    return GaussianSet(means, quats, scales, opacities, sh)


def _unpack_first_three(r: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 -> (N, 4) x y z w, w >= 0 derived."""
    xyz = r.astype(np.float32) / np.float32(127.5) - np.float32(1)
    w = np.sqrt(np.maximum(np.float32(0), np.float32(1) - (xyz * xyz).sum(axis=1)))
    return np.concatenate([xyz, w[:, None]], axis=1)


# For each index of the largest component: the other indices, in the order their 10-bit fields
# sit from the lowest bits up (the packer shifts them in ascending, so the last is lowest).
_SMALLEST_ORDER = np.array([[3, 2, 1], [3, 2, 0], [3, 1, 0], [2, 1, 0]])


def _unpack_smallest_three(r: np.ndarray) -> np.ndarray:
    """(N, 4) uint8 -> (N, 4) x y z w."""
    comp = r.astype(np.uint32)
    comp = comp[:, 0] | (comp[:, 1] << 8) | (comp[:, 2] << 16) | (comp[:, 3] << 24)
    largest = (comp >> 30).astype(np.intp)
    q = np.zeros((len(r), 4), np.float32)
    rows = np.arange(len(r))
    sum_sq = np.zeros(len(r), np.float32)
    for slot in range(3):
        field = (comp >> np.uint32(10 * slot)) & np.uint32(0x3FF)
        mag = (field & np.uint32(0x1FF)).astype(np.float32)
        v = _SQRT1_2 * mag / np.float32(511)
        v = np.where(field & np.uint32(0x200), -v, v)
        q[rows, _SMALLEST_ORDER[largest, slot]] = v
        sum_sq += v * v
    q[rows, largest] = np.sqrt(np.maximum(np.float32(0), np.float32(1) - sum_sq))
    return q


# --- reading -----------------------------------------------------------------------------------
def _check_header(n: int, degree: int, fractional_bits: int, version: int):
    if version not in SUPPORTED_VERSIONS:
        raise FormatError(f"SPZ version {version} is not supported (this reader knows "
                          f"{', '.join(map(str, SUPPORTED_VERSIONS))})")
    if degree > _MAX_SH_DEGREE:
        raise FormatError(f"SH degree {degree} is out of range (0..{_MAX_SH_DEGREE})")
    if fractional_bits > _MAX_FRACTIONAL_BITS:
        raise FormatError(f"{fractional_bits} fractional bits is out of range (0..{_MAX_FRACTIONAL_BITS})")
    if n == 0:
        raise FormatError("the header says the file holds no Gaussians")


def _read_legacy(data: bytes) -> GaussianSet:
    d = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        head = d.decompress(data, _LEGACY_HEADER.size)
        if len(head) < _LEGACY_HEADER.size:
            raise FormatError("truncated: the gzip stream ends inside the SPZ header")
        magic, version, n, degree, fbits, flags, _ = _LEGACY_HEADER.unpack(head)
        if magic != SPZ_MAGIC:
            raise FormatError(f"not an SPZ file (magic {magic:#010x}, expected {SPZ_MAGIC:#010x})")
        if version == 4:
            raise FormatError("version 4 SPZ data must not be gzip-wrapped")
        _check_header(n, degree, fbits, version)
        sizes = [n * b for b in _bytes_per_point(version, degree)]
        need = sum(sizes)
        if need > len(data) * _MAX_RATIO:
            raise FormatError(f"the header claims {n} Gaussians, more than {len(data)} compressed "
                              "bytes can hold")
        # max_length bounds what is inflated (and so allocated) by what the header promises
        payload = d.decompress(d.unconsumed_tail, need)
        if len(payload) < need:
            raise FormatError(f"truncated: {n} Gaussians need {need} bytes of data, the file has "
                              f"{len(payload)}")
        trailing = d.decompress(d.unconsumed_tail, _MAX_TRAILING_BYTES)
        if not d.eof:
            raise FormatError("truncated or oversized gzip stream (no end of stream after the data)")
        if trailing and not flags & FLAG_EXTENSIONS:
            # a count below the real one would otherwise shift every attribute after positions
            raise FormatError(f"{len(trailing)} bytes follow the data of the {n} Gaussians the header "
                              "claims, and its flags announce no extensions: the count is wrong")
    except zlib.error as e:
        raise FormatError(f"corrupt gzip stream ({e})") from None
    offsets = np.cumsum([0] + sizes)
    streams = [payload[offsets[i]:offsets[i + 1]] for i in range(6)]
    return _decode(streams, n, version, degree, fbits)


def _zstd():
    try:
        import zstandard
        return zstandard
    except ImportError:
        pass
    try:
        from compression import zstd  # Python >= 3.14
        return zstd
    except ImportError:
        return None


def _zstd_decompress(chunk: bytes, size: int) -> bytes:
    z = _zstd()
    if z is None:
        raise InputError("SPZ version 4 is zstd-compressed; install the 'zstandard' package to read it")
    try:
        if hasattr(z, "ZstdDecompressor"):
            out = z.ZstdDecompressor().decompress(chunk, max_output_size=size)
        else:  # pragma: no cover - Python 3.14's compression.zstd
            out = z.decompress(chunk)
    except z.ZstdError as e:
        raise FormatError(f"corrupt zstd stream ({e})") from None
    if len(out) != size:
        raise FormatError(f"a zstd stream inflates to {len(out)} bytes, its table says {size}")
    return out


def _read_ngsp(data: bytes) -> GaussianSet:
    if len(data) < _NGSP_HEADER.size:
        raise FormatError("truncated: shorter than the 32-byte SPZ v4 header")
    magic, version, n, degree, fbits, _flags, num_streams, toc, _ = _NGSP_HEADER.unpack_from(data)
    if version < 4:
        raise FormatError(f"an uncompressed SPZ header must be version 4 or later, got {version}")
    _check_header(n, degree, fbits, version)
    sizes = [n * b for b in _bytes_per_point(version, degree)]
    if sum(sizes) > len(data) * _MAX_RATIO:
        raise FormatError(f"the header claims {n} Gaussians, more than {len(data)} bytes can hold")
    expected = [s for s in sizes if s]
    if num_streams != len(expected):
        raise FormatError(f"{num_streams} attribute streams, expected {len(expected)}")
    if toc < _NGSP_HEADER.size or toc + 16 * num_streams > len(data):
        raise FormatError(f"table of contents at byte {toc} lies outside the file")
    table = np.frombuffer(data, "<u8", count=2 * num_streams, offset=toc).reshape(-1, 2)
    offset = toc + 16 * num_streams
    chunks = []
    for (csize, usize), want in zip(table.tolist(), expected):
        if usize != want:
            raise FormatError(f"a stream holds {usize} bytes, {n} Gaussians need {want}")
        if csize > len(data) - offset:
            raise FormatError("truncated: a compressed stream runs past the end of the file")
        chunks.append(_zstd_decompress(data[offset:offset + csize], want))
        offset += csize
    if offset != len(data):
        raise FormatError(f"{len(data) - offset} unexpected bytes after the last stream")
    it = iter(chunks)
    streams = [next(it) if s else b"" for s in sizes]
    return _decode(streams, n, version, degree, fbits)


def read_spz(path: str | os.PathLike) -> GaussianSet:
    """Read an SPZ file (versions 2, 3 and 4) into a GaussianSet (see the module notes)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    data = path.read_bytes()
    try:
        if data[:2] == b"\x1f\x8b":
            return _read_legacy(data)
        if len(data) >= 4 and struct.unpack_from("<I", data)[0] == SPZ_MAGIC:
            return _read_ngsp(data)
        raise FormatError("not an SPZ file (neither a gzip stream nor an NGSP header)")
    except AvatarKitError as e:
        raise e.with_path(path) from None


# --- encoding ----------------------------------------------------------------------------------
def _round(x: np.ndarray) -> np.ndarray:
    """C's std::round: halves away from zero (numpy rounds them to even)."""
    return np.sign(x) * np.floor(np.abs(x) + np.float32(0.5))


def _to_u8(x: np.ndarray) -> np.ndarray:
    return np.clip(_round(x), 0, 255).astype(np.uint8)


def _pack_first_three(xyzw: np.ndarray) -> np.ndarray:
    q = xyzw * np.where(xyzw[:, 3:] < 0, np.float32(-127.5), np.float32(127.5)) + np.float32(127.5)
    return _to_u8(q[:, :3])


def _pack_smallest_three(xyzw: np.ndarray) -> np.ndarray:
    a = np.abs(xyzw)
    largest = np.argmax(a, axis=1)  # first of equals, like the reference's strict '>' scan
    negate = xyzw[np.arange(len(xyzw)), largest] < 0
    comp = largest.astype(np.uint32)
    for i in range(4):
        keep = largest != i
        negbit = ((xyzw[:, i] < 0) ^ negate).astype(np.uint32)
        mag = (np.float32(511) * (a[:, i] / _SQRT1_2) + np.float32(0.5)).astype(np.uint32)
        comp = np.where(keep, (comp << np.uint32(10)) | (negbit << np.uint32(9)) | mag, comp)
    return comp.astype("<u4").view(np.uint8).reshape(-1, 4)


def _quantize_sh(x: np.ndarray, bits: int) -> np.ndarray:
    bucket = 1 << (8 - bits)
    q = _round(x * np.float32(128)).astype(np.int64) + 128
    q = (q + bucket // 2) // bucket * bucket
    return np.clip(q, 0, 255).astype(np.uint8)


def encode_streams(gs: GaussianSet, version: int | None = None, sh1_bits: int | None = None,
                   sh_rest_bits: int | None = None) -> list[bytes]:
    """The six attribute byte streams (positions, alphas, colours, scales, rotations, SH)."""
    version = DEFAULT_VERSION if version is None else version
    sh1_bits = DEFAULT_SH1_BITS if sh1_bits is None else sh1_bits
    sh_rest_bits = DEFAULT_SH_REST_BITS if sh_rest_bits is None else sh_rest_bits
    n = len(gs)
    scale = np.float32(1 << FRACTIONAL_BITS)
    fixed = _round(gs.means * scale)
    limit = 1 << 23
    if n and not ((fixed >= -limit) & (fixed < limit)).all():
        bad = int(np.flatnonzero(~((fixed >= -limit) & (fixed < limit)).all(axis=1))[0])
        raise InputError(f"Gaussian {bad} at {gs.means[bad].tolist()} lies outside SPZ's position "
                         f"range (+-{limit / scale:g} m)")
    fixed = fixed.astype(np.int32).reshape(-1)
    pos = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF], axis=1).astype(np.uint8)
    alphas = _to_u8(gs.opacities * np.float32(255))
    colors = _to_u8(gs.sh[:, 0] * (COLOR_SCALE * np.float32(255)) + np.float32(0.5 * 255))
    scales = _to_u8((np.log(gs.scales) + np.float32(10)) * np.float32(16))
    xyzw = gs.quats[:, [1, 2, 3, 0]]
    xyzw = xyzw / np.linalg.norm(xyzw, axis=1, keepdims=True)
    rots = _pack_first_three(xyzw) if version == 2 else _pack_smallest_three(xyzw)
    rest = gs.sh[:, 1:]
    sh = np.empty(rest.shape, np.uint8)
    sh[:, :3] = _quantize_sh(rest[:, :3], sh1_bits)
    sh[:, 3:] = _quantize_sh(rest[:, 3:], sh_rest_bits)
    return [a.tobytes() for a in (pos, alphas, colors, scales, rots, sh)]


def _check_write_args(version: int, sh1_bits: int, sh_rest_bits: int):
    if version not in SUPPORTED_VERSIONS:
        raise InputError(f"SPZ version must be one of {SUPPORTED_VERSIONS}, got {version}")
    for name, bits in (("sh1_bits", sh1_bits), ("sh_rest_bits", sh_rest_bits)):
        if not (isinstance(bits, int) and 1 <= bits <= 8):
            raise InputError(f"{name} must be an integer 1..8, got {bits!r}")


def spz_bytes(gs: GaussianSet, version: int | None = None, sh1_bits: int | None = None,
              sh_rest_bits: int | None = None, antialiased: bool = False) -> bytes:
    """The bytes of an SPZ file holding `gs` (version 2, 3 or 4)."""
    version = DEFAULT_VERSION if version is None else version
    sh1_bits = DEFAULT_SH1_BITS if sh1_bits is None else sh1_bits
    sh_rest_bits = DEFAULT_SH_REST_BITS if sh_rest_bits is None else sh_rest_bits
    _check_write_args(version, sh1_bits, sh_rest_bits)
    if len(gs) == 0:
        raise InputError("SPZ cannot hold an empty set (its readers reject 0 points)")
    streams = encode_streams(gs, version, sh1_bits, sh_rest_bits)
    flags = FLAG_ANTIALIASED if antialiased else 0
    if version < 4:
        header = _LEGACY_HEADER.pack(SPZ_MAGIC, version, len(gs), gs.sh_degree, FRACTIONAL_BITS, flags, 0)
        z = zlib.compressobj(6, zlib.DEFLATED, 16 + zlib.MAX_WBITS, 9)
        return z.compress(header) + b"".join(z.compress(s) for s in streams) + z.flush()
    zstd = _zstd()
    if zstd is None:
        raise InputError("SPZ version 4 is zstd-compressed; install the 'zstandard' package "
                         "or write version 3")
    comp = (zstd.ZstdCompressor(level=12).compress if hasattr(zstd, "ZstdCompressor")
            else lambda b: zstd.compress(b, 12))
    chunks = [(comp(s), len(s)) for s in streams if s]
    header = _NGSP_HEADER.pack(SPZ_MAGIC, version, len(gs), gs.sh_degree, FRACTIONAL_BITS, flags,
                               len(chunks), _NGSP_HEADER.size, bytes(12))
    toc = b"".join(struct.pack("<QQ", len(c), u) for c, u in chunks)
    return header + toc + b"".join(c for c, _ in chunks)


def write_spz(path: str | os.PathLike, gs: GaussianSet, version: int | None = None,
              sh1_bits: int | None = None, sh_rest_bits: int | None = None) -> None:
    """Write `gs` as an SPZ file (default version 3, the gzip layout every SPZ reader knows), atomically."""
    version = DEFAULT_VERSION if version is None else version
    sh1_bits = DEFAULT_SH1_BITS if sh1_bits is None else sh1_bits
    sh_rest_bits = DEFAULT_SH_REST_BITS if sh_rest_bits is None else sh_rest_bits
    path = Path(path)
    if path.suffix.lower() != ".spz":
        raise OutputError(f"an SPZ file must end in .spz, not {path.suffix!r}", path)
    try:
        data = spz_bytes(gs, version, sh1_bits, sh_rest_bits)
    except AvatarKitError as e:
        raise e.with_path(path) from None
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def register() -> None:
    """Add `.spz` to `avatarkit.gaussians.io`'s dispatch tables."""
    from avatarkit.gaussians import io

    io.register_format(".spz", loader=read_spz, saver=write_spz)


__all__ = ["read_spz", "write_spz", "spz_bytes", "encode_streams", "register", "SPZ_MAGIC",
           "SUPPORTED_VERSIONS", "DEFAULT_VERSION"]
