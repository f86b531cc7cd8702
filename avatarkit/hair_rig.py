"""`HairRig`: what drives an avatar's hair and is slow to compute (the cage deformer's mean value
coordinates and the XPBD simulation model with the rest head's SDF), and its file `rig.npz`.

Rig format 2 stores the simulation model and the deformer's settings but not the MVC weights
(recomputed from hair.ply and cage.ply when the hair first moves); format 1 files, which hold
the dense weights, are still read. The SHA-256 of the rig's inputs (`rig_inputs_sha256`) and of
the head SDF's (`sdf_inputs_sha256`) let a load tell a stale rig from a good one.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Callable

import numpy as np

from avatarkit.errors import FormatError, InputError
from avatarkit.gaussians.gaussian_set import GaussianSet

RIG_FORMAT = "avatarkit.rig/2"
#: rig formats this version reads: 1 stores the dense MVC weights, 2 recomputes them on load
RIG_FORMATS_READ = ("avatarkit.rig/1", RIG_FORMAT)
#: seeds the rig's input hashes; kept at the first format so older avatars still match
_RIG_HASH_TAG = b"avatarkit.rig/1"


@dataclass(eq=False)
class HairRig:
    """What drives the hair and is slow to compute: `deformer` (`CageDeformer`: the MVC weights
    (C, P) of the hair's deformation points in the rest cage) and `model` (`CageModel`: roots,
    attachments, constraints, proxy weights and the rest head's SDF)."""

    deformer: Any
    model: Any

    @classmethod
    def build(cls, head_model, rest_vertices: np.ndarray, hair: GaussianSet, cage,
              method: str = "principal_axis",
              progress: Callable[[int, int], None] | None = None, sdf=None) -> "HairRig":
        """Compute the rig of `hair` in `cage` over the rest head (vertices (V, 3)).
        sdf: the rest head's `HeadSDF` if already built (else built here).

        The deformer's MVC weights are computed now only when `progress` is given (progress(done,
        total) follows them); otherwise they are deferred to the first deformation
        (`CageDeformer.deferred`, the same weights): rig.npz does not store them, so a build that
        is saved and never moves its hair (`avatarkit build`, a rigid-hair avatar) does not pay
        for them (about a third of a build's rig time)."""
        from avatarkit.cage.deform import CageDeformer
        from avatarkit.sim.model import CageModel

        deformer = (CageDeformer.build(hair, cage, method, progress=progress) if progress is not None
                    else CageDeformer.deferred(hair, cage, method))
        model = CageModel.build(cage, hair, head_model, np.asarray(rest_vertices, np.float32), sdf=sdf)
        # the file keeps the SDF's values only; use what a load rebuilds, so a loaded rig
        # simulates exactly like the one built here (the model's roots read distances only,
        # which are the same float32 values either way)
        if not model.sdf.from_values:
            model.sdf = sdf_from_values(model.sdf.values_grad[..., 0], model.sdf.origin, model.sdf.spacing)
        return cls(deformer, model)

    @property
    def method(self) -> str:
        return self.deformer.method

    def driver(self, head_model, rest_vertices: np.ndarray, config=None):
        """A `HairDriver` sharing this rig's model and weights (nothing is recomputed)."""
        from avatarkit.sim.driver import HairDriver

        return HairDriver(head_model, self.deformer.rest, self.deformer.cage, config,
                          rest_vertices=rest_vertices, model=self.model, deformer=self.deformer)

    # -- file ---------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, inputs_sha256: str, sdf_sha256: str) -> None:
        """Write rig.npz (format 2: without the deformer's MVC weights, which a load recomputes).
        inputs_sha256: hash of what the whole rig was computed from; sdf_sha256: of what the
        head SDF was (the rest head only), so a rig rebuilt for new hair can keep the SDF."""
        from avatarkit.fileio import atomic_path

        arrays: dict[str, np.ndarray] = {
            "format": np.array(RIG_FORMAT), "inputs_sha256": np.array(inputs_sha256),
            "sdf_inputs_sha256": np.array(sdf_sha256),
            "deform_method": np.array(self.deformer.method),
            "deform_axis_sigma": np.array(self.deformer.axis_sigma, np.float64)}
        for f in fields(self.model):
            value = getattr(self.model, f.name)
            if f.name == "sdf":  # the gradients are recomputed on load (4x smaller file)
                arrays["sdf_values"] = np.ascontiguousarray(value.values_grad[..., 0])
                arrays["sdf_origin"] = np.asarray(value.origin, np.float64)
                arrays["sdf_spacing"] = np.array(value.spacing, np.float64)
            else:
                arrays[f"model_{f.name}"] = np.asarray(value)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    @staticmethod
    def read_file(path: str | os.PathLike) -> dict[str, np.ndarray]:
        """The arrays of a rig.npz, checked for format and completeness (FormatError)."""
        from avatarkit.fileio import read_npz
        from avatarkit.sim.model import CageModel

        path = Path(path)
        if not path.is_file():
            raise FormatError("rig file missing", path)
        data = read_npz(path)
        if "format" not in data or str(data["format"]) not in RIG_FORMATS_READ:
            raise FormatError(f"not an avatarkit rig (format {' or '.join(map(repr, RIG_FORMATS_READ))} "
                              "expected)", path)
        need = ["inputs_sha256", "sdf_inputs_sha256", "deform_method", "deform_axis_sigma",
                "sdf_values", "sdf_origin", "sdf_spacing"]
        if str(data["format"]) == RIG_FORMATS_READ[0]:
            need.append("deform_weights_t")
        need += [f"model_{f.name}" for f in fields(CageModel) if f.name != "sdf"]
        missing = [k for k in need if k not in data]
        if missing:
            raise FormatError(f"rig is missing {', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''}",
                              path)
        return data

    @classmethod
    def from_file_arrays(cls, data: dict[str, np.ndarray], hair: GaussianSet, cage,
                         path: str | os.PathLike | None = None,
                         progress: Callable[[int, int], None] | None = None) -> "HairRig":
        """The rig of `hair` in `cage` from `read_file`'s arrays (FormatError naming `path`).
        Without stored weights (format 2) the deformer's MVC weights are computed on first use
        (`CageDeformer.deferred`), or here with `progress` (progress(done, total) over the
        points)."""
        from avatarkit.cage.deform import CageDeformer
        from avatarkit.sim.model import CageModel

        try:
            kwargs = {f.name: data[f"model_{f.name}"] for f in fields(CageModel) if f.name != "sdf"}
            kwargs["rest_volume"] = float(kwargs["rest_volume"])
            model = CageModel(sdf=stored_sdf(data), **kwargs)
            if model.num_vertices != cage.n_vertices:
                raise InputError(f"the simulation model has {model.num_vertices} cage vertices, "
                                 f"the cage {cage.n_vertices}")
            method, sigma = str(data["deform_method"]), float(data["deform_axis_sigma"])
            if "deform_weights_t" in data:  # format 1
                deformer = CageDeformer(hair, cage, data["deform_weights_t"], method, sigma)
            else:
                if progress is None:
                    deformer = CageDeformer.deferred(hair, cage, method, sigma)
                else:
                    deformer = CageDeformer.build(hair, cage, method, sigma, progress=progress)
        except InputError as e:
            raise FormatError(f"inconsistent rig: {e.message}", path) from None
        return cls(deformer, model)


def stored_sdf(data: dict[str, np.ndarray]):
    return sdf_from_values(data["sdf_values"], data["sdf_origin"], float(data["sdf_spacing"]))


def sdf_from_values(values: np.ndarray, origin, spacing: float):
    """A `HeadSDF` from its grid of distances (nx, ny, nz): unit gradients by central differences
    (as `HeadSDF.build` makes them, but from the float32 values)."""
    from avatarkit.head.sdf_grid import HeadSDF

    v = np.asarray(values, np.float32)
    if v.ndim != 3 or min(v.shape) < 2:
        raise InputError(f"SDF values must be a (nx, ny, nz) grid with n >= 2, got {v.shape}")
    grad = np.stack(np.gradient(v.astype(np.float64), float(spacing)), axis=-1)
    grad /= np.maximum(np.linalg.norm(grad, axis=-1, keepdims=True), 1e-12)
    return HeadSDF(np.concatenate([v[..., None], grad.astype(np.float32)], axis=-1), origin, spacing,
                   from_values=True)


def sdf_inputs_sha256(rest_vertices: np.ndarray, head_faces: np.ndarray) -> str:
    """SHA-256 of what a rig's head SDF is computed from: the rest head."""
    h = hashlib.sha256(_RIG_HASH_TAG + b"sdf")
    h.update(np.ascontiguousarray(rest_vertices, "<f4").tobytes())
    h.update(np.ascontiguousarray(head_faces, "<i4").tobytes())
    return h.hexdigest()


def rig_inputs_sha256(hair: GaussianSet, cage, rest_vertices: np.ndarray, head_faces: np.ndarray,
                      method: str) -> str:
    """SHA-256 of everything a rig is computed from: hair geometry, cage, rest head, method."""
    h = hashlib.sha256(_RIG_HASH_TAG)
    h.update(method.encode())
    for a in (hair.means, hair.quats, hair.scales, cage.vertices):
        h.update(np.ascontiguousarray(a, "<f4").tobytes())
    h.update(np.ascontiguousarray(cage.faces, "<i4").tobytes())
    h.update(np.ascontiguousarray(rest_vertices, "<f4").tobytes())
    h.update(np.ascontiguousarray(head_faces, "<i4").tobytes())
    return h.hexdigest()


__all__ = ["HairRig", "RIG_FORMAT", "RIG_FORMATS_READ", "rig_inputs_sha256", "sdf_from_values", "stored_sdf", "stored_sdf",
           "sdf_inputs_sha256"]
