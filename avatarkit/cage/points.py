"""The points of each Gaussian that a cage must hold and that mean value coordinates carry.

For a Gaussian with centre mu, rotation R (columns = its local axes) and scales s, the endpoint
of axis i is mu +- axis_sigma * s_i * R e_i. The principal axis is the longest one (argmax s).

Row layouts (blocks of N rows, so each block is a contiguous slice):
  principal_axis: [+ends of the principal axis, -ends]                       -> (2N, 3)
  seven_point:    [centres, +x, -x, +y, -y, +z, -z] in the Gaussian's frame  -> (7N, 3)
"""
from __future__ import annotations

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rotations import quat_to_matrix

#: endpoints sit this many standard deviations along each axis (1 sigma: the ellipsoid the
#: scales describe; the cage is built around the same points, so any value stays consistent)
AXIS_SIGMA = 1.0
METHODS = ("principal_axis", "seven_point")


def principal_axis_index(scales: np.ndarray) -> np.ndarray:
    """scales (N, 3) -> index (N,) int32 of the longest axis (first one on ties)."""
    return np.argmax(scales, axis=1).astype(np.int32)


def axis_vectors(gaussians: GaussianSet, axis_sigma: float | None = None) -> np.ndarray:
    """Half-axis vectors (N, 3, 3) float64: [:, :, i] = axis_sigma * s_i * R e_i."""
    axis_sigma = AXIS_SIGMA if axis_sigma is None else axis_sigma
    r = quat_to_matrix(gaussians.quats.astype(np.float64))
    return r * (axis_sigma * gaussians.scales.astype(np.float64))[:, None, :]


def deformation_points(gaussians: GaussianSet, method: str = "principal_axis",
                       axis_sigma: float | None = None) -> np.ndarray:
    """The points (2N or 7N, 3) float64 whose weights a `CageDeformer` needs (layout above)."""
    axis_sigma = AXIS_SIGMA if axis_sigma is None else axis_sigma
    if method not in METHODS:
        raise InputError(f"unknown deformation method {method!r}; choose one of {', '.join(METHODS)}")
    if not (np.isfinite(axis_sigma) and axis_sigma > 0):
        raise InputError(f"axis_sigma must be > 0, got {axis_sigma}")
    mu = gaussians.means.astype(np.float64)
    axes = axis_vectors(gaussians, axis_sigma)
    if method == "principal_axis":
        k = principal_axis_index(gaussians.scales)
        a = axes[np.arange(len(mu)), :, k]
        return np.concatenate([mu + a, mu - a])
    blocks = [mu]
    for i in range(3):
        blocks += [mu + axes[:, :, i], mu - axes[:, :, i]]
    return np.concatenate(blocks)


def cage_points(gaussians: GaussianSet, axis_sigma: float | None = None) -> np.ndarray:
    """Every point a cage must hold: centres and all six axis endpoints, (7N, 3) float64.

    A superset of both deformation layouts, so one cage serves either method."""
    axis_sigma = AXIS_SIGMA if axis_sigma is None else axis_sigma
    return deformation_points(gaussians, "seven_point", axis_sigma)
