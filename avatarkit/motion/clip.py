"""`MotionClip`: a sequence of FLAME parameters at a frame rate.

Channels (float32, frame axis first), named as FLAME's joints (DESIGN.md):
rotation (T, 3) global head rotation, axis-angle about the root joint; translation (T, 3) metres;
neck (T, 3), jaw (T, 3) axis-angle; eyes (T, 6) left then right eye axis-angle; expr (T, E)
expression coefficients; shape (S,) static identity coefficients (S may be 0: "keep the
avatar's own shape").

Procedural clips, like FLAME trackers (VHAP, GaussianAvatars), put the head pose in `rotation`
and keep `neck` near zero: the whole model, neck and shoulders, turns with the head. `avatarkit
track` (default `--head-on neck`) holds `rotation` at one pose and turns the head through `neck`,
so the neck's base and what the build saw around it stay with the body (`track.neck`); the
head's own rotation is then `track.neck.head_rotation(rotation, neck)`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.limits import MAX_FPS, MIN_FPS

DEFAULT_FPS = 25.0  # VHAP's default when a file does not say
#: per-frame channels and their widths; expr's width is the clip's E
CHANNELS: dict[str, int | None] = {"rotation": 3, "translation": 3, "neck": 3, "jaw": 3, "eyes": 6,
                                   "expr": None}
#: channels that hold axis-angle rotations (eyes: two of them)
ROTATION_CHANNELS = ("rotation", "neck", "jaw", "eyes")


class ExprDimsWarning(UserWarning):
    """A clip's expression vector was truncated or zero-padded to fit a model."""


def check_channel(label: str, value, width: int | None, n_frames: int | None = None) -> np.ndarray:
    """Validate one per-frame channel -> float32 (T, width). `label` names it in messages."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{label!r} is not a numeric array") from None
    want = f"(T, {width})" if width is not None else "(T, E)"
    if arr.ndim != 2 or (width is not None and arr.shape[1] != width):
        raise InputError(f"{label!r} must have shape {want}, got {arr.shape}")
    if n_frames is not None and len(arr) != n_frames:
        raise InputError(f"{label!r} has {len(arr)} frames but the clip has {n_frames}")
    bad = ~np.isfinite(arr)
    if bad.any():
        frame = int(np.argwhere(bad)[0][0])
        raise InputError(f"{label!r} has a non-finite value at frame {frame}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def check_fps(fps) -> float:
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise InputError(f"fps must be a number, got {fps!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    if not MIN_FPS <= value <= MAX_FPS:
        raise InputError(f"fps must be between {MIN_FPS:g} and {MAX_FPS:g}, got {value:g}")
    return value


@dataclass(eq=False)
class MotionClip:
    """FLAME parameters over T frames at `fps`. Validated and made float32 on construction."""

    fps: float
    rotation: np.ndarray     # (T, 3) axis-angle, global (root joint)
    translation: np.ndarray  # (T, 3) metres
    neck: np.ndarray         # (T, 3) axis-angle
    jaw: np.ndarray          # (T, 3) axis-angle
    eyes: np.ndarray         # (T, 6) axis-angle, left eye then right eye
    expr: np.ndarray         # (T, E)
    shape: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))  # (S,)
    name: str = ""

    def __post_init__(self):
        self.fps = check_fps(self.fps)
        self.rotation = check_channel("rotation", self.rotation, 3)
        n = len(self.rotation)
        if n == 0:
            raise InputError("a motion clip needs at least one frame")
        for key, width in CHANNELS.items():
            if key != "rotation":
                setattr(self, key, check_channel(key, getattr(self, key), width, n))
        shape = np.asarray(self.shape, dtype=np.float64)
        if shape.ndim != 1:
            raise InputError(f"'shape' must have shape (S,), got {shape.shape}")
        if not np.isfinite(shape).all():
            raise InputError("'shape' has a non-finite value")
        self.shape = shape.astype(np.float32)
        self.name = str(self.name)

    # --- construction -------------------------------------------------------------------
    @classmethod
    def rest(cls, n_frames: int, fps: float | None = None, expr_dims: int = 0, shape_dims: int = 0,
             name: str = "rest") -> "MotionClip":
        """Every parameter zero (the template pose) for `n_frames` frames."""
        fps = DEFAULT_FPS if fps is None else fps
        z = lambda w: np.zeros((n_frames, w), np.float32)  # noqa: E731
        return cls(fps, z(3), z(3), z(3), z(3), z(6), z(expr_dims), np.zeros(shape_dims, np.float32), name)

    def replace(self, **changes) -> "MotionClip":
        """A new validated clip with some fields replaced."""
        fields = {k: getattr(self, k) for k in ("fps", *CHANNELS, "shape", "name")}
        fields.update(changes)
        return MotionClip(**fields)

    # --- properties ---------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return len(self.rotation)

    def __len__(self) -> int:
        return self.n_frames

    @property
    def duration(self) -> float:
        """Playback length in seconds, n_frames / fps (each frame lasts 1/fps)."""
        return self.n_frames / self.fps

    @property
    def times(self) -> np.ndarray:
        """(T,) float64 time of each frame in seconds; frame i is at i / fps."""
        return np.arange(self.n_frames) / self.fps

    @property
    def expr_dims(self) -> int:
        return self.expr.shape[1]

    @property
    def pose(self) -> np.ndarray:
        """(T, 15) FLAME pose vector: rotation, neck, jaw, eyes (joint order 0..4)."""
        return np.concatenate([self.rotation, self.neck, self.jaw, self.eyes], axis=1)

    # --- derived clips ------------------------------------------------------------------
    def slice(self, start: int, stop: int | None = None) -> "MotionClip":
        """Frames start..stop-1 (Python slice rules, negatives count from the end)."""
        idx = range(self.n_frames)[slice(start, stop)]
        if len(idx) == 0:
            raise InputError(f"slice [{start}:{stop}] of a {self.n_frames}-frame clip is empty")
        s = slice(idx.start, idx.stop)
        return self.replace(**{k: getattr(self, k)[s] for k in CHANNELS})

    def resample(self, fps: float) -> "MotionClip":
        """The same motion sampled at another frame rate.

        Samples lie at k / fps for every k with k / fps <= (T - 1) / old_fps, so the first and
        last poses keep their times. Axis-angle channels are interpolated by quaternion slerp
        (shortest arc), translation and expressions linearly.
        """
        fps = check_fps(fps)
        last = (self.n_frames - 1) / self.fps
        n_new = int(np.floor(last * fps + 1e-9)) + 1
        u = np.arange(n_new) * (self.fps / fps)  # positions in old frame units
        if self.n_frames == 1:
            return self.replace(fps=fps)
        i0 = np.minimum(np.floor(u).astype(np.int64), self.n_frames - 2)
        w = (u - i0)[:, None]
        lerp = lambda a: (1 - w) * a[i0] + w * a[i0 + 1]  # noqa: E731
        out = {"translation": lerp(self.translation), "expr": lerp(self.expr)}
        for key in ROTATION_CHANNELS:
            a = getattr(self, key)
            out[key] = np.concatenate([_slerp_rotvec(a[:, j:j + 3], i0, w[:, 0])
                                       for j in range(0, a.shape[1], 3)], axis=1)
        return self.replace(fps=fps, **out)

    def with_expr_dims(self, dims: int) -> "MotionClip":
        """Expressions truncated or zero-padded to `dims` coefficients (with an ExprDimsWarning)."""
        dims = int(dims)
        if dims < 0:
            raise InputError(f"expression dimensions must be >= 0, got {dims}")
        e = self.expr_dims
        if dims == e:
            return self
        if dims < e:
            lost = float(np.abs(self.expr[:, dims:]).max())
            warnings.warn(f"motion clip {self.name or '(unnamed)'} has {e} expression coefficients, "
                          f"the model uses {dims}: dropped the last {e - dims} "
                          f"(largest magnitude dropped: {lost:.3g})", ExprDimsWarning, stacklevel=2)
            expr = self.expr[:, :dims]
        else:
            warnings.warn(f"motion clip {self.name or '(unnamed)'} has {e} expression coefficients, "
                          f"the model uses {dims}: padded with zeros", ExprDimsWarning, stacklevel=2)
            expr = np.concatenate([self.expr, np.zeros((self.n_frames, dims - e), np.float32)], axis=1)
        return self.replace(expr=expr)

    def __repr__(self) -> str:
        return (f"MotionClip(name={self.name!r}, frames={self.n_frames}, fps={self.fps:g}, "
                f"expr_dims={self.expr_dims}, shape_dims={len(self.shape)})")


def _slerp_rotvec(rv: np.ndarray, i0: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Slerp between axis-angle samples rv[i0] and rv[i0+1] at fractions w -> (M, 3)."""
    from scipy.spatial.transform import Rotation

    r0 = Rotation.from_rotvec(rv[i0].astype(np.float64))
    r1 = Rotation.from_rotvec(rv[i0 + 1].astype(np.float64))
    # r0 * exp(w * log(r0^-1 r1)): the relative rotvec has angle <= pi, i.e. the shorter arc
    delta = (r0.inv() * r1).as_rotvec()
    return (r0 * Rotation.from_rotvec(delta * w[:, None])).as_rotvec()
