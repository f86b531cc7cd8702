"""`write_player(path, output, options)`: a bake as ONE self-contained HTML file that plays it.

The page (`web_player.html`, package data) holds a WebGL2 Gaussian splat renderer with the CPU
renderer's image formation (`avatarkit/render/pipeline.py`: EWA projection with the same
Jacobian clamp, 0.3 px^2 low-pass, alpha = min(0.99, o exp(-d^T conic d / 2)) skipped below
1/255, near plane 0.01 m, OpenCV camera axes, pixel centres at i + 0.5, background under the
splats) drawn back to front as quads along each splat's projected axes (6 vertices per splat
from gl_VertexID by default, instanced quads with `#draw=instanced`: the same image, but
SwiftShader ran the instanced draw ~3x slower here), in an order from a 16-bit counting sort of the
camera-space depths run in a Web Worker. SH degree 0 only: colour = max(0, SH_C0 dc + 0.5),
higher bands are dropped (the result says so). The CPU renderer stops a pixel once its
transmittance would fall below 1e-4 and ties depths exactly; the browser does neither, which
changes nothing visible.

Data (one zlib stream, base64 in the page, inflated by the browser's DecompressionStream):
per part (the bake's face and hair, or one part for a plain file), N splats, F frames,
splats whose rotation or scale moves against the part ("animated", K of them) first:

    colors        (N, 4) uint8    r, g, b over [0, color_scale], opacity over [0, 1]
    rot_static    (N,) uint32     rotation in the part's frame at frame 0 (smallest three)
    scale_static  (N, 3) uint8    log scale over the part's log range, frame 0
    rot_frames    (F, 4, K) uint8 rotation in the part's frame, per frame, animated splats only:
                                  smallest-three words, each bit field as its difference from
                                  the previous frame, as 4 byte planes (`delta_quat_words`)
    scale_frames  (F, K, 3) uint8 per frame, animated splats only, as differences mod 256 from
                                  the previous frame
    part_rot      (F, 4) float32  the part's rotation at each frame (wxyz)
    positions     (F, 2, 3N) uint8 16-bit positions over the part's box (all frames), stored as
                                  the difference from the previous frame mod 2^16, low bytes
                                  then high bytes (so zlib finds the slow motion)

The part's rotation at frame t is the least-squares rotation taking the part's frame-0 centres
to frame t's (Kabsch). A splat's rotation relative to it that stays within
`rotation_tolerance_deg` of frame 0's, and whose scales stay within `scale_tolerance` (log
units), is stored once: a rigid or near-rigid part costs positions only. The codes are in
`quantize.py`; `decode_player` is the Python twin of the page's decoder (used by the tests).

`--max-size` (`PlayerOptions.max_bytes`): when the page would be larger, a random subset of
each part's splats (same fraction for all, fixed seed) is kept so it fits; the result lists
what was dropped.
"""
from __future__ import annotations

import base64
import html
import json
import math
import os
import re
import time
import zlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from avatarkit.errors import FormatError, InputError, OutputError
from avatarkit.export import quantize as qz
from avatarkit.export.splat_frames import SplatFrames, open_splat_frames
from avatarkit.fileio import atomic_path, check_output_folder
from avatarkit.gaussians.sh import SH_C0
from avatarkit.render.pipeline import NEAR_PLANE, check_background
from avatarkit.rotations import matrix_to_quat, quat_multiply

FORMAT_NAME = "avatarkit.web-player"
FORMAT_VERSION = 1
TEMPLATE = "web_player.html"
#: the default view, as `avatarkit render`'s: vertical field of view and framing margin
DEFAULT_FOV_DEG = 30.0
DEFAULT_MARGIN = 1.15
#: tries at shrinking the subset under --max-size before giving up
MAX_SIZE_TRIES = 8


@dataclass
class PlayerOptions:
    """How `write_player` builds the page.

    max_bytes: cap on the HTML file's size; splats are subsampled to fit (None: no cap).
    background: (r, g, b) in [0, 1] composited under the splats, as the CPU renderer's.
    fps: playback rate; None keeps the source's (a plain PLY folder: 24).
    title: the page title (default: the source's name).
    rotation_tolerance_deg / scale_tolerance: how far (degrees; log units) a splat's rotation
        and scales may move against its part's rotation and still be stored once.
    seed: of the random subset under max_bytes.
    """

    max_bytes: int | None = None
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fps: float | None = None
    title: str | None = None
    rotation_tolerance_deg: float = 0.5
    scale_tolerance: float = 0.01
    seed: int = 0

    def check(self) -> None:
        if self.max_bytes is not None and (isinstance(self.max_bytes, bool) or
                                           not isinstance(self.max_bytes, (int, np.integer)) or self.max_bytes <= 0):
            raise InputError(f"max size must be a positive number of bytes, got {self.max_bytes!r}")
        check_background(self.background)
        if self.fps is not None and not (isinstance(self.fps, (int, float)) and math.isfinite(self.fps) and self.fps > 0):
            raise InputError(f"fps must be a positive number, got {self.fps!r}")
        for name in ("rotation_tolerance_deg", "scale_tolerance"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be a number >= 0, got {v!r}")


@dataclass(frozen=True)
class PlayerResult:
    """What `write_player` wrote."""

    output: Path
    bytes: int
    kind: str                    # what the source was (see SplatFrames.kind)
    frames: int
    fps: float
    splats: int                  # in the page
    source_splats: int
    dropped: dict[str, int]      # part -> splats left out to meet max_bytes
    animated: dict[str, int]     # part -> splats with per-frame rotation/scale
    sh_degree_dropped: int       # the source's SH degree when > 0 (the page shows degree 0)
    seconds: float


@dataclass
class _Part:
    """One part's codes for all its splats (before any subsampling)."""

    name: str
    order: np.ndarray            # (N,) source index of each stored splat (animated first)
    animated: int                # K
    box: tuple[np.ndarray, np.ndarray]
    log_scale: tuple[float, float]
    colors: np.ndarray           # (N, 4) uint8
    rot_static: np.ndarray       # (N,) uint32
    scale_static: np.ndarray     # (N, 3) uint8
    rot_frames: np.ndarray       # (F, K) uint32
    scale_frames: np.ndarray     # (F, K, 3) uint8
    part_rot: np.ndarray         # (F, 4) float32
    positions: np.ndarray        # (F, N, 3) uint16
    extra: dict = field(default_factory=dict)


# --- pass 1: boxes, part rotations, which splats move against their part ------------------------
def kabsch_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R (3, 3) minimising sum |R (a_i - mean a) - (b_i - mean b)|^2; a, b: (N, 3)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    h = (a - a.mean(0)).T @ (b - b.mean(0))
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def _conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _measure(src: SplatFrames, options: PlayerOptions) -> dict[str, dict]:
    stats = {}
    for name, gs in src.rest.items():
        stats[name] = dict(lo=np.full(3, np.inf), hi=np.full(3, -np.inf), llo=np.inf, lhi=-np.inf,
                           angle=np.zeros(len(gs)), dscale=np.zeros(len(gs)), part_rot=[],
                           rest_means=gs.means.astype(np.float64), q0=None, ls0=None)
    for frame in src.frames():
        for name, (means, quats, scales) in frame.items():
            s = stats[name]
            s["lo"] = np.minimum(s["lo"], means.min(0))
            s["hi"] = np.maximum(s["hi"], means.max(0))
            ls = np.log(scales.astype(np.float64))
            s["llo"], s["lhi"] = min(s["llo"], float(ls.min())), max(s["lhi"], float(ls.max()))
            r = kabsch_rotation(s["rest_means"], means) if src.n_frames > 1 else np.eye(3)
            qr = matrix_to_quat(r)
            s["part_rot"].append(qr)
            local = quat_multiply(_conj(qr)[None], quats.astype(np.float64))
            local /= np.linalg.norm(local, axis=1, keepdims=True)
            if s["q0"] is None:
                s["q0"], s["ls0"] = local, ls
            else:
                np.maximum(s["angle"], qz.quat_angle_deg(local, s["q0"]), out=s["angle"])
                np.maximum(s["dscale"], np.abs(ls - s["ls0"]).max(1), out=s["dscale"])
    for s in stats.values():
        s["animated"] = (s["angle"] > options.rotation_tolerance_deg) | (s["dscale"] > options.scale_tolerance)
        del s["q0"], s["ls0"], s["rest_means"]
    return stats


# --- pass 2: the codes ----------------------------------------------------------------------------
def _encode(src: SplatFrames, stats: dict[str, dict]) -> tuple[list[_Part], float]:
    colours = {n: np.maximum(0.0, g.sh[:, 0].astype(np.float64) * SH_C0 + 0.5) for n, g in src.rest.items()}
    color_scale = max(1.0, max(float(c.max()) for c in colours.values()))
    parts: dict[str, _Part] = {}
    n_frames = src.n_frames
    for name, gs in src.rest.items():
        s = stats[name]
        order = np.concatenate([np.flatnonzero(s["animated"]), np.flatnonzero(~s["animated"])])
        k = int(s["animated"].sum())
        lo, hi = qz.position_box(s["lo"], s["hi"])
        llo, lhi = s["llo"], max(s["lhi"], s["llo"] + 1e-6)
        colors = np.concatenate([qz.encode_unit(colours[name][order], color_scale),
                                 qz.encode_unit(gs.opacities[order])[:, None]], axis=1)
        parts[name] = _Part(name, order, k, (lo, hi), (llo, lhi), colors,
                            np.zeros(len(gs), np.uint32), np.zeros((len(gs), 3), np.uint8),
                            np.zeros((n_frames, k), np.uint32), np.zeros((n_frames, k, 3), np.uint8),
                            np.asarray(s["part_rot"], np.float32).reshape(n_frames, 4),
                            np.zeros((n_frames, len(gs), 3), np.uint16))
    for f, frame in enumerate(src.frames()):
        for name, (means, quats, scales) in frame.items():
            p = parts[name]
            o, k = p.order, p.animated
            p.positions[f] = qz.encode_positions(means[o], *p.box)
            local = quat_multiply(_conj(p.part_rot[f].astype(np.float64))[None], quats[o].astype(np.float64))
            if f == 0:
                p.rot_static[:] = qz.encode_quats(local)
                p.scale_static[:] = qz.encode_log_scales(scales[o], *p.log_scale)
            p.rot_frames[f] = qz.encode_quats(local[:k])
            p.scale_frames[f] = qz.encode_log_scales(scales[o[:k]], *p.log_scale)
    return list(parts.values()), color_scale


def encode_frames(src: SplatFrames, options: PlayerOptions | None = None) -> tuple[list[_Part], float]:
    """Both passes over the frames: the parts' codes (all splats) and the colour scale."""
    options = options or PlayerOptions()
    return _encode(src, _measure(src, options))


def _subset(p: _Part, keep: np.ndarray) -> _Part:
    """The part restricted to stored rows `keep` (sorted), animated rows staying first."""
    ka = keep[keep < p.animated]
    return _Part(p.name, p.order[keep], len(ka), p.box, p.log_scale, p.colors[keep], p.rot_static[keep],
                 p.scale_static[keep], p.rot_frames[:, ka], p.scale_frames[:, ka], p.part_rot,
                 p.positions[:, keep])


# --- packing ----------------------------------------------------------------------------------------
def delta_planes(positions: np.ndarray) -> np.ndarray:
    """(F, N, 3) uint16 -> (F, 2, 3N) uint8: frame-to-frame differences mod 2^16, low bytes
    then high bytes per frame (frame 0 as is)."""
    q = positions.reshape(len(positions), -1)
    d = q.copy()
    d[1:] = q[1:] - q[:-1]  # uint16 arithmetic wraps: mod 2^16
    return np.stack([(d & 0xFF).astype(np.uint8), (d >> 8).astype(np.uint8)], axis=1)


#: bit fields of a smallest-three word (see quantize.py), high to low: index, three components
_QUAT_FIELDS = ((30, 2), (20, 10), (10, 10), (0, 10))


def delta_quat_words(words: np.ndarray) -> np.ndarray:
    """(F, K) uint32 smallest-three words -> (F, 4, K) uint8: each bit field's difference from the
    previous frame mod its size, packed back into a word, split into its 4 bytes (low first).
    A slowly turning splat then gives bytes near 0 and 255, which zlib packs well."""
    w = np.asarray(words, np.uint32)
    d = w.copy()
    if len(w) > 1:
        d[1:] = 0
        for shift, bits in _QUAT_FIELDS:
            mask = np.uint32((1 << bits) - 1)
            f = (w >> np.uint32(shift)) & mask
            d[1:] |= ((f[1:] - f[:-1]) & mask) << np.uint32(shift)
    return np.stack([((d >> np.uint32(8 * b)) & np.uint32(0xFF)).astype(np.uint8) for b in range(4)], axis=1)


def undelta_quat_words(planes: np.ndarray) -> np.ndarray:
    """Inverse of `delta_quat_words`: (F, 4, K) uint8 -> (F, K) uint32."""
    d = sum(planes[:, b].astype(np.uint32) << np.uint32(8 * b) for b in range(4))
    out = np.zeros_like(d)
    for shift, bits in _QUAT_FIELDS:
        mask = np.uint32((1 << bits) - 1)
        f = np.cumsum((d >> np.uint32(shift)) & mask, axis=0, dtype=np.uint32) & mask
        out |= f << np.uint32(shift)
    return out


def delta_bytes(codes: np.ndarray) -> np.ndarray:
    """(F, ...) uint8 -> frame-to-frame differences mod 256 (frame 0 as is)."""
    d = np.asarray(codes, np.uint8).copy()
    d[1:] = codes[1:] - codes[:-1]
    return d


def undelta_bytes(deltas: np.ndarray) -> np.ndarray:
    return np.cumsum(deltas, axis=0, dtype=np.uint8)


def undelta_planes(planes: np.ndarray, n: int) -> np.ndarray:
    """Inverse of `delta_planes`: (F, 2, 3N) uint8 -> (F, N, 3) uint16."""
    d = planes[:, 0].astype(np.uint16) | (planes[:, 1].astype(np.uint16) << 8)
    return np.cumsum(d, axis=0, dtype=np.uint16).reshape(len(planes), n, 3)


def pack_parts(parts: list[_Part]) -> tuple[bytes, list[dict]]:
    chunks: list[bytes] = []
    offset = 0
    specs = []
    for p in parts:
        arrays = dict(colors=p.colors, rot_static=p.rot_static, scale_static=p.scale_static,
                      rot_frames=delta_quat_words(p.rot_frames), scale_frames=delta_bytes(p.scale_frames),
                      part_rot=p.part_rot.astype(np.float32), positions=delta_planes(p.positions))
        spec = {}
        for key, a in arrays.items():
            a = np.ascontiguousarray(a)
            spec[key] = dict(offset=offset, dtype=str(a.dtype), length=int(a.size), shape=list(a.shape))
            b = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
            pad = (-len(b)) % 4  # typed-array views need aligned offsets
            chunks.append(b + b"\0" * pad)
            offset += len(b) + pad
        specs.append(dict(name=p.name, count=int(len(p.order)), animated=int(p.animated),
                          box=[np.asarray(p.box[0]).tolist(), np.asarray(p.box[1]).tolist()],
                          log_scale=[float(p.log_scale[0]), float(p.log_scale[1])], arrays=spec))
    return b"".join(chunks), specs


def _template() -> str:
    return resources.files("avatarkit.export").joinpath(TEMPLATE).read_text(encoding="utf-8")


def _page_parts(title: str, header: dict) -> tuple[str, str]:
    """The page around the base64 data: (before, after)."""
    text = _template()
    head_json = json.dumps(header, separators=(",", ":")).replace("</", "<\\/")
    text = text.replace("__TITLE__", html.escape(title)).replace("__HEADER__", head_json)
    before, marker, after = text.partition("__DATA__")
    if not marker:
        raise RuntimeError("web player template has no __DATA__ marker")
    return before, after


def _html_bytes(before: str, payload: bytes, after: str) -> int:
    return len(before.encode()) + 4 * ((len(payload) + 2) // 3) + len(after.encode())


_UNITS = {"": 1, "b": 1, "k": 1000, "kb": 1000, "m": 10**6, "mb": 10**6, "g": 10**9, "gb": 10**9,
          "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30}


def parse_size(text) -> int:
    """"50MB", "800 kB", "20MiB", "1.5G" or a plain byte count -> bytes (MB = 10^6, MiB = 2^20)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*([a-z]*)\s*", str(text).lower())
    if not m or m.group(2) not in _UNITS:
        raise InputError(f"cannot read size {text!r}: use e.g. 50MB, 800KB, 20MiB or a number of bytes")
    n = int(float(m.group(1)) * _UNITS[m.group(2)])
    if n <= 0:
        raise InputError(f"size must be more than 0 bytes, got {text!r}")
    return n


# --- the one call ----------------------------------------------------------------------------------
def check_output(output: str | os.PathLike) -> Path:
    """OutputError unless `output` is a .html name in an existing, writable folder."""
    output = Path(output)
    if output.suffix.lower() not in (".html", ".htm"):
        raise OutputError(f"the player is an HTML page: name it .html, not {output.suffix or '(no extension)'!r}",
                          output)
    if output.is_dir():
        raise OutputError("is a folder, not a file name", output)
    check_output_folder(output.parent)
    return output


def write_player(source: str | os.PathLike | SplatFrames, output: str | os.PathLike,
                 options: PlayerOptions | None = None, progress=None) -> PlayerResult:
    """Read a bake (USD stage, PLY sequence folder, avatar folder or splat file, or frames
    already opened with `open_splat_frames`) and write `output` (.html), a page that plays it.
    `progress(done, total)` follows the two passes over the frames. See the module notes."""
    t0 = time.perf_counter()
    options = options or PlayerOptions()
    options.check()
    output = check_output(output)
    src = source if isinstance(source, SplatFrames) else open_splat_frames(source, options.fps)
    path = src.source
    fps = float(options.fps or src.fps)
    total = 2 * src.n_frames
    done = [0]

    def counted(it):
        for item in it:
            yield item
            done[0] += 1
            if progress:
                progress(done[0], total)

    measuring = SplatFrames(src.source, src.kind, src.fps, src.n_frames, src.rest, lambda: counted(src.frames()))
    parts, color_scale = encode_frames(measuring, options)

    from avatarkit.gaussians.gaussian_set import GaussianSet
    from avatarkit.render.views import framing

    target, distance = framing(GaussianSet.concat([g.replace(extras={}) for g in src.rest.values()]),
                               DEFAULT_FOV_DEG, 512, 512, DEFAULT_MARGIN)
    header = dict(format=FORMAT_NAME, version=FORMAT_VERSION, source=Path(path).name, kind=src.kind,
                  fps=fps, n_frames=src.n_frames, near=NEAR_PLANE,
                  background=[float(v) for v in check_background(options.background)],
                  color_scale=color_scale, sh_degree_source=src.sh_degree,
                  camera=dict(target=[float(v) for v in target], distance=float(distance), azimuth=0.0,
                              elevation=0.0, fov=DEFAULT_FOV_DEG))
    title = options.title or f"{Path(path).name} - avatarkit player"
    source_counts = {p.name: len(p.order) for p in parts}
    rng = np.random.default_rng(options.seed)
    ranks = {p.name: rng.permutation(len(p.order)) for p in parts}  # drop order, fixed per run
    fraction = 1.0
    for _ in range(MAX_SIZE_TRIES):
        kept = [p if fraction >= 1.0 else _subset(p, np.sort(ranks[p.name][:max(1, int(len(p.order) * fraction))]))
                for p in parts]
        raw, specs = pack_parts(kept)
        header.update(parts=specs, raw_bytes=len(raw),
                      dropped={p.name: source_counts[p.name] - len(k.order) for p, k in zip(parts, kept)})
        payload = zlib.compress(raw, 6)
        before, after = _page_parts(title, header)
        size = _html_bytes(before, payload, after)
        if options.max_bytes is None or size <= options.max_bytes:
            break
        fixed = _html_bytes(before, b"", after)
        if options.max_bytes <= fixed or all(len(k.order) <= 1 for k in kept):
            raise InputError(f"--max-size {options.max_bytes:,} bytes is below what the page needs without "
                             f"any splats ({fixed:,} bytes)")
        # data scale with the splats kept; aim a little under the cap
        fraction *= max(0.01, 0.97 * (options.max_bytes - fixed) / (size - fixed))
    else:
        raise InputError(f"could not fit the page under --max-size {options.max_bytes:,} bytes "
                         f"(last try {size:,} bytes)")
    with atomic_path(output) as tmp:
        with open(tmp, "wb") as f:
            f.write(before.encode())
            f.write(base64.b64encode(payload))
            f.write(after.encode())
    return PlayerResult(output, output.stat().st_size, src.kind, src.n_frames, fps,
                        sum(len(k.order) for k in kept), src.count, header["dropped"],
                        {k.name: k.animated for k in kept}, src.sh_degree if src.sh_degree > 0 else 0,
                        time.perf_counter() - t0)


# --- reading a page back (tests, inspection) ----------------------------------------------------------
_SCRIPT = r'<script id="{}" type="[^"]*">(.*?)</script>'


def read_player(path: str | os.PathLike) -> tuple[dict, bytes]:
    """(header, raw data bytes) of a page `write_player` wrote; FormatError otherwise."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise FormatError(f"cannot read the page ({e})", path) from None
    head = re.search(_SCRIPT.format("avatarkit-header"), text, re.S)
    data = re.search(_SCRIPT.format("avatarkit-data"), text, re.S)
    if not head or not data:
        raise FormatError("not an avatarkit player page", path)
    header = json.loads(head.group(1).replace("<\\/", "</"))
    if header.get("format") != FORMAT_NAME:
        raise FormatError("not an avatarkit player page", path)
    raw = zlib.decompress(base64.b64decode(data.group(1).strip()))
    if len(raw) != header["raw_bytes"]:
        raise FormatError("the page's data is damaged", path)
    return header, raw


def decode_player(header: dict, raw: bytes) -> dict[str, dict[str, np.ndarray]]:
    """What the page's JavaScript reconstructs, per part: means (F, N, 3), quats (F, N, 4) wxyz
    (world), scales (F, N, 3), colors (N, 3), opacities (N,), order (N,) source indices."""
    out = {}
    n_frames = header["n_frames"]
    for p in header["parts"]:
        def arr(key, _p=p):
            s = _p["arrays"][key]
            a = np.frombuffer(raw, np.dtype(s["dtype"]).newbyteorder("<"), s["length"], s["offset"])
            return a.reshape(s["shape"])
        n, k = p["count"], p["animated"]
        lo, hi = np.asarray(p["box"][0]), np.asarray(p["box"][1])
        pos = undelta_planes(arr("positions"), n)
        means = np.stack([qz.decode_positions(pos[f], lo, hi) for f in range(n_frames)])
        local = np.broadcast_to(qz.decode_quats(arr("rot_static")), (n_frames, n, 4)).copy()
        scales = np.broadcast_to(qz.decode_log_scales(arr("scale_static"), *p["log_scale"]), (n_frames, n, 3)).copy()
        if k:
            words = undelta_quat_words(arr("rot_frames"))
            local[:, :k] = qz.decode_quats(words.reshape(-1)).reshape(n_frames, k, 4)
            scales[:, :k] = qz.decode_log_scales(undelta_bytes(arr("scale_frames")), *p["log_scale"])
        quats = quat_multiply(arr("part_rot")[:, None].astype(np.float64), local.astype(np.float64)).astype(np.float32)
        colors = arr("colors")
        out[p["name"]] = dict(means=means, quats=quats, scales=scales,
                              colors=qz.decode_unit(colors[:, :3], header["color_scale"]),
                              opacities=qz.decode_unit(colors[:, 3]))
    return out


__all__ = ["check_output", "PlayerOptions", "PlayerResult", "write_player", "read_player", "decode_player",
           "delta_planes", "undelta_planes", "delta_quat_words", "undelta_quat_words",
           "delta_bytes", "undelta_bytes", "kabsch_rotation", "encode_frames", "pack_parts",
           "parse_size", "FORMAT_NAME"]
