"""Hair rig (issue 8 item 9): cage + weights + roots, or a rigid scalp binding for short hair.

Mode (`HAIR_MODES`):
- "cage": long hair is simulated. A closed cage of <= `cage_vertices` vertices is built around
  the hair (`avatarkit.cage.build_cage`) and the rig the avatar stores is computed
  (`hair_rig.HairRig.build`: mean value coordinates of the hair in the cage, the XPBD model with
  roots attached to the scalp, proxy collision weights, the rest head's SDF).
- "rigid": short hair does not swing; every hair Gaussian is bound to its nearest scalp
  triangle (`TriangleBinding`, the same local frames as the bald head), so it moves rigidly
  with the scalp. The host triangle travels as the hair's `binding` extra (int32) and the mode
  is recorded in the avatar's provenance (`build.hair_mode`). The cage and rig are built all
  the same: the avatar format requires them, and they let a user simulate the hair anyway.

`detect_hair_mode` decides from the 2D hair mask: hair reaching more than `SHORT_BELOW_EARS`
inter-ocular distances (IOD) below the ear lobes (`EAR_LOBE_V` IOD below the eye line, in the
eye frame of `PortraitAnalysis`), beside the face, is long.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet

HAIR_MODES = ("cage", "rigid")
#: the ear lobes sit this far below the eye line (eye frame v, IOD units)
EAR_LOBE_V = 0.75
#: hair reaching less than this far below the lobes (IOD) is short
SHORT_BELOW_EARS = 0.35
CAGE_VERTICES = 500
#: grid spacing (m) of the rig's head SDF (`HeadSDF.build`'s default: the simulation's collisions)
RIG_SDF_SPACING = 0.0025


def detect_hair_mode(segmentation, analysis) -> tuple[str, dict]:
    """("cage" | "rigid", figures): long or short hair, from the hair label (module docstring).
    Only hair beside or behind the face counts (|u| > 0.6 IOD), so a beard or a fringe does not."""
    hair = np.asarray(segmentation.hair, bool)
    if not hair.any():
        return "rigid", {"hair_below_ears_iod": 0.0}
    ys, xs = np.nonzero(hair)
    uv = analysis.to_face(np.stack([xs + 0.5, ys + 0.5], axis=1))
    side = np.abs(uv[:, 0]) > 0.6
    if not side.any():
        return "rigid", {"hair_below_ears_iod": 0.0}
    lowest = float(np.percentile(uv[side, 1], 99.5))
    below = max(0.0, lowest - EAR_LOBE_V)
    mode = "cage" if below > SHORT_BELOW_EARS else "rigid"
    return mode, {"hair_below_ears_iod": round(below, 4), "hair_lowest_v_iod": round(lowest, 4)}


def scalp_binding(hair: GaussianSet, model, rest_vertices: np.ndarray):
    """`TriangleBinding` of the hair on its nearest scalp triangles of the rest head."""
    from avatarkit.rig.binding import TriangleBinding
    from avatarkit.rig.frames import degenerate_faces
    from avatarkit.rig.nearest import nearest_faces

    v = np.asarray(rest_vertices, np.float64)
    faces = model.faces
    if "scalp" not in model.regions:
        raise InputError("the head model has no scalp region to bind short hair to")
    scalp = np.flatnonzero(model.region_mask("scalp")[faces].sum(axis=1) >= 2)
    scalp = scalp[~degenerate_faces(v, faces[scalp])]
    if len(scalp) == 0:
        raise InputError("the head model's scalp region has no usable triangles")
    ids, _ = nearest_faces(hair.means, v, faces[scalp])
    return TriangleBinding.bind(hair, v, faces, face_ids=scalp[ids])


def rig_sdf(rest_vertices: np.ndarray, faces: np.ndarray):
    """The rig's head SDF of the rest head (vertices as float32, as `rig_hair` uses them), with
    the gradients a rig file's load makes, so `HairRig.build` need not remake them."""
    from avatarkit.hair_rig import sdf_from_values
    from avatarkit.head.sdf_grid import distance_grid

    rest = np.asarray(rest_vertices, np.float32)
    return sdf_from_values(*distance_grid(rest, faces, RIG_SDF_SPACING), RIG_SDF_SPACING)


@dataclass(eq=False)
class HairRigResult:
    """mode: "cage" | "rigid"; hair: the hair (with a `binding` extra in rigid mode); cage: the
    rest `Cage`; rig: the `HairRig`; info: figures."""

    mode: str
    hair: GaussianSet
    cage: object
    rig: object
    info: dict = field(default_factory=dict)


def rig_hair(fit, hair: GaussianSet, mode: str, *, sdf=None, cage_vertices: int | None = None,
             progress=None, threads: int = 2) -> HairRigResult:
    """Build the hair's cage and rig over the fitted rest head (`fit.rest_vertices`).

    mode: "cage" or "rigid" (see the module docstring). sdf: the rest head's `HeadSDF` if
    already built (`rig_sdf`), or a `recon.background.Background` computing it.
    progress(done, total): follows the cage weights. threads=1: everything on this thread, one
    step after the other (the reference the second thread must equal)."""
    cage_vertices = CAGE_VERTICES if cage_vertices is None else cage_vertices
    from avatarkit.hair_rig import HairRig
    from avatarkit.cage.build import build_cage
    from avatarkit.recon.background import Background

    if mode not in HAIR_MODES:
        raise InputError(f"hair mode must be one of {', '.join(HAIR_MODES)}, got {mode!r}")
    if len(hair) == 0:
        raise InputError("there is no hair to rig")
    model = fit.model
    rest = np.asarray(fit.rest_vertices, np.float32)
    keep = {k: v for k, v in hair.extras.items() if k != "binding"}
    hair = hair.replace(extras=keep)
    # The cage (its distance transforms are off the GIL) is built on this thread while the
    # head SDF, unless given (a kd-tree query and a distance transform, off the GIL), and the
    # scalp binding (numpy) are made on two others: none needs another's result, so the results
    # are those of one step after the other (threads=1), in about the time of the longest. The
    # binding has its own thread because the build's SDF (begun during the colours stage) may
    # still be running: behind it, the binding was the stage's longest path.
    if threads < 2:
        sdf = sdf.result() if isinstance(sdf, Background) else sdf if sdf is not None else rig_sdf(rest, model.faces)
        binding = scalp_binding(hair, model, rest) if mode == "rigid" else None
        cage = build_cage(hair, target_vertices=cage_vertices)
    else:
        if sdf is None:
            sdf = Background(rig_sdf, rest, model.faces, name="avatarkit-rig-sdf")
        pending = (Background(scalp_binding, hair, model, rest, name="avatarkit-scalp-binding")
                   if mode == "rigid" else None)
        cage = build_cage(hair, target_vertices=cage_vertices)
        binding = pending.result() if pending is not None else None
        if isinstance(sdf, Background):
            sdf = sdf.result()
    rig = HairRig.build(model, rest, hair, cage, progress=progress, sdf=sdf)
    info = {"cage_vertices": int(cage.n_vertices), "roots": int(len(rig.model.roots))}
    if binding is not None:
        hair = hair.replace(extras={**hair.extras, "binding": binding.face_ids.astype(np.int32)})
        info["bound_to_scalp"] = int(len(np.unique(binding.face_ids)))
    return HairRigResult(mode, hair, cage, rig, info)


__all__ = ["CAGE_VERTICES", "HAIR_MODES", "RIG_SDF_SPACING", "HairRigResult", "detect_hair_mode", "rig_hair",
           "rig_sdf", "scalp_binding"]
