"""Compact codes for splat attributes (what the web player embeds), each with its decoder.

- positions: 16 bits per axis over a box (lo, hi): q = round((x - lo) / (hi - lo) * 65535);
  error <= (hi - lo) / 131070 per axis (half a step) plus float32 rounding.
- quaternions: "smallest three" in 32 bits: the index of the largest |component| in the top 2
  bits (that component made positive, since q and -q are one rotation), the other three in
  10 bits each over [-1/sqrt 2, 1/sqrt 2] (no smaller component can lie outside), in
  increasing component order from bit 20 down to bit 0. Half a step is 6.9e-4 per component,
  so the rotation is off by < 0.25 degrees (measured 0.21; test: `test_web_player.py`).
- scales: 8 bits of log(scale) over a range (lo, hi) of logs: relative error
  <= exp((hi - lo) / 510) - 1.
- colours and opacities: 8 bits over [0, colour_scale] and [0, 1].

Every encoder is vectorised numpy; the decoders are the obvious inverses and are what the
player's JavaScript does too (`web_player.html`: `decodeQuat`, `decodeScales`, `buildFrame`).
"""
from __future__ import annotations

import numpy as np

QUAT_BITS = 10
QUAT_LEVELS = (1 << QUAT_BITS) - 1
QUAT_MAX = float(np.sqrt(0.5))


def position_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64 widened where an axis is flat, so every step is > 0."""
    lo = np.asarray(lo, np.float64).copy()
    hi = np.asarray(hi, np.float64).copy()
    flat = ~(hi - lo > 1e-9)
    hi[flat] = lo[flat] + 1e-6
    return lo, hi


def encode_positions(means: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """means (N, 3) inside the box -> (N, 3) uint16."""
    t = (np.asarray(means, np.float64) - lo) / (hi - lo)
    return np.clip(np.rint(t * 65535.0), 0, 65535).astype(np.uint16)


def decode_positions(codes: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N, 3) uint16 -> (N, 3) float32, as the player computes them."""
    lo = np.asarray(lo, np.float64)
    step = (np.asarray(hi, np.float64) - lo) / 65535.0
    return (lo + codes.astype(np.float64) * step).astype(np.float32)


def encode_quats(quats: np.ndarray) -> np.ndarray:
    """(N, 4) wxyz (any length > 0) -> (N,) uint32 smallest-three words."""
    q = np.asarray(quats, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    n = len(q)
    big = np.argmax(np.abs(q), axis=1)
    sign = np.where(q[np.arange(n), big] < 0, -1.0, 1.0)
    q = q * sign[:, None]
    # the three others, in increasing component order
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[big]   # (N, 3)
    small = np.take_along_axis(q, others, axis=1)
    codes = np.clip(np.rint((small / QUAT_MAX + 1.0) * 0.5 * QUAT_LEVELS), 0, QUAT_LEVELS).astype(np.uint32)
    return (big.astype(np.uint32) << 30) | (codes[:, 0] << 20) | (codes[:, 1] << 10) | codes[:, 2]


def decode_quats(words: np.ndarray) -> np.ndarray:
    """(N,) uint32 -> (N, 4) float32 unit wxyz."""
    w = np.asarray(words, np.uint32)
    n = len(w)
    big = (w >> 30).astype(np.int64)
    small = np.stack([(w >> s) & QUAT_LEVELS for s in (20, 10, 0)], axis=1).astype(np.float64)
    small = (small / QUAT_LEVELS * 2.0 - 1.0) * QUAT_MAX
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[big]
    q = np.zeros((n, 4))
    np.put_along_axis(q, others, small, axis=1)
    q[np.arange(n), big] = np.sqrt(np.maximum(0.0, 1.0 - (small ** 2).sum(1)))
    return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)


def encode_log_scales(scales: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """scales (...) > 0 -> uint8 codes of log(scale) over [lo, hi]."""
    span = max(hi - lo, 1e-6)
    t = (np.log(np.asarray(scales, np.float64)) - lo) / span
    return np.clip(np.rint(t * 255.0), 0, 255).astype(np.uint8)


def decode_log_scales(codes: np.ndarray, lo: float, hi: float) -> np.ndarray:
    span = max(hi - lo, 1e-6)
    return np.exp(lo + codes.astype(np.float64) * (span / 255.0)).astype(np.float32)


def encode_unit(values: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """values in [0, scale] -> uint8 (clamped)."""
    return np.clip(np.rint(np.asarray(values, np.float64) / scale * 255.0), 0, 255).astype(np.uint8)


def decode_unit(codes: np.ndarray, scale: float = 1.0) -> np.ndarray:
    return (codes.astype(np.float32) / np.float32(255.0) * np.float32(scale)).astype(np.float32)


def quat_angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (degrees) of the rotation between unit quaternions a and b (N, 4), sign-blind."""
    d = np.abs(np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64), axis=-1))
    return np.degrees(2.0 * np.arccos(np.clip(d, 0.0, 1.0)))


__all__ = ["position_box", "encode_positions", "decode_positions", "encode_quats", "decode_quats",
           "encode_log_scales", "decode_log_scales", "encode_unit", "decode_unit", "quat_angle_deg"]
