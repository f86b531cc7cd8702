"""The built-in lifter (issue 8 item 5): the portrait -> a bald head and a hair volume of 3D
Gaussians, offline, with no learned model, in the rest head's frame (see `recon.fit`).

    result = BuiltinLifter().lift(image, analysis, segmentation, bald, fit)   # -> LiftResult

- bald: flat discs on the fitted head's triangles, coloured from the bald image
  (`recon.bald_discs`);
- hair: strands grown from roots on the fitted scalp through a shell extrapolated from the
  photo's hair silhouette, following the 2D hair flow (`recon.hair_strands`), plus small
  Gaussians on the hair pixels the strands leave uncovered (`recon.hair_fill`).

The lifting interface is `recon.lifter` (`LiftResult`, `Lifter`); the other lifter,
`ImportLifter` (splats from an image-to-3D tool), is `recon.import_lifter`.
"""
from __future__ import annotations

import dataclasses

import math
from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.bald_discs import lift_bald
from avatarkit.recon.fit import HeadFit
from avatarkit.recon.hair_fill import fill_coverage
from avatarkit.recon import hair_strands
from avatarkit.recon.hair_strands import (GrowthContext, Hairline, grow_strands, hair_colours, hair_flow,
                                          hair_shell, hidden_from_camera, scalp_roots, unit_vectors)
from avatarkit.recon.image_sampling import lookup
from avatarkit.recon.lifter import LiftResult
from avatarkit.recon.visibility import depth_map
from avatarkit.rotations import matrix_to_quat
from avatarkit.recon import hair_fill as _hair_fill  # its switches read at call time

#: a hidden root (the back of the head) grows where the photo's silhouette shows at least this
#: much hair (metres) at its polar angle
HIDDEN_MIN_THICKNESS = 0.003


def lift_hair(image: np.ndarray, analysis, segmentation, fit: HeadFit, n: int,
              rng: np.random.Generator, sdf=None, bald_set: GaussianSet | None = None,
              hair_end: float | None = None) -> tuple[GaussianSet, dict]:
    """The built-in hair lifting (module docstring) -> (GaussianSet with `strand` and `seen`
    extras, info). An empty set when the portrait has no hair. hair_end: the rest-frame height
    other views show the hair reaching down to (`recon.hair_end`); it lowers the photo's own
    end of the hidden strands, never raises it."""
    from avatarkit.head.sdf_grid import HeadSDF

    model = fit.model
    hair_mask = segmentation.hair
    empty = GaussianSet.empty()
    if n <= 0 or not hair_mask.any():
        return empty, {"hair": 0, "strands": 0}
    v = np.asarray(fit.rest_vertices, np.float64)
    if sdf is None:
        sdf = HeadSDF.build(v, model.faces)
    shell = hair_shell(fit, hair_mask, analysis)
    if hair_end is not None and hair_end < shell.y_end:
        shell = dataclasses.replace(shell, y_end=float(hair_end))
    if not shell.hair.any():
        return empty, {"hair": 0, "strands": 0}
    flow, coherence = hair_flow(image, shell.hair, analysis.eye_distance)
    if bald_set is None:
        bald_set, _ = lift_bald(image, analysis, segmentation,
                                _NoBald(image, segmentation.labels), fit, 20000, rng)
    head_depth, _, dcam = depth_map(bald_set, fit.camera)
    scalp = model.regions["scalp"]
    crown = v[scalp][np.argmax(v[scalp, 1])].copy()
    crown[2] -= 0.25 * (crown[2] - v[scalp, 2].min())     # the whorl sits toward the back
    neck_z = float(np.median(v[model.regions["neck"], 2])) if "neck" in model.regions else float(shell.center3d[2])
    hairline = Hairline.from_scalp(v[scalp], shell.center3d) if hair_strands.NAPE_HAIR else None
    g = GrowthContext(fit, sdf, shell, flow, coherence, head_depth, dcam, segmentation.labels, crown, neck_z,
                      hairline)

    span = max(float(crown[1] - min(shell.y_end, shell.y_jaw)), 0.05)
    max_steps = int(min(160, math.ceil(1.6 * span / hair_strands.SEGMENT) + 10))

    def candidate_roots(count):
        roots = scalp_roots(fit, count, rng)
        _, normal = sdf.query(roots)
        px, _ = fit.camera.project(roots)
        hidden = hidden_from_camera(g, roots + normal * hair_strands.MARGIN, px)
        visible_ok = lookup(shell.hair, px)
        # hidden roots grow where the silhouette shows hair at their polar angle, and below the
        # photo's lowest hair (the nape) when the hairline lets them
        hidden_ok = (shell.thickness_at(px) > HIDDEN_MIN_THICKNESS) | g.nape_roots(roots)
        return roots[np.where(hidden, hidden_ok, visible_ok)]

    pilot = candidate_roots(600)
    if len(pilot) == 0:
        return empty, {"hair": 0, "strands": 0}
    pts, alive, _ = grow_strands(g, pilot, rng.random(len(pilot)), max_steps)
    per = max(float(alive.sum(axis=1).mean()), 1.0)
    keep_share = len(pilot) / 600
    want = int(math.ceil(1.1 * n / per / max(keep_share, 1e-3)))
    roots = candidate_roots(min(want, 60000))
    layer = rng.random(len(roots)) ** 0.7          # more strands toward the outside
    pts, alive, seen = grow_strands(g, roots, layer, max_steps)

    lengths = alive.sum(axis=1)
    order = rng.permutation(len(roots))
    total = np.cumsum(lengths[order])
    chosen = order[: int(np.searchsorted(total, (1 - _hair_fill.FILL_SHARE) * n, side="right"))]
    chosen = chosen[lengths[chosen] > 0]
    sel_s, sel_k = np.nonzero(alive[chosen])
    strand = chosen[sel_s]
    a, b = pts[strand, sel_k], pts[strand, sel_k + 1]
    means = 0.5 * (a + b)
    t = unit_vectors(b - a)
    _, normal = sdf.query(means)
    nrm = unit_vectors(normal - np.einsum("ij,ij->i", normal, t)[:, None] * t)
    side = np.cross(nrm, t)
    rot = np.stack([t, side, nrm], axis=2)           # columns: along, across, out of the scalp
    m = len(means)
    seg = np.linalg.norm(b - a, axis=1)
    # fewer strands must each cover more: widen them below the reference count
    width = hair_strands.HAIR_WIDTH * float(np.clip(np.sqrt(hair_strands.HAIR_REFERENCE_COUNT / max(n, 1)),
                                                    1.0, 4.0))
    scales = np.stack([np.maximum(0.5 * seg, 1e-4), np.full(m, width) * rng.uniform(0.7, 1.3, m),
                       np.full(m, hair_strands.HAIR_THICKNESS)], axis=1)
    px, _ = fit.camera.project(means)
    seen_m = seen[strand, sel_k]
    rgb = hair_colours(image, shell.hair, px, seen_m, rng,
                       below_end=means[:, 1] < shell.y_end if hairline is not None else None)
    rgb *= (0.8 + 0.2 * layer[strand])[:, None]    # inner layers a little darker
    opacity = rng.uniform(0.75, 1.0, m)
    hair = GaussianSet.from_colors(means, matrix_to_quat(rot), scales, opacity, np.clip(rgb, 0, 1),
                                   extras={"strand": strand.astype(np.int32),
                                           "seen": seen_m.astype(np.uint8)})
    hair = GaussianSet.concat([hair, fill_coverage(fit, g, image, bald_set, hair, int(_hair_fill.FILL_SHARE * n), rng)])
    m = len(hair)
    info = {"hair": m, "strands": int(len(np.unique(strand))), "hair_fill": int(m - len(strand)),
            "hair_seen_share": round(float(hair.extras["seen"].mean()), 4) if m else 0.0,
            "hair_end_y": round(shell.y_end, 4), "shell_max_m": round(float(shell.thickness.max()), 4)}
    return hair, info


@dataclass(eq=False)
class _NoBald:
    """A stand-in bald result (the photo itself) for lifting hair without a bald image."""

    image: np.ndarray
    labels: np.ndarray


class BuiltinLifter:
    """The offline lifter (module docstring). n_bald / n_hair: Gaussian counts (hair: at most);
    face_density: how much denser the face is sampled than the back of the head."""

    name = "builtin"

    def __init__(self, n_bald: int = 40_000, n_hair: int = 40_000, seed: int = 0,
                 face_density: float = 4.0):
        for label, value in (("n_bald", n_bald), ("n_hair", n_hair)):
            if int(value) != value or value < (1 if label == "n_bald" else 0):
                raise InputError(f"{label} must be a {'positive' if label == 'n_bald' else 'non-negative'} "
                                 f"integer, got {value!r}")
        self.n_bald, self.n_hair, self.seed = int(n_bald), int(n_hair), int(seed)
        self.face_density = float(face_density)
        # the rest head's HeadSDF (or a `recon.background.Background` computing it), set by the
        # pipeline to share it
        self.sdf = None
        # how low other views show the hair (`recon.hair_end`), set by the pipeline for a video
        self.hair_end = None

    def lift(self, image, analysis, segmentation, bald, fit: HeadFit) -> LiftResult:
        rng = np.random.default_rng([self.seed, 11])
        bald_set, info = lift_bald(image, analysis, segmentation, bald, fit, self.n_bald, rng,
                                   self.face_density)
        from avatarkit.recon.background import Background

        sdf = self.sdf.result() if isinstance(self.sdf, Background) else self.sdf
        hair, hinfo = lift_hair(image, analysis, segmentation, fit, self.n_hair, rng, sdf=sdf,
                                bald_set=bald_set, hair_end=self.hair_end)
        return LiftResult(bald_set, hair, {**info, **hinfo, "lifter": self.name})


__all__ = ["BuiltinLifter", "lift_hair"]
