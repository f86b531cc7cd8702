"""The build's outline brought onto the photo's person: bald discs the build's own camera shows
over the wall move inward, the hair it shows there is dropped (`trim_outline`; `TRIM_OUTLINE`,
off).

The bald head is flat discs on the fitted head's triangles, each a Gaussian about a pixel and a
half wide at a 256-480 px portrait (`bald_discs.COVERAGE`). The fit puts the mesh's outline on
the segmentation's, so the discs on that outline spread their Gaussian tails past it: the render
(alpha > 0.5) covered about 2 px of wall per outline pixel all round (session 18, the synthetic
talking video's build frame: 2.02 px on a near-black wall, 2.32 px on a light one; most of it the
bald discs, 1.6 of the 1.7 px before `coverage`'s discs). On a dark wall that rim is skin-
coloured and decides the PSNR; on any wall it is error.

The video build already moves such discs inward by its frames (`track.frame_hull.recede`). Here
the build's single photo votes the same way: the discs and hair are rendered from the fit's
camera, a bald disc with at least `SHARE` of its blending weight on the wall (the segmentation's
background, `MARGIN` px beyond the person) moves `STEP_PX` pixels (at its depth) inward along its
triangle's normal, and the photo votes again, `ROUNDS` times at most. Hidden discs do not vote.
The head stays one closed layer (a side view sees the moved discs face on, a little deeper).
The hair's Gaussians vote too (`HAIR`), and those voted outside are dropped, as the video build's
frame hull clears them (`frame_hull.carve`): the hair is a volume, and dropping its outer
Gaussians shows the hair or scalp behind. Moving them inward instead would put them inside the
head (`assemble` keeps the hair `HAIR_MARGIN` outside it, and the crown's hair lies at that
margin): at the synthetic talking video's build frame every hair Gaussian voted outside was
already at it.
"""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet

#: trim the build's outline (`recon.pipeline`'s colours stage, after `coverage`; the video build's
#: reference frame too). Off (session 19, docs/building.md "The outline's overshoot"): it brings
#: the outline onto the person (the synthetic talking video's held-out frames: 1.83 -> 0.32 px
#: outward, 0.01 -> 0.28 inward per outline px) and raises every `evaluate --compare-single`
#: figure (grey 27.747 / 26.554 -> 27.885 / 26.954, glasses 28.721 / 27.294 -> 28.725 / 27.635,
#: the light / dark synthetic talking videos' single-frame builds +2.9 / +7.5 dB), but the
#: single-frame build gains more than the video build (grey's lead +1.19 -> +0.93 dB, under #25's
#: +1), and the sample portrait's front view inside the head mask loses 1.4 dB (28.01 -> 26.60).
#: The gentler MARGIN 1 / SHARE 0.3 keeps the front view (28.08) but grey's lead is +0.91 too
TRIM_OUTLINE = False
#: a Gaussian votes outside when this share of its blending weight in the photo falls on the wall
SHARE = 0.1
#: pixels (at the disc's depth) a voted disc moves inward per round
STEP_PX = 0.5
#: rounds of votes (at most ROUNDS x STEP_PX pixels inward; each round sees what the last exposed)
ROUNDS = 8
#: the person mask is dilated by this many pixels before the wall is taken
MARGIN = 0
#: the hair's Gaussians vote too, and those voted outside are dropped: the hair's outline over
#: the temples and the crown
HAIR = True


def trim_outline(bald: GaussianSet, hair: GaussianSet, fit, person: np.ndarray,
                 share: float | None = None, step_px: float | None = None, rounds: int | None = None,
                 margin: int | None = None, with_hair: bool | None = None
                 ) -> tuple[GaussianSet, GaussianSet, dict]:
    """(bald, hair, figures): the bald discs the photo shows over the wall moved inward, the
    hair it shows there dropped (module docstring). bald: the bald discs (extras `binding`: host
    triangles of `fit`'s rest head); hair: drawn with them (it hides what is behind it), trimmed
    when `with_hair` (None: `HAIR`); person: (H, W) bool, the photo's person seen by
    `fit.camera`."""
    from avatarkit.track.frame_hull import inward_normals, wall_image, wall_votes

    with_hair = HAIR if with_hair is None else bool(with_hair)
    share = SHARE if share is None else float(share)
    step_px = STEP_PX if step_px is None else float(step_px)
    rounds = ROUNDS if rounds is None else int(rounds)
    margin = MARGIN if margin is None else int(margin)
    cam = fit.camera
    person = np.asarray(person, bool)
    info = {"moved": [], "dropped": [], "bald_moved": 0, "hair_dropped": 0, "step_px": step_px, "share": share}
    if len(bald) == 0 or person.shape != (cam.height, cam.width) or not person.any():
        return bald, hair, info
    nb = len(bald)
    both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})]) if len(hair) else \
        bald.replace(extras={})
    rest = np.asarray(both.means[:nb], np.float64)                              # (nb, 3)
    opacities = np.asarray(both.opacities, np.float32)
    w2c = np.asarray(cam.world_to_camera, np.float64)
    depth = float(np.median(rest @ w2c[:3, :3].T[:, 2] + w2c[2, 3]))
    step = step_px * depth / cam.fx                                              # metres
    normals = inward_normals(fit.rest_vertices, fit.model.faces, bald.extras["binding"])
    wall = wall_image(person, margin)
    offsets = np.zeros((nb, 3))
    moved = np.zeros(nb, bool)
    dropped = np.zeros(len(both) - nb, bool)
    for _ in range(rounds):
        means = np.asarray(both.means).copy()
        means[:nb] = rest + offsets
        shown = both.replace(means=means, opacities=np.where(np.r_[np.zeros(nb, bool), dropped], 0.0,
                                                             opacities).astype(np.float32))
        _, outside = wall_votes(shown, cam, wall, share)
        move = outside[:nb]
        drop = outside[nb:] & ~dropped if with_hair else np.zeros_like(dropped)
        info["moved"].append(int(move.sum()))
        info["dropped"].append(int(drop.sum()))
        if not move.any() and not drop.any():
            break
        offsets[move] += step * normals[move]
        moved |= move
        dropped |= drop
    info["bald_moved"], info["hair_dropped"] = int(moved.sum()), int(dropped.sum())
    if moved.any():
        bald = bald.replace(means=(rest + offsets).astype(np.float32))
    if dropped.any():
        hair = hair.subset(np.flatnonzero(~dropped))
    return bald, hair, info


__all__ = ["HAIR", "MARGIN", "ROUNDS", "SHARE", "STEP_PX", "TRIM_OUTLINE", "trim_outline"]
