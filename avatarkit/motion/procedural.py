"""Procedural motion clips: nod, shake, tilt, turn, talk, idle and a "whip" stress test.

Every clip starts and ends exactly at rest (all parameters zero) and eases in and out, except
`whip`, whose moves start smoothly and stop dead (maximum speed right before a stop) to
stress the hair simulation. Head motion goes into `rotation` (the root joint) with `neck` at
zero, as FLAME trackers do. FLAME axes: +X right-to-left pitch (a positive angle tips the face
down), +Y up (yaw; positive turns the face toward +X), +Z forward (roll).
`amplitude` is the peak angle in degrees of the clip's main motion (see `DEFAULT_AMPLITUDE`);
no other head joint turns further (in `idle` the eyes' gaze drifts up to twice that).
Clips are deterministic: the same arguments give the same clip.
"""
from __future__ import annotations

import numpy as np

from avatarkit.errors import InputError
from avatarkit.motion import clip as _clip
from avatarkit.motion.clip import MotionClip, check_fps

KINDS = ("nod", "shake", "tilt", "turn", "talk", "idle", "whip")
#: degrees: nod pitch, shake yaw, tilt roll, turn yaw, talk jaw opening, idle sway yaw, whip yaw
DEFAULT_AMPLITUDE = {"nod": 15.0, "shake": 25.0, "tilt": 15.0, "turn": 40.0, "talk": 12.0,
                     "idle": 3.0, "whip": 60.0}
DEFAULT_SECONDS = {"nod": 2.0, "shake": 2.0, "tilt": 2.0, "turn": 3.0, "talk": 4.0, "idle": 6.0,
                   "whip": 3.0}
#: FLAME 2020/2023 trackers (VHAP, GaussianAvatars) use 100 expression coefficients
DEFAULT_EXPR_DIMS = 100
#: oscillations per second of the periodic kinds
_RATE_HZ = {"nod": 1.0, "shake": 1.5, "tilt": 0.75}
_AXIS = {"nod": 0, "shake": 1, "tilt": 2}


def _smoothstep(x: np.ndarray) -> np.ndarray:
    """Quintic ease 0 -> 1 with zero velocity and acceleration at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6 * x - 15) + 10)


def _envelope(u: np.ndarray, ramp: float = 0.25) -> np.ndarray:
    """1 in the middle, easing to exactly 0 at u = 0 and u = 1."""
    return _smoothstep(u / ramp) * _smoothstep((1 - u) / ramp)


def _peak_normalised(f, u: np.ndarray) -> np.ndarray:
    """f(u) scaled so its largest magnitude over the continuous interval is 1."""
    dense = np.linspace(0.0, 1.0, 20001)
    peak = np.abs(f(dense)).max()
    # A clip too short to hold one syllable/wiggle has no motion at all, not 0/0.
    return f(u) / peak if peak > 0 else np.zeros_like(u, dtype=np.float64)


def _keyframes(u: np.ndarray, keys: list[tuple[float, float]], ease) -> np.ndarray:
    """Piecewise motion through (time, value) keys (times in [0, 1], increasing), each segment
    shaped by `ease` (0 -> 1)."""
    times = np.array([k[0] for k in keys])
    values = np.array([k[1] for k in keys])
    seg = np.clip(np.searchsorted(times, u, side="right") - 1, 0, len(keys) - 2)
    span = times[seg + 1] - times[seg]
    x = np.where(span > 0, (u - times[seg]) / np.where(span > 0, span, 1), 1.0)
    return values[seg] + (values[seg + 1] - values[seg]) * ease(x)


def _hard_stop(x: np.ndarray) -> np.ndarray:
    """Ease-in that ends at full speed: a sudden stop."""
    x = np.clip(x, 0.0, 1.0)
    return x * x


def _smooth_noise(u: np.ndarray, rng: np.random.Generator, n_waves: int, max_cycles: float) -> np.ndarray:
    """A smooth deterministic wiggle in about [-1, 1]: a few sines of random phase."""
    cycles = rng.uniform(0.5, max_cycles, n_waves)
    phases = rng.uniform(0, 2 * np.pi, n_waves)
    weights = rng.uniform(0.5, 1.0, n_waves)
    return (weights * np.sin(2 * np.pi * np.outer(u, cycles) + phases)).sum(1) / weights.sum()


def make_clip(kind: str, frames: int | None = None, fps: float | None = None,
              amplitude: float | None = None, expr_dims: int | None = None,
              seed: int = 0) -> MotionClip:
    """A procedural clip of `kind` (one of KINDS).

    frames: length (default: DEFAULT_SECONDS[kind] * fps, at least 2); fps: frame rate;
    amplitude: peak angle in degrees of the main motion (default DEFAULT_AMPLITUDE[kind],
    0..180); expr_dims: expression coefficients per frame (only `talk` sets any);
    seed: varies the random-looking parts of `talk` and `idle`.
    """
    fps = _clip.DEFAULT_FPS if fps is None else fps
    expr_dims = DEFAULT_EXPR_DIMS if expr_dims is None else expr_dims
    if kind not in KINDS:
        raise InputError(f"unknown motion kind {kind!r}; choose one of {', '.join(KINDS)}")
    fps = check_fps(fps)
    if frames is None:
        frames = max(2, int(round(DEFAULT_SECONDS[kind] * fps)))
    if int(frames) != frames or frames < 2:
        raise InputError(f"frames must be an integer >= 2, got {frames}")
    frames = int(frames)
    amp = DEFAULT_AMPLITUDE[kind] if amplitude is None else float(amplitude)
    if not (np.isfinite(amp) and 0 <= amp <= 180):
        raise InputError(f"amplitude must be between 0 and 180 degrees, got {amplitude}")
    if int(expr_dims) != expr_dims or expr_dims < 0:
        raise InputError(f"expr_dims must be an integer >= 0, got {expr_dims}")

    clip = MotionClip.rest(frames, fps, int(expr_dims), name=kind)
    u = np.linspace(0.0, 1.0, frames)      # normalised time, 0 at the first frame, 1 at the last
    seconds = (frames - 1) / fps
    a = np.deg2rad(amp)
    rng = np.random.default_rng(seed)
    rot = np.zeros((frames, 3))

    if kind in _RATE_HZ:
        cycles = max(1, int(round(_RATE_HZ[kind] * seconds)))
        rot[:, _AXIS[kind]] = a * _peak_normalised(
            lambda x: _envelope(x) * np.sin(2 * np.pi * cycles * x), u)
        return clip.replace(rotation=rot)

    if kind == "turn":  # look to one side, hold, to the other, hold, back
        keys = [(0.0, 0), (0.05, 0), (0.25, 1), (0.4, 1), (0.65, -1), (0.8, -1), (0.95, 0), (1.0, 0)]
        rot[:, 1] = a * _keyframes(u, keys, _smoothstep)
        return clip.replace(rotation=rot)

    if kind == "whip":
        # at 3 s: 0.3 s to +A, hold, 0.4 s to -A, hold, 0.3 s back, then a quick pitch snap
        yaw_keys = [(0.0, 0), (0.1, 0), (0.2, 1), (0.37, 1), (0.5, -1), (0.63, -1), (0.73, 0), (1.0, 0)]
        pitch_keys = [(0.0, 0), (0.78, 0), (0.85, 0.5), (0.88, 0.5), (0.95, 0), (1.0, 0)]
        rot[:, 1] = a * _keyframes(u, yaw_keys, _hard_stop)
        rot[:, 0] = a * _keyframes(u, pitch_keys, _hard_stop)
        return clip.replace(rotation=rot)

    if kind == "talk":
        jaw = np.zeros((frames, 3))
        jaw[:, 0] = a * _peak_normalised(lambda x: _envelope(x, 0.1) * _syllables(x, seconds, seed), u)
        env = _envelope(u, 0.1)
        expr = np.zeros((frames, clip.expr_dims))
        for j in range(min(5, clip.expr_dims)):  # a little mouth and cheek play on the main modes
            expr[:, j] = 0.6 / (j + 1) * env * _smooth_noise(u, rng, 3, max(1.0, 1.5 * seconds))
        rot[:, 0] = np.deg2rad(amp / 6) * env * _smooth_noise(u, rng, 3, max(1.0, 0.4 * seconds))
        rot[:, 1] = np.deg2rad(amp / 4) * env * _smooth_noise(u, rng, 3, max(1.0, 0.3 * seconds))
        return clip.replace(rotation=rot, jaw=jaw, expr=expr)

    # idle: slow sway of the head and body, the eyes drifting a little
    env = _envelope(u, 0.15)
    slow = max(1.0, 0.3 * seconds)
    for axis, share in ((1, 1.0), (0, 0.6), (2, 0.5)):
        wiggle = _smooth_noise_fn(rng, slow)
        rot[:, axis] = a * share * _peak_normalised(lambda x: _envelope(x, 0.15) * wiggle(x), u)
    trans = np.zeros((frames, 3))
    trans[:, 0] = 0.001 * amp * env * _smooth_noise(u, rng, 2, slow)  # ~1 mm per degree of sway
    trans[:, 2] = 0.0005 * amp * env * _smooth_noise(u, rng, 2, slow)
    eyes = np.zeros((frames, 6))
    gaze = np.deg2rad(2 * amp) * env * _smooth_noise(u, rng, 2, max(1.0, 0.5 * seconds))
    eyes[:, 1] = eyes[:, 4] = gaze  # both eyes turn together
    return clip.replace(rotation=rot, translation=trans, eyes=eyes)


def _smooth_noise_fn(rng: np.random.Generator, max_cycles: float):
    """A fixed smooth wiggle as a function of u (its random waves drawn now)."""
    state = rng.integers(2**32)
    return lambda x: _smooth_noise(x, np.random.default_rng(state), 3, max_cycles)


def _syllables(u: np.ndarray, seconds: float, seed: int) -> np.ndarray:
    """Mouth openness in [0, 1]: raised-cosine bumps at ~4.5 syllables/s with short pauses."""
    rng = np.random.default_rng(seed + 7919)
    t = u * seconds
    centres, heights, now = [], [], 0.1
    while now < seconds:
        centres.append(now)
        heights.append(rng.uniform(0.4, 1.0))
        now += rng.uniform(0.17, 0.28) + (rng.uniform(0.25, 0.5) if rng.uniform() < 0.12 else 0.0)
    c = np.array(centres)[None]
    h = np.array(heights)[None]
    x = np.clip((t[:, None] - c) / 0.1, -1.0, 1.0)  # each bump spans 0.2 s
    return np.minimum((h * 0.5 * (1 + np.cos(np.pi * x))).sum(1), 1.0)
