"""The built-in lifter's gap fill: small hair Gaussians on the photo's hair pixels that the grown
strands leave uncovered in the input view, so the hair silhouette is filled."""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.fit import HeadFit
from avatarkit.recon.hair_strands import GrowthContext, back_project, flow_to_tangent, unit_vectors
from avatarkit.recon.image_sampling import sample_image
from avatarkit.rotations import matrix_to_quat
from avatarkit.recon import hair_strands as _hair_strands  # its switches read at call time

#: share of the hair budget kept for filling the photo's hair silhouette (`fill_coverage`)
FILL_SHARE = 0.1
#: hair pixels whose rendered alpha is below this get fill Gaussians
FILL_ALPHA = 0.9


def fill_coverage(fit: HeadFit, g: GrowthContext, image: np.ndarray, bald_set: GaussianSet,
                  hair: GaussianSet, budget: int, rng: np.random.Generator) -> GaussianSet:
    """Hair Gaussians for the hair pixels the strands left uncovered in the input view (their
    rendered alpha below `FILL_ALPHA`), so the photo's hair silhouette is filled: one small
    Gaussian per uncovered pixel (at most `budget`, evenly thinned), at the depth of the nearest
    covered hair pixel, lying along the 2D hair flow in the head's tangent plane, coloured from
    the photo. Extras as the strands' (`strand` -1, `seen` 1). With more holes than budget,
    a random subset of hole pixels gets proportionally larger Gaussians."""
    from scipy import ndimage

    from avatarkit.render import render

    cam = fit.camera
    empty = GaussianSet.empty().replace(extras={"strand": np.zeros(0, np.int32), "seen": np.zeros(0, np.uint8)})
    if budget <= 0 or len(hair) == 0:
        return empty
    both = GaussianSet.concat([bald_set.replace(extras={}), hair.replace(extras={})])
    alpha = render(both, cam).alpha
    hair_depth = render(hair.replace(extras={}), cam).depth
    hole = g.shell.hair & (alpha < FILL_ALPHA)
    known = hair_depth > 0
    if not hole.any() or not known.any():
        return empty
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    ys, xs = np.nonzero(hole)
    spread = 1.0
    if len(ys) > budget:
        keep = rng.choice(len(ys), budget, replace=False)
        ys, xs = ys[keep], xs[keep]
        spread = float(np.sqrt(hole.sum() / budget))   # fewer, larger Gaussians cover the holes
    px = np.stack([xs + rng.random(len(xs)), ys + rng.random(len(ys))], axis=1)
    depth = hair_depth[iy[ys, xs], ix[ys, xs]].astype(np.float64)
    means = back_project(fit, px, 1.0)  # direction only at depth 1: scale below
    centre = cam.camera_center
    means = centre + (means - centre) * depth[:, None]
    _, normal = g.sdf.query(means)
    f2 = np.stack([g.flow[ys, xs, 0], g.flow[ys, xs, 1]], axis=1)
    t = flow_to_tangent(g, f2, normal)
    nrm = unit_vectors(normal - np.einsum("ij,ij->i", normal, t)[:, None] * t)
    rot = np.stack([t, np.cross(nrm, t), nrm], axis=2)
    pixel = spread * depth / cam.fx                         # metres per pixel at that depth
    m = len(means)
    scales = np.stack([1.6 * pixel, 0.8 * pixel, np.full(m, _hair_strands.HAIR_THICKNESS)], axis=1)
    rgb = sample_image(image, px) / 255.0
    return GaussianSet.from_colors(means, matrix_to_quat(rot), scales, np.full(m, 0.9), rgb,
                                   extras={"strand": np.full(m, -1, np.int32), "seen": np.ones(m, np.uint8)})


__all__ = ["FILL_ALPHA", "FILL_SHARE", "fill_coverage"]
