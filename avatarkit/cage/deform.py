"""Deform Gaussians through a cage with mean value coordinates (paper sec. 3.3).

`CageDeformer` is built once from (rest Gaussians, rest cage, method): it computes the MVC weights
W (P, C) of the points each Gaussian needs (`deformation_points`) and what the rebuild needs at
rest. Per frame it does one float32 matrix product X = W @ V' with the deformed cage vertices
V' (C, 3) and rebuilds the Gaussians from X:

principal_axis (the paper's method, for slender hair Gaussians): only the two ends x+-, x- of the
    longest axis are carried. centre = their midpoint; rotation = the minimal rotation taking the
    rest axis direction to the deformed one, applied to the rest rotation; the longest scale is
    multiplied by |x+ - x-| / |x+ - x-|_rest, the other two are kept.
seven_point (GSDeformer-style, for comparison): the centre and the six axis ends. A least-squares
    affine map A takes the rest half-axes to the deformed ones (with symmetric ends it is
    B_deformed B_rest^-1); the covariance A Sigma A^T is split back into rotation and scales by an
    eigendecomposition, eigenvectors matched to the deformed rest axes so that axis order and
    sign stay continuous; centre = deformed centre. Where two scales are nearly equal, that split
    is ill-conditioned: float32 rounding of the product can turn the pair's eigenvectors in their
    plane (quaternions differing by ~1e-3 between a batched and a single product), while the
    covariance, which is what renders, stays within rounding.

`CageDeformer.deferred` makes a deformer that computes its weights on first use (what a loaded
avatar's rig holds: the weights are not stored in the avatar folder).

Rest references (W @ V_rest) are taken from the weights themselves, so an undeformed cage gives
back the rest Gaussians exactly up to float32 rounding, and no frame jitters at rest: the
residual mu - (W @ V_rest) of the centre (~1e-7 of the cage size) is stored and added back.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from avatarkit.cage import points as _points
from avatarkit.cage.mesh import Cage
from avatarkit.cage.mvc import mvc_weights
from avatarkit.cage.points import METHODS, axis_vectors, deformation_points, principal_axis_index
from avatarkit.errors import FormatError, InputError
from avatarkit.fileio import atomic_path, read_npz
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.rotations import matrix_to_quat, quat_multiply, quat_to_matrix, shortest_arc

WEIGHTS_FORMAT = "avatarkit.cage_weights/1"


def fingerprint(gaussians: GaussianSet) -> str:
    """A short hash of the geometry (means, quats, scales) that weights were computed for."""
    h = hashlib.sha1()
    for a in (gaussians.means, gaussians.quats, gaussians.scales):
        h.update(np.ascontiguousarray(a, np.float32).tobytes())
    return h.hexdigest()[:16]


@dataclass(eq=False, repr=False)
class CageDeformer:
    """Carries a cage's motion to Gaussians. Build with `CageDeformer.build(...)`.

    rest: the Gaussians at rest (N); cage: the rest cage (C vertices); method: "principal_axis"
    or "seven_point"; weights_t: MVC weights stored transposed, (C, P) float32 C-contiguous, with
    P = 2N or 7N rows in the `deformation_points` layout (the per-frame product is fastest in
    this layout: X^T = V'^T @ W^T).
    """

    rest: GaussianSet
    cage: Cage
    weights_t: np.ndarray
    method: str = "principal_axis"
    axis_sigma: float = field(default_factory=lambda: _points.AXIS_SIGMA)  # read when made
    _pre: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.method not in METHODS:
            raise InputError(f"unknown deformation method {self.method!r}; choose one of {', '.join(METHODS)}")
        n = len(self.rest)
        rows = (2 if self.method == "principal_axis" else 7) * n
        wt = np.ascontiguousarray(self.weights_t, dtype=np.float32)
        if wt.shape != (self.cage.n_vertices, rows):
            raise InputError(f"weights have shape {wt.shape[::-1]} (points x cage vertices); "
                             f"{self.method} with {n} Gaussians and a {self.cage.n_vertices}-vertex "
                             f"cage needs ({rows}, {self.cage.n_vertices})")
        self.weights_t = wt
        rest_x = (self.cage.vertices.astype(np.float32).T @ wt).T.astype(np.float64)  # (P, 3)
        mu = self.rest.means.astype(np.float64)
        if self.method == "principal_axis":
            plus, minus = rest_x[:n], rest_x[n:]
            axis = plus - minus
            length = np.linalg.norm(axis, axis=1)
            length = np.where(length > 0, length, 1e-30)
            k = principal_axis_index(self.rest.scales)
            rot = quat_to_matrix(self.rest.quats.astype(np.float64))
            perp = rot[np.arange(n), :, (k + 1) % 3]  # any unit vector normal to the axis
            # C order for the rebuild kernel (rest_x is a transpose, so axis is Fortran order and
            # Taichi would copy it on every frame's launch: ~1 ms a frame for 50k Gaussians)
            self._pre = dict(
                axis=np.ascontiguousarray(axis / length[:, None], np.float32), length=length.astype(np.float32),
                perp=np.ascontiguousarray(perp, np.float32), index=k,
                offset=(mu - 0.5 * (plus + minus)).astype(np.float32))
        else:
            half = np.stack([(rest_x[n * (1 + 2 * i):n * (2 + 2 * i)] - rest_x[n * (2 + 2 * i):n * (3 + 2 * i)]) / 2
                             for i in range(3)], axis=2)                       # (N, 3, 3) columns
            det = np.linalg.det(half)
            if (np.abs(det) < 1e-300).any():
                bad = int(np.flatnonzero(np.abs(det) < 1e-300)[0])
                raise InputError(f"Gaussian {bad} is too flat for the seven-point method "
                                 "(its axis ends coincide in float32); use principal_axis")
            self._pre = dict(half_inv=np.linalg.inv(half), cov=self.rest.covariances(),
                             axes=axis_vectors(self.rest, 1.0), offset=mu - rest_x[:n])

    # --- construction -----------------------------------------------------------------------
    @classmethod
    def build(cls, gaussians: GaussianSet, cage: Cage, method: str = "principal_axis",
              axis_sigma: float | None = None,
              progress: Callable[[int, int], None] | None = None) -> "CageDeformer":
        """Compute the weights of the points `method` needs (2 or 7 per Gaussian) and precompute."""
        axis_sigma = _points.AXIS_SIGMA if axis_sigma is None else axis_sigma
        points = deformation_points(gaussians, method, axis_sigma)
        wt = mvc_weights(points, cage.vertices, cage.faces, transposed=True, progress=progress)
        return cls(gaussians, cage, wt, method, float(axis_sigma))

    @classmethod
    def deferred(cls, gaussians: GaussianSet, cage: Cage, method: str = "principal_axis",
                 axis_sigma: float | None = None) -> "CageDeformer":
        """A deformer whose weights are computed (as `build` does) the first time they are
        needed: by a deformation, or by reading `weights_t`/`weights`. Loading an avatar uses
        this, so tools that never move its hair (rendering at rest, hair transfer, inspection)
        do not pay for the MVC weights (~2 s per 50k hair Gaussians)."""
        axis_sigma = _points.AXIS_SIGMA if axis_sigma is None else axis_sigma
        if method not in METHODS:
            raise InputError(f"unknown deformation method {method!r}; choose one of {', '.join(METHODS)}")
        if not (np.isfinite(axis_sigma) and axis_sigma > 0):
            raise InputError(f"axis_sigma must be > 0, got {axis_sigma}")
        obj = cls.__new__(cls)
        obj.rest, obj.cage, obj.method, obj.axis_sigma = gaussians, cage, method, float(axis_sigma)
        obj.__dict__["_deferred"] = True
        return obj

    def __repr__(self) -> str:  # not the dataclass one: it would print (and compute) the weights
        state = "ready" if self.weights_ready else "deferred"
        return (f"CageDeformer(n={len(self.rest)}, cage={self.cage.n_vertices} vertices, "
                f"method={self.method!r}, axis_sigma={self.axis_sigma:g}, weights {state})")

    @property
    def weights_ready(self) -> bool:
        """False while a `deferred` deformer has not computed its weights yet."""
        return "weights_t" in self.__dict__

    def ensure_weights(self, progress: Callable[[int, int], None] | None = None) -> "CageDeformer":
        """Compute a deferred deformer's weights now (progress(done, total) over the points),
        e.g. under a progress bar before a bake; nothing to do when they are ready."""
        if self.__dict__.get("_deferred"):
            points = deformation_points(self.rest, self.method, self.axis_sigma)
            # assigned only when complete: an interrupted computation leaves it deferred
            self.weights_t = mvc_weights(points, self.cage.vertices, self.cage.faces, transposed=True,
                                         progress=progress)
            self.__post_init__()
            del self.__dict__["_deferred"]
        return self

    def __getattr__(self, name: str):
        # only reached for attributes not set yet: the weights of a deferred deformer
        if name in ("weights_t", "_pre") and self.__dict__.get("_deferred"):
            return self.ensure_weights().__dict__[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def weights(self) -> np.ndarray:
        """W (P, C) float32 (a transposed view of `weights_t`)."""
        return self.weights_t.T

    # --- per frame --------------------------------------------------------------------------
    def _check_vertices(self, cage_vertices) -> np.ndarray:
        v = np.asarray(cage_vertices, dtype=np.float32)
        if v.shape[-2:] != (self.cage.n_vertices, 3):
            raise InputError(f"cage vertices must have shape (..., {self.cage.n_vertices}, 3), got {v.shape}")
        if not np.isfinite(v).all():
            raise InputError("deformed cage vertices have a non-finite value")
        return v

    def deformed_points(self, cage_vertices: np.ndarray) -> np.ndarray:
        """X^T (3, P) float32: the carried points for cage vertices (C, 3). One product."""
        v = self._check_vertices(cage_vertices)
        return np.matmul(np.ascontiguousarray(v.T), self.weights_t)

    def deform_arrays(self, cage_vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(means (N, 3), quats (N, 4) wxyz, scales (N, 3)) float32 for cage vertices (C, 3)."""
        return self._rebuild(self.deformed_points(cage_vertices))

    def deform(self, cage_vertices: np.ndarray) -> GaussianSet:
        """The rest Gaussians (colours, opacities, extras kept) moved by the deformed cage."""
        means, quats, scales = self.deform_arrays(cage_vertices)
        return self.rest.replace(means=means, quats=quats, scales=scales)

    def deform_batch(self, frames: np.ndarray,
                     chunk: int = 16) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """frames (T, C, 3) -> yields deform_arrays per frame (to float32 rounding: BLAS may sum the
        batched product in another order). W is read once per `chunk` frames (one (3 chunk, C) x
        (C, P) product), which is where the per-frame cost goes down."""
        v = self._check_vertices(frames)
        if v.ndim != 3:
            raise InputError(f"frames must have shape (T, C, 3), got {v.shape}")
        for s in range(0, len(v), max(1, int(chunk))):
            block = v[s:s + max(1, int(chunk))]
            t = len(block)
            stacked = np.ascontiguousarray(block.transpose(0, 2, 1).reshape(3 * t, -1))  # (3t, C)
            xt = np.matmul(stacked, self.weights_t)                                       # (3t, P)
            for i in range(t):
                yield self._rebuild(xt[3 * i:3 * i + 3])

    def _rebuild(self, xt: np.ndarray):
        if self.method == "principal_axis":
            return self._principal_fast(xt)
        return seven_point_rebuild(xt, self.rest, self._pre)

    def _principal_fast(self, xt: np.ndarray):
        from avatarkit.cage import _kernels

        n = len(self.rest)
        pre = self._pre
        means = np.empty((n, 3), np.float32)
        quats = np.empty((n, 4), np.float32)
        scales = np.empty((n, 3), np.float32)
        if n:
            _kernels.principal_rebuild(np.ascontiguousarray(xt, np.float32), pre["axis"], pre["length"],
                                       pre["perp"], pre["offset"], self.rest.quats, self.rest.scales,
                                       pre["index"], means, quats, scales)
        return means, quats, scales


def principal_rebuild_reference(xt: np.ndarray, rest: GaussianSet, pre: dict):
    """numpy float64 twin of the principal-axis rebuild kernel (tests compare them)."""
    n = len(rest)
    x = np.asarray(xt, np.float64).T
    plus, minus = x[:n], x[n:]
    means = 0.5 * (plus + minus) + pre["offset"]
    v = plus - minus
    length = np.linalg.norm(v, axis=1)
    a = pre["axis"].astype(np.float64)
    b = np.where(length[:, None] > 1e-30, v / np.where(length > 1e-30, length, 1)[:, None], a)
    q = shortest_arc(a, b, pre["perp"])
    quats = quat_multiply(q, rest.quats.astype(np.float64))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    scales = rest.scales.astype(np.float64).copy()
    ratio = np.maximum(length / pre["length"], 1e-6)
    scales[np.arange(n), pre["index"]] *= ratio
    return means.astype(np.float32), quats.astype(np.float32), scales.astype(np.float32)


_PERMUTATIONS = np.array([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]])


def seven_point_rebuild(xt: np.ndarray, rest: GaussianSet, pre: dict):
    """Seven-point rebuild (numpy float64): affine fit, A Sigma A^T, eigendecomposition."""
    n = len(rest)
    x = np.asarray(xt, np.float64).T
    half = np.stack([(x[n * (1 + 2 * i):n * (2 + 2 * i)] - x[n * (2 + 2 * i):n * (3 + 2 * i)]) / 2
                     for i in range(3)], axis=2)                                  # (N, 3, 3)
    affine = half @ pre["half_inv"]                                              # (N, 3, 3)
    cov = affine @ pre["cov"] @ np.swapaxes(affine, 1, 2)
    evals, evecs = np.linalg.eigh(cov)                                           # ascending
    # match eigenvectors to where the rest axes went (A R e_i), keeping axis order and sign
    target = affine @ pre["axes"]                                                # (N, 3, 3) cols
    target /= np.maximum(np.linalg.norm(target, axis=1, keepdims=True), 1e-300)
    score = np.abs(np.einsum("nki,nkj->nij", evecs, target))                     # (N, eig, axis)
    totals = score[:, _PERMUTATIONS, np.arange(3)].sum(axis=2)                   # (N, 6)
    perm = _PERMUTATIONS[np.argmax(totals, axis=1)]                              # axis i <- eig perm[i]
    rot = np.take_along_axis(evecs, perm[:, None, :], axis=2)
    lam = np.take_along_axis(evals, perm, axis=1)
    sign = np.sign(np.einsum("nki,nki->ni", rot, target))
    rot = rot * np.where(sign == 0, 1.0, sign)[:, None, :]
    bad = np.linalg.det(rot) < 0  # a reflecting map: flip the least aligned axis
    if bad.any():
        worst = np.argmin(np.abs(np.einsum("nki,nki->ni", rot[bad], target[bad])), axis=1)
        rot[np.flatnonzero(bad), :, worst] *= -1
    quats = matrix_to_quat(rot)
    same_side = np.einsum("ij,ij->i", quats, rest.quats.astype(np.float64)) < 0
    quats[same_side] *= -1  # keep the rest quaternion's sign: no flips between frames
    scales = np.sqrt(np.maximum(lam, 1e-30))
    means = x[:n] + pre["offset"]
    return means.astype(np.float32), quats.astype(np.float32), scales.astype(np.float32)


# --- weight files ------------------------------------------------------------------------------

@dataclass(eq=False)
class CageWeights:
    """What a weights file holds: enough to rebuild a CageDeformer without recomputing MVC."""

    weights_t: np.ndarray      # (C, P) float32
    cage: Cage
    method: str
    axis_sigma: float
    n_gaussians: int
    fingerprint: str
    path: str | None = None

    def deformer(self, gaussians: GaussianSet) -> CageDeformer:
        """A CageDeformer for `gaussians`, which must be the ones the weights were made for."""
        if len(gaussians) != self.n_gaussians:
            raise InputError(f"weights are for {self.n_gaussians} Gaussians, got {len(gaussians)}", self.path)
        if fingerprint(gaussians) != self.fingerprint:
            raise InputError("weights were computed for different Gaussians (geometry differs)", self.path)
        return CageDeformer(gaussians, self.cage, self.weights_t, self.method, self.axis_sigma)


def save_weights(path: str | os.PathLike, deformer: CageDeformer) -> None:
    """Write a deformer's weights, cage and settings as an uncompressed .npz (atomic)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, format=np.array(WEIGHTS_FORMAT), weights_t=deformer.weights_t,
                 cage_vertices=deformer.cage.vertices, cage_faces=deformer.cage.faces,
                 method=np.array(deformer.method), axis_sigma=np.array(deformer.axis_sigma),
                 n_gaussians=np.array(len(deformer.rest)), fingerprint=np.array(fingerprint(deformer.rest)))


def load_weights(path: str | os.PathLike) -> CageWeights:
    """Read a file written by `save_weights`; FormatError when it is not one."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("file not found", path)
    data = read_npz(path)
    needed = ("format", "weights_t", "cage_vertices", "cage_faces", "method", "axis_sigma",
              "n_gaussians", "fingerprint")
    missing = [k for k in needed if k not in data]
    if missing:
        raise FormatError(f"not a cage weights file (missing {', '.join(missing)})", path)
    if str(data["format"]) != WEIGHTS_FORMAT:
        raise FormatError(f"unsupported weights format {str(data['format'])!r}", path)
    try:
        cage = Cage(data["cage_vertices"], data["cage_faces"])
    except InputError as e:
        raise FormatError(e.message, path) from None
    wt = data["weights_t"]
    method = str(data["method"])
    n = int(data["n_gaussians"])
    rows = (2 if method == "principal_axis" else 7) * n
    if method not in METHODS or wt.dtype != np.float32 or wt.shape != (cage.n_vertices, rows):
        raise FormatError(f"inconsistent weights: {method}, {wt.dtype} {wt.shape} for {n} Gaussians "
                          f"and {cage.n_vertices} cage vertices", path)
    return CageWeights(wt, cage, method, float(data["axis_sigma"]), n, str(data["fingerprint"]), path)
