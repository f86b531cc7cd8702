"""Procedural hair: strands grown from the scalp of a head-sized ellipsoid, as thin Gaussians.

Deterministic for a given seed. Sizes are those of a real head (metres, +Y up, face toward +Z):
the default ellipsoid has semi-axes 7.8 x 9.5 x 9.0 cm. Roots lie on the scalp region only
(above a hairline that runs from the forehead down to the nape), and every strand point stays
outside the head ellipsoid, so no hair covers the face or sinks into the skull.

Each strand is a polyline resampled to equal-length segments; each segment becomes one Gaussian
whose longest axis (scale index 0) lies along the segment, with 1 sigma = half the segment
length so neighbours join up, and two thin axes of a few tenths of a millimetre.

Styles (HAIR_STYLES):
    long_straight  combed over the head, then falling straight, 0.25-0.35 m below the crown
    bob            the same, jaw length (0.15-0.19 m below the crown), ends curled in
    ponytail       gathered tight at the back of the head, a tail hanging 0.2-0.26 m
    curly          a curly blob: helical strands standing off the scalp
    short          3-5 cm strands combed back, hugging the scalp
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rotations import matrix_to_quat

HAIR_STYLES = ("long_straight", "bob", "ponytail", "curly", "short")

# segments per strand: curls need short segments to follow the helix
_SEGMENTS = {"long_straight": 32, "bob": 16, "ponytail": 28, "curly": 36, "short": 6}
_COLORS = {  # linear-ish RGB base colour per style
    "long_straight": (0.24, 0.15, 0.09),
    "bob": (0.09, 0.075, 0.07),
    "ponytail": (0.45, 0.22, 0.11),
    "curly": (0.16, 0.11, 0.08),
    "short": (0.55, 0.42, 0.26),
}
#: every strand point keeps at least this clearance (metres) outside the head ellipsoid
CLEARANCE = 0.0015


@dataclass(frozen=True)
class HeadEllipsoid:
    """The head the hair grows on: an axis-aligned ellipsoid (metres)."""

    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radii: tuple[float, float, float] = (0.078, 0.095, 0.090)

    def __post_init__(self):
        c, r = np.asarray(self.center, float), np.asarray(self.radii, float)
        if c.shape != (3,) or r.shape != (3,) or not np.isfinite(c).all() or not (r > 0).all():
            raise InputError(f"head ellipsoid needs a finite centre (3,) and radii (3,) > 0, "
                             f"got {self.center}, {self.radii}")

    @classmethod
    def sphere(cls, radius: float, center=(0.0, 0.0, 0.0)) -> "HeadEllipsoid":
        return cls(tuple(map(float, center)), (float(radius),) * 3)

    @property
    def crown_y(self) -> float:
        return float(self.center[1] + self.radii[1])

    def level(self, points: np.ndarray) -> np.ndarray:
        """points: (P, 3) -> (P,) ellipsoid level, |(p - c) / r|: < 1 inside, 1 on the surface."""
        q = (np.asarray(points, np.float64) - self.center) / np.asarray(self.radii)
        return np.linalg.norm(q, axis=-1)

    def push_out(self, points: np.ndarray, clearance: float | None = None) -> np.ndarray:
        """points: (..., 3) -> the same with those closer than ~`clearance` moved out radially."""
        clearance = CLEARANCE if clearance is None else clearance
        c = np.asarray(self.center)
        big = np.asarray(self.radii) + clearance
        q = (points - c) / big
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        inside = n < 1.0
        moved = c + big * q / np.where(n > 1e-12, n, 1.0)
        return np.where(inside, moved, points)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _sample_scalp(rng: np.random.Generator, count: int) -> np.ndarray:
    """Unit directions (count, 3) from the ellipsoid centre, above the hairline.

    The hairline's elevation falls from ~24 degrees at the forehead to ~-34 degrees at the nape
    (azimuth measured around +Y from the face direction +Z).
    """
    out = []
    have = 0
    while have < count:
        d = _unit(rng.standard_normal((2 * count + 64, 3)))
        elevation = np.arcsin(np.clip(d[:, 1], -1, 1))
        azimuth = np.arctan2(d[:, 0], d[:, 2])
        e_min = 0.42 + (-0.60 - 0.42) * (1 - np.cos(azimuth)) / 2
        d = d[elevation > e_min]
        out.append(d)
        have += len(d)
    return np.concatenate(out)[:count]


def _resample(paths: np.ndarray, segments: int) -> np.ndarray:
    """paths: (S, T, 3) polylines (possibly with repeated points) -> (S, segments + 1, 3) at
    equal arc-length steps."""
    s_count, t_count, _ = paths.shape
    seg = np.linalg.norm(np.diff(paths, axis=1), axis=2)                  # (S, T-1)
    cum = np.concatenate([np.zeros((s_count, 1)), np.cumsum(seg, axis=1)], axis=1)  # (S, T)
    total = cum[:, -1:]
    targets = total * np.linspace(0.0, 1.0, segments + 1)[None]            # (S, K+1)
    # one searchsorted over all strands: offset each strand's arc lengths into its own range
    offset = (np.arange(s_count) * (total.max() * 2 + 1.0))[:, None]
    flat = (cum + offset).ravel()
    idx = np.searchsorted(flat, (targets + offset).ravel(), side="right") - 1
    idx = np.clip(idx.reshape(s_count, -1) - (np.arange(s_count) * t_count)[:, None], 0, t_count - 2)
    rows = np.arange(s_count)[:, None]
    c0, c1 = cum[rows, idx], cum[rows, idx + 1]
    f = np.where(c1 > c0, (targets - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.0)[..., None]
    return paths[rows, idx] * (1 - f) + paths[rows, idx + 1] * f


def _march(head: HeadEllipsoid, d0: np.ndarray, layer: np.ndarray, steps: int, ds: float, comb,
           stop=None, fall_below: float | None = None, y_end=None, splay: float = 0.0,
           curl: np.ndarray | None = None) -> np.ndarray:
    """Grow strands from roots at unit directions d0 (S, 3) on the ellipsoid grown by `layer` (S,).

    While on the head a strand walks along its offset ellipsoid in the tangent direction of
    comb(d (S,3), p (S,3)) -> (S,3); once its direction's y drops below `fall_below` it falls
    (straight down, spreading out by `splay`, curling inward over the last `curl` (S,) metres)
    until it reaches y_end (S,). `stop(p) -> (S,) bool` freezes strands early. Returns (S, steps+1, 3).
    """
    c = np.asarray(head.center, np.float64)
    big = np.asarray(head.radii, np.float64)[None] + layer[:, None]  # (S, 3) offset radii
    p = c + big * d0
    falling = np.zeros(len(d0), bool) if fall_below is None else d0[:, 1] <= fall_below
    out = [p]
    down = np.array([0.0, -1.0, 0.0])
    for _ in range(steps):
        d = _unit((p - c) / big)
        normal = _unit(d / big)
        g = comb(d, p)
        g = _unit(g - np.sum(g * normal, axis=1, keepdims=True) * normal)
        p_surf = c + big * _unit((p + ds * g - c) / big)
        p_new = p_surf
        if fall_below is not None:
            horiz = _unit((p - c) * np.array([1.0, 0.0, 1.0]))
            v = down + splay * horiz
            if curl is not None:
                curling = (p[:, 1] < y_end + curl)[:, None]
                v = np.where(curling, down - 1.2 * horiz, v)
            p_fall = p + ds * _unit(v)
            p_new = np.where(falling[:, None], p_fall, p_surf)
            falling = falling | (_unit((p_new - c) / big)[:, 1] <= fall_below)
        frozen = np.zeros(len(p), bool)
        if y_end is not None:
            frozen |= p[:, 1] <= y_end
        if stop is not None:
            frozen |= stop(p)
        p = np.where(frozen[:, None], p, p_new)
        out.append(p)
    return np.stack(out, axis=1)


def _comb_down(d: np.ndarray, p: np.ndarray) -> np.ndarray:
    # down, and away from the face: over the front half the hair is combed back and to the
    # sides hard enough to climb over the forehead instead of falling onto the face
    h = _unit(np.stack([1.5 * d[:, 0], np.zeros(len(d)), np.minimum(d[:, 2], 0) - 0.5], axis=1))
    front = np.clip(d[:, 2], 0.0, 1.0)[:, None]
    return np.array([0.0, -1.0, 0.0]) * (1 - front) + (0.8 + 2.0 * front) * h


def hair_strands(style: str, strands: int = 1000, seed: int = 0,
                 head: HeadEllipsoid | None = None) -> np.ndarray:
    """Strand polylines (S, K + 1, 3) float64 for `style`, K segments each (see module doc)."""
    if style not in HAIR_STYLES:
        raise InputError(f"unknown hair style {style!r}; choose one of {', '.join(HAIR_STYLES)}")
    if strands < 1:
        raise InputError(f"need at least one strand, got {strands}")
    head = head or HeadEllipsoid()
    rng = np.random.default_rng(seed)
    c = np.asarray(head.center, np.float64)
    r = np.asarray(head.radii, np.float64)
    scale = float(np.mean(r)) / 0.0877  # styles are tuned on the default head; scale lengths along
    d0 = _sample_scalp(rng, strands)
    s = strands

    if style in ("long_straight", "bob"):
        if style == "long_straight":
            layer = rng.uniform(0.002, 0.014, s) * scale
            y_end = head.crown_y - rng.uniform(0.25, 0.35, s) * scale
            curl = None
        else:
            layer = rng.uniform(0.003, 0.018, s) * scale
            y_end = head.crown_y - rng.uniform(0.15, 0.19, s) * scale
            curl = rng.uniform(0.015, 0.03, s) * scale
        # roots low on the nape still grow a strand at least 3-6 cm long
        root_y = head.center[1] + head.radii[1] * d0[:, 1]
        y_end = np.minimum(y_end, root_y - rng.uniform(0.03, 0.06, s) * scale)
        paths = _march(head, d0, layer, steps=200, ds=0.004 * scale, comb=_comb_down,
                       fall_below=0.0, y_end=y_end, splay=0.12, curl=curl)
    elif style == "short":
        layer = rng.uniform(0.002, 0.005, s) * scale
        length = rng.uniform(0.03, 0.05, s) * scale
        paths = _short_paths(head, d0, layer, length, steps=40)
    elif style == "ponytail":
        layer = rng.uniform(0.0015, 0.004, s) * scale
        d_tie = _unit(np.array([0.0, 0.3, -1.0]))
        tie = c + r * d_tie
        tie_normal = _unit(d_tie / r)
        gather = rng.uniform(0.006, 0.014, s) * scale
        phase1 = _march(head, d0, layer, steps=90, ds=0.004 * scale, comb=lambda d, p: tie - p,
                        stop=lambda p: np.linalg.norm(p - tie, axis=1) < gather)
        length = rng.uniform(0.20, 0.26, s) * scale
        u = np.linspace(0.0, 1.0, 80)[None, :, None]                           # (1, T, 1)
        start = tie + tie_normal * 0.012 * scale
        u = np.broadcast_to(u, (s, u.shape[1], 1))
        centre = start + np.concatenate([
            np.zeros_like(u), -length[:, None, None] * u,
            -0.05 * scale * np.sin(np.minimum(2 * u, 1.0) * np.pi / 2)], axis=2)
        spread = _unit(rng.standard_normal((s, 3))) * rng.uniform(0, 1, (s, 1)) ** (1 / 3)
        radius = (0.008 + 0.02 * u) * scale                                    # (1, T, 1)
        tail = centre + radius * spread[:, None, :]
        paths = np.concatenate([phase1, tail], axis=1)
    else:  # curly
        normal = _unit(d0 / r)
        front = np.maximum(d0[:, 2], 0.0)[:, None]
        axis = _unit(normal + np.array([0.0, -0.35, 0.0]) * (1 - front))
        b1 = _unit(np.cross(axis, rng.standard_normal((s, 3))))
        b2 = np.cross(axis, b1)
        length = rng.uniform(0.05, 0.08, s) * scale
        t = np.linspace(0.0, 1.0, 240)[None, :] * length[:, None]              # (S, T)
        rho = rng.uniform(0.006, 0.010, s)[:, None] * scale
        rho = rho * np.clip(t / (0.015 * scale), 0, 1) ** 2                   # no curl at the root
        omega = 2 * np.pi / (rng.uniform(0.012, 0.018, s)[:, None] * scale)
        phase = rng.uniform(0, 2 * np.pi, s)[:, None]
        root = c + (r + 0.002 * scale) * d0
        ang = omega * t + phase
        paths = (root[:, None] + axis[:, None] * t[..., None]
                 + rho[..., None] * (np.cos(ang)[..., None] * b1[:, None] + np.sin(ang)[..., None] * b2[:, None]))

    polylines = _resample(paths, _SEGMENTS[style])
    # a little low-frequency waviness so strands are not perfectly parallel (after resampling,
    # where samples are evenly spaced along the strand: frozen path ends must not wiggle)
    if style in ("long_straight", "bob", "ponytail"):
        t = np.linspace(0.0, 1.0, polylines.shape[1])[None, :, None]
        length = np.linalg.norm(np.diff(polylines, axis=1), axis=2).sum(axis=1)[:, None, None]
        amp = rng.uniform(0.002, 0.006, (s, 1, 3)) * length
        freq = rng.uniform(2.0, 5.0, (s, 1, 1))
        ph = rng.uniform(0, 2 * np.pi, (s, 1, 3))
        polylines = polylines + amp * np.sin(2 * np.pi * freq * t + ph) * t
    return head.push_out(polylines, CLEARANCE * scale)


def _comb_back(d: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.stack([0.4 * d[:, 0], np.full(len(d), -0.2), np.full(len(d), -1.0)], axis=1)


def _short_paths(head: HeadEllipsoid, d0, layer, length, steps: int) -> np.ndarray:
    """Each strand walks its own `length` (S,) along its offset ellipsoid, combed back."""
    c = np.asarray(head.center, np.float64)
    big = np.asarray(head.radii, np.float64)[None] + layer[:, None]
    p = c + big * d0
    out = [p]
    ds = (length / steps)[:, None]
    heading = np.zeros_like(p)
    for _ in range(steps):
        d = _unit((p - c) / big)
        normal = _unit(d / big)
        # keep going the way it went where the comb points into the head (no zig-zag in place)
        g = _unit(_comb_back(d, p)) + heading
        g = _unit(g - np.sum(g * normal, axis=1, keepdims=True) * normal)
        p_new = c + big * _unit((p + ds * g - c) / big)
        heading = _unit(p_new - p)
        p = p_new
        out.append(p)
    return np.stack(out, axis=1)


def make_hair(style: str = "long_straight", n: int = 20000, seed: int = 0,
              head: HeadEllipsoid | None = None, head_radius: float | None = None,
              color=None) -> GaussianSet:
    """A procedural hair GaussianSet of exactly `n` Gaussians (SH degree 0).

    head: the ellipsoid the hair grows on (default: HeadEllipsoid()); or give `head_radius` for
    a sphere at the origin. color: base RGB in [0, 1] (default per style); strands vary around it.
    extras: `strand` (n,) int32, the strand each Gaussian belongs to.
    """
    if head is not None and head_radius is not None:
        raise InputError("give either head or head_radius, not both")
    if head_radius is not None:
        if not (np.isfinite(head_radius) and head_radius > 0):
            raise InputError(f"head_radius must be > 0, got {head_radius}")
        head = HeadEllipsoid.sphere(head_radius)
    head = head or HeadEllipsoid()
    if int(n) != n or n < 1:
        raise InputError(f"n must be a positive integer, got {n}")
    n = int(n)
    k = _SEGMENTS.get(style, 1)
    strands = -(-n // k)
    lines = hair_strands(style, strands, seed, head)                 # (S, K+1, 3)
    rng = np.random.default_rng([seed, 1])
    a, b = lines[:, :-1].reshape(-1, 3)[:n], lines[:, 1:].reshape(-1, 3)[:n]
    strand_id = np.repeat(np.arange(strands, dtype=np.int32), k)[:n]
    seg = b - a
    length = np.linalg.norm(seg, axis=1)
    tangent = seg / np.maximum(length, 1e-12)[:, None]
    helper = _unit(rng.standard_normal((n, 3)))
    b1 = np.cross(tangent, helper)
    weak = np.linalg.norm(b1, axis=1) < 1e-3
    b1[weak] = np.cross(tangent[weak], np.array([0.0, 0.0, 1.0]) + helper[weak] * 0.5)
    b1 = _unit(b1)
    b2 = np.cross(tangent, b1)
    rot = np.stack([tangent, b1, b2], axis=2)                       # columns: local x, y, z
    size = float(np.mean(head.radii)) / 0.0877
    thin = rng.uniform(0.00025, 0.0005, n) * size
    scales = np.stack([np.maximum(0.5 * length, 1.5 * thin), thin,
                       thin * rng.uniform(0.6, 1.0, n)], axis=1)
    base = np.asarray(_COLORS[style] if color is None else color, np.float64)
    if base.shape != (3,) or not ((base >= 0) & (base <= 1)).all():
        raise InputError(f"color must be 3 numbers in [0, 1], got {color}")
    per_strand = np.exp(rng.normal(0.0, 0.15, strands))[strand_id][:, None]
    along = np.tile(np.linspace(0.0, 1.0, k), strands)[:n][:, None]  # root 0 -> tip 1
    rgb = base * per_strand * (1 + 0.15 * along) * (1 + rng.normal(0, 0.04, (n, 3)))
    opacity = rng.uniform(0.6, 1.0, n)
    return GaussianSet.from_colors(
        (a + b) / 2, matrix_to_quat(rot), scales, opacity, np.clip(rgb, 0, 1),
        extras={"strand": strand_id})
