"""`GaussianSet`: the splats every layer passes around, in *activated* form.

Conventions (DESIGN.md): means (N,3) metres; quats (N,4) w,x,y,z unit; scales (N,3) linear > 0;
opacities (N,) in [0,1]; sh (N,K,3) coefficient-major, K in {1,4,9,16}. File formats convert
at their boundary (PLY stores log-scales, logit opacity, channel-major f_rest).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.sh import SH_COUNTS, dc_to_rgb, rgb_to_dc, rotate_sh
from avatarkit.rotations import matrix_to_quat, quat_multiply, quat_to_matrix

#: a quaternion whose norm is further than this from 1 is an input error, not rounding noise
QUAT_NORM_TOLERANCE = 1e-3
#: the fields a set is made of, in the constructor's order
_FIELDS = ("means", "quats", "scales", "opacities", "sh", "extras")


def _as_f32(name: str, a, shape_tail: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.ascontiguousarray(a, dtype=np.float32)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name} is not a numeric array: {e}") from None
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "(N" + "".join(f", {d}" for d in shape_tail) + ")"
        raise InputError(f"{name} must have shape {want}, got {arr.shape}")
    return arr


def _all_finite(a: np.ndarray) -> bool:
    """Every value finite? A NaN/inf anywhere makes the sum non-finite, so a finite sum proves
    it in one cheap reduction (validation runs on every derived set); an overflowing sum falls
    back to the exact elementwise test."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(a.sum()):
            return True
    return bool(np.isfinite(a).all())


def _checked_extras(extras: dict, n: int) -> dict[str, np.ndarray]:
    out = {}
    for key, value in dict(extras).items():
        arr = np.asarray(value)  # not ascontiguousarray: it would turn a scalar into (1,)
        if not isinstance(key, str) or not key.isidentifier():
            raise InputError(f"extra name {key!r} must be an identifier")
        if arr.ndim == 0 or len(arr) != n:
            raise InputError(f"extra {key!r} has shape {arr.shape}, first axis must be {n}")
        out[key] = np.ascontiguousarray(arr)
    return out


@dataclass(eq=False)
class GaussianSet:
    """N anisotropic 3D Gaussians with SH colour. Validated (and made float32) on construction.

    `extras` holds optional per-Gaussian arrays whose first axis is N (e.g. `binding` (N,) int:
    the face a Gaussian rides; `part` (N,) uint8). They survive subset/concat/PLY round trips.
    """

    means: np.ndarray      # (N, 3) float32
    quats: np.ndarray      # (N, 4) float32, w x y z, unit
    scales: np.ndarray     # (N, 3) float32, linear, > 0
    opacities: np.ndarray  # (N,) float32 in [0, 1]
    sh: np.ndarray         # (N, K, 3) float32, K in {1, 4, 9, 16}
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        self._validate(_FIELDS)

    def _validate(self, names) -> None:
        """Hold the fields `names` (all of them on construction; the replaced ones in `replace`,
        the others having passed already) to the rules, made float32; every field's row count
        and the extras are checked whatever the names."""
        if "means" in names:
            self.means = _as_f32("means", self.means, (3,))
        n = len(self.means)
        if "quats" in names:
            self.quats = _as_f32("quats", self.quats, (4,))
        if "scales" in names:
            self.scales = _as_f32("scales", self.scales, (3,))
        if "opacities" in names:
            self.opacities = _as_f32("opacities", self.opacities, ())
        if "sh" in names:
            sh = np.asarray(self.sh)
            if sh.ndim == 2 and sh.shape[1] == 3:  # (N, 3): DC only
                sh = sh[:, None, :]
            if sh.ndim != 3 or sh.shape[2] != 3 or sh.shape[1] not in SH_COUNTS:
                raise InputError(f"sh must have shape (N, K, 3) with K in {SH_COUNTS}, got {sh.shape}")
            self.sh = np.ascontiguousarray(sh, dtype=np.float32)
        for name in ("quats", "scales", "opacities", "sh"):
            if len(getattr(self, name)) != n:
                raise InputError(f"{name} has {len(getattr(self, name))} rows but means has {n}")
        for name in ("means", "quats", "scales", "opacities", "sh"):
            if name not in names:
                continue
            a = getattr(self, name)
            if not _all_finite(a):
                bad = int(np.flatnonzero(~np.isfinite(a.reshape(n, -1)).all(axis=1))[0])
                raise InputError(f"{name} has a non-finite value (Gaussian {bad})")
        if "scales" in names and n and not (self.scales > 0).all():
            bad = int(np.flatnonzero(~(self.scales > 0).all(axis=1))[0])
            raise InputError(f"scales must be > 0 (Gaussian {bad} has {self.scales[bad].tolist()})")
        if "opacities" in names and n and not ((self.opacities >= 0) & (self.opacities <= 1)).all():
            bad = int(np.flatnonzero((self.opacities < 0) | (self.opacities > 1))[0])
            raise InputError(f"opacities must lie in [0, 1] (Gaussian {bad} has {self.opacities[bad]})")
        if "quats" in names:
            norms = np.sqrt(np.einsum("ij,ij->i", self.quats, self.quats, dtype=np.float64))
            if n and not (np.abs(norms - 1) <= QUAT_NORM_TOLERANCE).all():
                bad = int(np.flatnonzero(np.abs(norms - 1) > QUAT_NORM_TOLERANCE)[0])
                raise InputError(f"quats must be unit length (Gaussian {bad} has norm {norms[bad]:.6g}); "
                                 "normalise them first")
            # Renormalise only rows not already unit to float32 precision, so constructing a set
            # from another set's quats (replace, subset, file round trips) keeps them bit-identical.
            fix = np.abs(norms - 1) > 4 * np.finfo(np.float32).eps
            if fix.any():
                self.quats = self.quats.copy()
                self.quats[fix] = self.quats[fix].astype(np.float64) / norms[fix, None]
        self.extras = _checked_extras(self.extras, n)

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_checked(cls, means: np.ndarray, quats: np.ndarray, scales: np.ndarray,
                     opacities: np.ndarray, sh: np.ndarray,
                     extras: dict[str, np.ndarray] | None = None) -> "GaussianSet":
        """A set from arrays a decoder has already held to every rule the constructor checks:
        C-contiguous float32 of the right shapes, finite, scales > 0, opacities in [0, 1], quats
        unit to float32 precision. Only the extras are checked. For readers whose single pass
        over a file did the checks (`ply`'s kernel): validating again would cost ~20 ms per
        million splats. Tests hold such readers to `GaussianSet(...)` giving the same bits."""
        gs = object.__new__(cls)
        gs.means, gs.quats, gs.scales, gs.opacities, gs.sh = means, quats, scales, opacities, sh
        gs.extras = _checked_extras(extras or {}, len(means))
        return gs

    @classmethod
    def empty(cls, sh_degree: int = 0) -> "GaussianSet":
        k = SH_COUNTS[sh_degree]
        return cls(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, k, 3)))

    @classmethod
    def from_colors(cls, means, quats, scales, opacities, rgb, sh_degree: int = 0, extras=None,
                    normalize_quats: bool = True) -> "GaussianSet":
        """Build from RGB colours (N,3) in [0,1]; higher SH bands start at zero."""
        rgb = np.asarray(rgb, dtype=np.float32)
        sh = np.zeros((len(rgb), SH_COUNTS[sh_degree], 3), np.float32)
        sh[:, 0] = rgb_to_dc(rgb)
        q = np.asarray(quats, dtype=np.float64)
        if normalize_quats:
            q = q / np.linalg.norm(q, axis=1, keepdims=True)
        return cls(means, q, scales, opacities, sh, dict(extras or {}))

    # --- properties ---------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return SH_COUNTS.index(self.sh.shape[1])

    @property
    def colors(self) -> np.ndarray:
        """DC colour (N, 3) in [0,1] (clamped), the view-independent part of the SH."""
        return np.clip(dc_to_rgb(self.sh[:, 0]), 0.0, 1.0)

    def with_colors(self, rgb: np.ndarray) -> "GaussianSet":
        """A copy whose DC term gives colour `rgb` (N, 3); higher bands are kept."""
        sh = self.sh.copy()
        sh[:, 0] = rgb_to_dc(np.asarray(rgb, np.float32))
        return self.replace(sh=sh)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min (3,), max (3,)) of the means; raises InputError for an empty set."""
        if len(self) == 0:
            raise InputError("an empty GaussianSet has no bounds")
        return self.means.min(axis=0), self.means.max(axis=0)

    def covariances(self) -> np.ndarray:
        """World covariances (N, 3, 3) = R S S^T R^T, float64."""
        r = quat_to_matrix(self.quats.astype(np.float64))
        rs = r * self.scales.astype(np.float64)[:, None, :]
        return rs @ np.swapaxes(rs, 1, 2)

    # --- derived sets --------------------------------------------------------------------
    def replace(self, **changes) -> "GaussianSet":
        """A new, validated set with some fields replaced (arrays are not copied). Only the
        replaced fields are checked (the others passed on this set's construction), and the
        row counts: the same set as `replace_reference`'s, which checks every field again (a
        refined tracking's frame or a colour round replaces one or two of five)."""
        unknown = set(changes) - set(_FIELDS)
        if unknown or type(self) is not GaussianSet:
            return self.replace_reference(**changes)
        gs = object.__new__(GaussianSet)
        gs.means, gs.quats, gs.scales, gs.opacities, gs.sh, gs.extras = (
            changes.get(k, getattr(self, k)) for k in _FIELDS)
        gs._validate(frozenset(changes))
        return gs

    def replace_reference(self, **changes) -> "GaussianSet":
        """`replace` through the constructor: every field checked (the obvious twin)."""
        fields = dict(means=self.means, quats=self.quats, scales=self.scales,
                      opacities=self.opacities, sh=self.sh, extras=self.extras)
        fields.update(changes)
        return GaussianSet(**fields)

    def subset(self, index) -> "GaussianSet":
        """Gaussians selected by a boolean mask (N,) or integer indices (M,), extras included."""
        idx = np.asarray(index)
        if idx.size == 0 and idx.dtype != bool:  # np.asarray([]) is float64
            idx = idx.astype(np.intp)
        if idx.dtype == bool and idx.shape != (len(self),):
            raise InputError(f"mask has shape {idx.shape}, expected ({len(self)},)")
        return GaussianSet(self.means[idx], self.quats[idx], self.scales[idx], self.opacities[idx],
                           self.sh[idx], {k: v[idx] for k, v in self.extras.items()})

    def with_sh_degree(self, degree: int) -> "GaussianSet":
        """Drop higher bands or pad with zeros to reach `degree` (0..3)."""
        if degree not in range(4):
            raise InputError(f"SH degree must be 0..3, got {degree}")
        k = SH_COUNTS[degree]
        sh = np.zeros((len(self), k, 3), np.float32)
        m = min(k, self.sh.shape[1])
        sh[:, :m] = self.sh[:, :m]
        return self.replace(sh=sh)

    @staticmethod
    def concat(sets: "list[GaussianSet]") -> "GaussianSet":
        """Join sets. SH is padded to the highest degree present; extras are kept when every set
        has them with matching trailing shape (others are dropped: there is no fill value)."""
        sets = list(sets)
        if not sets:
            raise InputError("concat needs at least one GaussianSet")
        degree = max(s.sh_degree for s in sets)
        sets = [s if s.sh_degree == degree else s.with_sh_degree(degree) for s in sets]
        keys = set(sets[0].extras)
        for s in sets[1:]:
            keys &= {k for k, v in s.extras.items() if v.shape[1:] == sets[0].extras.get(k, v).shape[1:]}
        return GaussianSet(
            np.concatenate([s.means for s in sets]), np.concatenate([s.quats for s in sets]),
            np.concatenate([s.scales for s in sets]), np.concatenate([s.opacities for s in sets]),
            np.concatenate([s.sh for s in sets]),
            {k: np.concatenate([s.extras[k] for s in sets]) for k in sorted(keys)})

    def transform(self, rotation=None, translation=None, scale: float = 1.0,
                  rotate_sh_coeffs: bool = True) -> "GaussianSet":
        """Similarity transform x -> scale * R x + t.

        rotation: (3,3) proper rotation or (4,) wxyz quaternion; translation: (3,); scale > 0.
        Orientations are left-multiplied by R, scales multiplied by `scale`, and (unless
        `rotate_sh_coeffs` is False) the view-dependent SH bands are rotated with the splats so
        they keep their appearance.
        """
        r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        if r.shape == (4,):
            r = quat_to_matrix(r)
        if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-5) or np.linalg.det(r) < 0:
            raise InputError("rotation must be a proper 3x3 rotation matrix or a unit quaternion")
        t = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise InputError("translation must be 3 finite numbers")
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"scale must be a positive number, got {scale}")
        means = scale * (self.means.astype(np.float64) @ r.T) + t
        quats = quat_multiply(matrix_to_quat(r)[None], self.quats.astype(np.float64))
        sh = rotate_sh(self.sh, r) if rotate_sh_coeffs and self.sh_degree > 0 else self.sh
        return self.replace(means=means, quats=quats / np.linalg.norm(quats, axis=1, keepdims=True),
                            scales=self.scales * np.float32(scale), sh=sh)

    def __repr__(self) -> str:
        extras = ", ".join(f"{k}{tuple(v.shape[1:])}:{v.dtype}" for k, v in self.extras.items())
        return f"GaussianSet(n={len(self)}, sh_degree={self.sh_degree}, extras=[{extras}])"
