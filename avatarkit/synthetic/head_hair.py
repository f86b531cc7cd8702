"""A complete test avatar made in code: the template head, procedural hair grown from its scalp,
and the hair's cage. Used by the simulation tests and benchmark, and as a sample avatar.

The hair generator (`synthetic.hair.make_hair`) grows strands on an ellipsoid. We fit that
ellipsoid to the template's scalp region (axis-aligned least squares), keep only the strands
whose root lies over the template's scalp region, move each strand along the head's normal so
its root Gaussian sits `CLEARANCE` outside the real head mesh, and finally move every Gaussian
still closer than that out along the head SDF's gradient: the hair starts outside the head,
rooted on the scalp.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from avatarkit.errors import InputError
from avatarkit.gaussians.gaussian_set import GaussianSet

#: every hair Gaussian centre ends at least this far outside the head (metres)
CLEARANCE = 0.0015


@dataclass(eq=False)
class TestAvatar:
    """head_model: `HeadModel` (template); head_vertices (V, 3): the rest head the hair fits;
    hair: hair `GaussianSet` (extras: `strand`); cage: its `Cage`; sdf: the rest head's `HeadSDF`."""

    __test__ = False  # not a pytest class, despite the name

    head_model: object
    head_vertices: np.ndarray
    hair: GaussianSet
    cage: object
    sdf: object


def fit_ellipsoid(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned ellipsoid through points (P, 3) in the least-squares sense of
    a x^2 + b y^2 + c z^2 + d x + e y + f z = 1 -> (centre (3,), radii (3,))."""
    p = np.asarray(points, dtype=np.float64)
    design = np.concatenate([p * p, p], axis=1)
    coef, *_ = np.linalg.lstsq(design, np.ones(len(p)), rcond=None)
    quad, lin = coef[:3], coef[3:]
    if (quad <= 0).any():
        raise InputError("the scalp points do not describe an ellipsoid")
    centre = -lin / (2 * quad)
    rhs = 1 + np.sum(quad * centre * centre)
    return centre, np.sqrt(rhs / quad)


def make_test_avatar(style: str = "long_straight", n_hair: int = 20000, seed: int = 0,
                     cage_vertices: int = 500, head_model=None, sdf_spacing: float = 0.0025) -> TestAvatar:
    """The template head with `style` hair (at most `n_hair` Gaussians: strands whose roots miss
    the scalp region are dropped) and a cage of about `cage_vertices` vertices around it."""
    from avatarkit.cage.build import build_cage
    from avatarkit.head.model import HeadModel
    from avatarkit.head.sdf_grid import HeadSDF
    from avatarkit.synthetic.hair import HeadEllipsoid, make_hair

    head = head_model or HeadModel.template()
    v = np.asarray(head.v_template, dtype=np.float64)
    if "scalp" not in head.regions:
        raise InputError("the head model has no 'scalp' region to grow hair from")
    scalp = np.asarray(head.regions["scalp"])
    centre, radii = fit_ellipsoid(v[scalp])
    hair = make_hair(style, n=n_hair, seed=seed, head=HeadEllipsoid(tuple(centre), tuple(radii)))

    sdf = HeadSDF.build(v, head.faces, spacing=sdf_spacing)
    strand = hair.extras["strand"]
    first = np.r_[True, strand[1:] != strand[:-1]]                      # each strand's root segment
    on_scalp_mask = np.zeros(len(v), bool)
    on_scalp_mask[scalp] = True
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(v).query(hair.means[first])
    keep_strand = np.zeros(strand.max() + 1, bool)
    keep_strand[strand[first]] = on_scalp_mask[nearest]
    hair = hair.subset(keep_strand[strand])
    if len(hair) == 0:
        raise InputError("no hair strand grew over the head's scalp region")

    # Seat every strand on the real scalp: move it (rigidly) along the head's normal at its root
    # so that its first Gaussian sits `clearance` outside the head.
    strand = hair.extras["strand"]
    first = np.r_[True, strand[1:] != strand[:-1]]
    d, g = sdf.query(hair.means[first])
    shift = np.zeros((strand.max() + 1, 3))
    shift[strand[first]] = (CLEARANCE - d)[:, None] * g
    means = hair.means.astype(np.float64) + shift[strand]
    for _ in range(3):  # the SDF is interpolated: a couple of passes settle the last 0.1 mm
        d, g = sdf.query(means)
        low = d < CLEARANCE
        means[low] += (CLEARANCE - d[low])[:, None] * g[low]
    hair = hair.replace(means=means)
    cage = build_cage(hair, target_vertices=cage_vertices)
    return TestAvatar(head, v.astype(np.float32), hair, cage, sdf)
