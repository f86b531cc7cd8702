"""`Camera`: a pinhole camera in the OpenCV convention that 3DGS tools use.

Camera axes: x right, y down, z forward (the camera looks along +z). `world_to_camera` (4, 4)
maps world points (metres, +Y up, the face looking toward +Z) into these axes.

Pixel convention (as gsplat and COLMAP): pixel (i, j) (column i, row j) covers
[i, i+1) x [j, j+1) and its centre is (i + 0.5, j + 0.5); a camera point (x, y, z) projects to
u = fx x / z + cx, v = fy y / z + cy. The principal point of a centred camera is (W/2, H/2).
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path, json_loads

#: how far R R^T may stray from I before the matrix is not a rotation (float32 JSON round trips)
ROTATION_TOLERANCE = 1e-4

_OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def _finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"camera {name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise InputError(f"camera {name} must be finite, got {v}")
    return v


def _size(name: str, value) -> int:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise InputError(f"camera {name} must be a positive integer, got {value!r}") from None
    if not math.isfinite(f) or f != int(f) or f <= 0:
        raise InputError(f"camera {name} must be a positive integer, got {value!r}")
    return int(f)


def _vec3(name: str, value) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 numbers, got {value!r}") from None
    if v.shape != (3,) or not np.isfinite(v).all():
        raise InputError(f"{name} must be 3 finite numbers, got {value!r}")
    return v


def focal_from_fov(fov_deg: float, size: int) -> float:
    """Focal length in pixels giving a field of view of `fov_deg` across `size` pixels."""
    fov = _finite("fov_deg", fov_deg)
    if not 0 < fov < 180:
        raise InputError(f"field of view must lie in (0, 180) degrees, got {fov}")
    return 0.5 * size / math.tan(math.radians(fov) / 2)


@dataclass(frozen=True, eq=False)
class Camera:
    """Pinhole intrinsics (pixels) + world-to-camera extrinsics (OpenCV axes), validated."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    world_to_camera: np.ndarray = field(default_factory=lambda: np.eye(4))  # (4, 4) float64

    def __post_init__(self):
        set_ = object.__setattr__  # frozen: normalise the fields once, here
        set_(self, "width", _size("width", self.width))
        set_(self, "height", _size("height", self.height))
        for name in ("fx", "fy", "cx", "cy"):
            set_(self, name, _finite(name, getattr(self, name)))
        if self.fx <= 0 or self.fy <= 0:
            raise InputError(f"camera focal lengths must be > 0, got fx={self.fx}, fy={self.fy}")
        try:
            m = np.array(self.world_to_camera, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("camera world_to_camera must be a 4x4 matrix of numbers") from None
        if m.shape != (4, 4):
            raise InputError(f"camera world_to_camera must be 4x4, got shape {m.shape}")
        if not np.isfinite(m).all():
            raise InputError("camera world_to_camera has a non-finite value")
        if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
            raise InputError(f"camera world_to_camera last row must be 0 0 0 1, got {m[3].tolist()}")
        r = m[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=ROTATION_TOLERANCE) or np.linalg.det(r) <= 0:
            raise InputError("camera world_to_camera rotation part is not a proper rotation "
                             "(orthonormal, determinant +1)")
        m[3] = (0, 0, 0, 1)
        m.setflags(write=False)
        set_(self, "world_to_camera", m)

    # --- constructors -----------------------------------------------------------------------
    @classmethod
    def from_fov(cls, fov_deg: float, width: int, height: int,
                 world_to_camera: np.ndarray | None = None) -> "Camera":
        """Square pixels, principal point at the image centre; `fov_deg` is the VERTICAL field
        of view (across `height`), as in OpenGL/USD-style cameras."""
        width, height = _size("width", width), _size("height", height)
        f = focal_from_fov(fov_deg, height)
        return cls(f, f, width / 2, height / 2, width, height,
                   np.eye(4) if world_to_camera is None else world_to_camera)

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 1.0, 0.0), fov_deg: float = 30.0,
                width: int = 512, height: int = 512) -> "Camera":
        """A camera at `eye` looking at `target` (which lands on the principal point), with
        world `up` pointing up in the image (toward -y)."""
        eye, target, up = _vec3("eye", eye), _vec3("target", target), _vec3("up", up)
        fwd = target - eye
        if np.linalg.norm(fwd) < 1e-12:
            raise InputError("look_at: eye and target are the same point")
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-9 * max(np.linalg.norm(up), 1e-300):
            raise InputError("look_at: up is parallel to the viewing direction (or zero)")
        right /= np.linalg.norm(right)
        return cls.from_fov(fov_deg, width, height, _extrinsics(eye, right, fwd))

    @classmethod
    def orbit(cls, target=(0.0, 0.0, 0.0), azimuth_deg: float = 0.0, elevation_deg: float = 0.0,
              distance: float = 1.0, fov_deg: float = 30.0, width: int = 512,
              height: int = 512) -> "Camera":
        """A camera on a sphere around `target` in our +Y-up world, looking at it.

        azimuth 0, elevation 0: in front of the face (on +Z), looking toward -Z. Positive
        azimuth turns the camera counter-clockwise seen from above (toward +X); positive
        elevation raises it. Well defined at the poles (elevation +-90).
        """
        target = _vec3("target", target)
        dist = _finite("distance", distance)
        if dist <= 0:
            raise InputError(f"orbit distance must be > 0, got {dist}")
        az = math.radians(_finite("azimuth", azimuth_deg))
        el = math.radians(_finite("elevation", elevation_deg))
        offset = np.array([math.sin(az) * math.cos(el), math.sin(el), math.cos(az) * math.cos(el)])
        # Right = the direction of increasing azimuth, which stays defined at the poles.
        right = np.array([math.cos(az), 0.0, -math.sin(az)])
        return cls.from_fov(fov_deg, width, height,
                            _extrinsics(target + dist * offset, right, -offset))

    # --- JSON -------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The bench `make_scene.py` camera format."""
        return dict(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, width=self.width,
                    height=self.height, world_to_camera=self.world_to_camera.tolist(),
                    convention="opencv")

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        """Inverse of `to_dict`. Also accepts convention "opengl" (x right, y up, z backward)."""
        if not isinstance(d, dict):
            raise FormatError(f"a camera must be a JSON object, got {type(d).__name__}")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height", "world_to_camera")
                   if k not in d]
        if missing:
            raise FormatError(f"camera is missing {', '.join(missing)}")
        convention = d.get("convention", "opencv")
        if convention not in ("opencv", "opengl"):
            raise FormatError(f"camera convention must be 'opencv' or 'opengl', got {convention!r}")
        try:
            m = np.array(d["world_to_camera"], dtype=np.float64)
        except (TypeError, ValueError):
            raise FormatError("camera world_to_camera must be a 4x4 array of numbers") from None
        if convention == "opengl" and m.shape == (4, 4):
            m = _OPENGL_TO_OPENCV @ m
        return cls(d["fx"], d["fy"], d["cx"], d["cy"], d["width"], d["height"], m)

    def to_json(self, path: str | os.PathLike) -> None:
        """Write the camera as JSON (atomically)."""
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def from_json(cls, path: str | os.PathLike) -> "Camera":
        """Read a camera JSON file; a bad file raises an InputError naming it."""
        try:
            with open(path, "rb") as f:
                d = json_loads(f.read().decode("utf-8"), path)
        except FileNotFoundError:
            raise InputError("camera file not found", path) from None
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(f"cannot read camera file: {e}", path) from None
        except json.JSONDecodeError as e:
            raise FormatError(f"not valid JSON: {e}", path) from None
        try:
            return cls.from_dict(d)
        except InputError as e:
            raise e.with_path(path) from None

    # --- geometry ---------------------------------------------------------------------------
    @property
    def rotation(self) -> np.ndarray:
        """World-to-camera rotation (3, 3)."""
        return self.world_to_camera[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """World-to-camera translation (3,)."""
        return self.world_to_camera[:3, 3]

    @property
    def camera_center(self) -> np.ndarray:
        """The camera's position in world coordinates (3,)."""
        return -self.rotation.T @ self.translation

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix (3, 3)."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def tan_half_fov(self) -> tuple[float, float]:
        """(tan of half the horizontal FOV, same vertical), as 3DGS computes them."""
        return 0.5 * self.width / self.fx, 0.5 * self.height / self.fy

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera coordinates (N, 3), float64."""
        p = np.asarray(points, dtype=np.float64)
        return p @ self.rotation.T + self.translation

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> (pixel coordinates (N, 2), depths z (N,)), float64.

        Points at or behind the camera (z <= 0) get NaN pixel coordinates.
        """
        pc = self.to_camera(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([self.fx * pc[:, 0] / z + self.cx, self.fy * pc[:, 1] / z + self.cy], 1)
        uv[z <= 0] = np.nan
        return uv, z

    def with_size(self, width: int, height: int) -> "Camera":
        """The same view at another resolution (intrinsics scaled)."""
        width, height = _size("width", width), _size("height", height)
        sx, sy = width / self.width, height / self.height
        return Camera(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, width, height,
                      self.world_to_camera)

    def __repr__(self) -> str:
        c = np.round(self.camera_center, 4).tolist()
        return (f"Camera({self.width}x{self.height}, fx={self.fx:.4g}, fy={self.fy:.4g}, "
                f"cx={self.cx:.4g}, cy={self.cy:.4g}, center={c})")


def _extrinsics(eye: np.ndarray, right: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """World-to-camera (4, 4) with camera axes x=right, z=forward, y=z cross x (image down)."""
    down = np.cross(forward, right)
    r = np.stack([right, down / np.linalg.norm(down), forward])
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = -r @ eye
    return m
