"""The build's outline brought onto the photo's person: bald discs the build's own camera shows
over the wall move inward, the hair it shows there is dropped (`trim_outline`; `TRIM_OUTLINE`,
off); or the outline discs narrowed across the outline, their inner edge kept
(`sharpen_outline`; `SHARPEN_OUTLINE`, off).

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

Moving whole discs inward thins the outer ring: the last person pixel is left half covered
(alpha 0.99 -> 0.91 within 1.5 px of the sample portrait's outline), and the front view inside
the head mask loses 1.4-4.7 dB. `sharpen_outline` keeps the inside opaque instead: the
distance to the photo's outline (`outline_distance`) is known at every pixel, so each disc whose
projected edge (`EDGE_SIGMAS` of its projected sigma across the outline, the renderer's 0.3 px^2
dilation included) stands past it is narrowed across the outline only, its inner edge where it
was and its outer edge `BEYOND_PX` past the outline (`narrow_across`: a linear map on the
covariance scales only the image's outward coordinate; along the outline and in depth nothing
changes, so the other views see the disc as before but thinner across). A disc already as thin
as the dilation (seen edge-on at the outline) can only move in whole, no further than its edge
needs. The renderer's dilation (sigma 0.55 px) sets the floor: one layer of Gaussians cannot be
opaque on the last person pixel and clear of the first wall pixel at once, and the head-mask
figure (rendered on white) charges any transparency on the last pixel, so the defaults leave the
edge a quarter pixel out (the sphere's overshoot 1.72 -> 0.84 px per outline px; 2.5 sigmas on
the outline gives 0.14, with the last pixel's alpha 0.96).
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


#: sharpen the build's outline instead (`sharpen_outline`; `recon.pipeline`'s colours stage, in
#: `trim_outline`'s place): the outline discs narrowed across the outline, their inner edge kept.
#: Off (session 20, docs/building.md "A sharp outline"): the overshoot halves (the synthetic
#: talking video's frame 62: 2.04 -> 1.10 px per outline px light, 2.19 -> 1.07 dark) with the
#: last person pixel opaque, the portraits' head-mask figure ties (-0.02..+0.01 dB) and the whole
#: frame gains 0.4-2.9 dB, every evaluate figure rises (grey 27.741 / 26.554 -> 27.785 / 26.795,
#: glasses 28.715 / 27.294 -> 28.769 / 27.490); but the 35-degree render's head mask loses
#: 0.16 dB, grey's #25 lead falls to +0.99 dB and the video builds' side views lose up to 0.15 dB
SHARPEN_OUTLINE = False
#: a disc's edge, in its projected sigmas (across the outline) from its centre
EDGE_SIGMAS = 2.0
#: px beyond the person's outline a sharpened disc's outer edge may stand
BEYOND_PX = 0.25
#: a disc is never narrowed below this share of its projected extent across the outline (it moves
#: inward instead, its outer edge still on the outline)
MIN_SHRINK = 0.05
#: rounds of the hair's votes after the sharpening (0: the hair is left as it is)
HAIR_ROUNDS = 0
#: the hair's Gaussians past the outline are narrowed as the bald discs are (before the votes);
#: one whose move would bring its centre within `assemble.HAIR_MARGIN` of the head keeps its centre
NARROW_HAIR = False


def outline_distance(person: np.ndarray) -> np.ndarray:
    """(H, W) float64: each pixel centre's distance in px to the outline of `person` (H, W) bool,
    positive inside, negative outside; the outline runs half a pixel beyond the last person pixel."""
    from scipy import ndimage

    person = np.asarray(person, bool)
    inside = ndimage.distance_transform_edt(person)
    outside = ndimage.distance_transform_edt(~person)
    return np.where(person, inside - 0.5, 0.5 - outside)


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N,) `img` (H, W) at the pixel positions uv (N, 2) (pixel centres at i + 0.5), clamped to
    the image."""
    h, w = img.shape
    x = np.clip(uv[:, 0] - 0.5, 0, w - 1.000001)
    y = np.clip(uv[:, 1] - 0.5, 0, h - 1.000001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    return ((1 - fy) * ((1 - fx) * img[y0, x0] + fx * img[y0, x0 + 1])
            + fy * ((1 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x0 + 1]))


def narrow_across(gaussians: GaussianSet, camera, sd: np.ndarray, edge_sigmas: float, beyond_px: float,
                  min_shrink: float) -> tuple[GaussianSet, np.ndarray]:
    """(gaussians, narrowed (N,) bool): every Gaussian whose projected edge (`edge_sigmas` of
    its projected sigma, the renderer's dilation included) across the outline of `sd` ((H, W)
    `outline_distance`) stands more than `beyond_px` past it, narrowed across the outline in
    the image and moved inward so that its inner edge stays and its outer edge comes onto
    `beyond_px`. Along the outline, and in depth, nothing changes: the covariance is squashed
    by a linear map that scales only the image's outward coordinate (see `_squash`)."""
    from avatarkit.render.pipeline import DILATION
    from avatarkit.rotations import matrix_to_quat, quat_to_matrix

    n = len(gaussians)
    if n == 0:
        return gaussians, np.zeros(0, bool)
    w = np.asarray(camera.rotation, np.float64)
    pc = camera.to_camera(gaussians.means)                                      # (N, 3)
    z = np.maximum(pc[:, 2], 1e-6)
    uv = np.stack([camera.fx * pc[:, 0] / z + camera.cx, camera.fy * pc[:, 1] / z + camera.cy], 1)
    # the outward direction: down the distance's gradient, from a lightly smoothed field
    from scipy import ndimage
    smooth = ndimage.gaussian_filter(sd, 1.0)
    gy, gx = np.gradient(smooth)
    o = -np.stack([_bilinear(gx, uv), _bilinear(gy, uv)], 1)                    # (N, 2)
    o /= np.maximum(np.linalg.norm(o, axis=1, keepdims=True), 1e-12)
    d = _bilinear(sd, uv)                                                       # (N,) px inside
    jac = np.zeros((n, 2, 3))
    jac[:, 0, 0] = camera.fx / z
    jac[:, 0, 2] = -camera.fx * pc[:, 0] / z ** 2
    jac[:, 1, 1] = camera.fy / z
    jac[:, 1, 2] = -camera.fy * pc[:, 1] / z ** 2
    a = np.einsum("nij,ni->nj", jac, o)                  # (N, 3): camera-space row giving px along o
    t = np.stack([-o[:, 1], o[:, 0]], 1)
    b = np.einsum("nij,ni->nj", jac, t)                  # along the outline
    rot = quat_to_matrix(gaussians.quats.astype(np.float64))
    m = w @ rot * gaussians.scales.astype(np.float64)[:, None, :]
    cov = m @ m.transpose(0, 2, 1)                                              # camera space
    var = np.einsum("ni,nij,nj->n", a, cov, a)                                  # px^2, undilated
    sig = np.sqrt(var + DILATION)
    inner = d + edge_sigmas * sig
    narrowed = (d - edge_sigmas * sig < -beyond_px) & (pc[:, 2] > 1e-6)
    if not narrowed.any():
        return gaussians, narrowed
    # the new projected sigma spans inner edge .. -beyond_px, at least min_shrink of the old
    new_sig = (inner + beyond_px) / (2 * edge_sigmas)
    k = np.sqrt(np.maximum(new_sig ** 2 - DILATION, 0.0) / np.maximum(var, 1e-30))
    k = np.clip(k, min_shrink, 1.0)
    new_sig = np.sqrt(k * k * var + DILATION)
    new_d = -beyond_px + edge_sigmas * new_sig                                  # outer edge on it
    # the squash direction: across the outline (b . q = 0), square to the ray (depth kept)
    q = np.cross(b, pc)
    q /= np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-30)
    aq = np.einsum("ni,ni->n", a, q)
    q *= np.sign(aq)[:, None]
    aq = np.abs(aq)
    ok = narrowed & (aq > 1e-9)
    sq = np.eye(3)[None] + ((k - 1) / np.maximum(aq, 1e-30))[:, None, None] * q[:, :, None] * a[:, None, :]
    new_cov = sq @ cov @ sq.transpose(0, 2, 1)
    shift = -(new_d - d)[:, None] * q / np.maximum(aq, 1e-30)[:, None]          # camera space
    means = np.asarray(gaussians.means, np.float64).copy()
    means[ok] += shift[ok] @ w                                                  # to world
    world_cov = w.T[None] @ new_cov[ok] @ w[None]
    vals, vecs = np.linalg.eigh(world_cov)
    vecs[np.linalg.det(vecs) < 0, :, 0] *= -1
    scales = np.asarray(gaussians.scales, np.float64).copy()
    quats = np.asarray(gaussians.quats, np.float64).copy()
    scales[ok] = np.sqrt(np.maximum(vals, (1e-4 * scales[ok].max(axis=1, keepdims=True)) ** 2))
    quats[ok] = matrix_to_quat(vecs)
    out = gaussians.replace(means=means.astype(np.float32), scales=scales.astype(np.float32),
                            quats=quats.astype(np.float32))
    return out, ok


def _narrow_hair(hair: GaussianSet, fit, person: np.ndarray, edge_sigmas: float, beyond_px: float,
                 min_shrink: float) -> tuple[GaussianSet, int, int]:
    """`narrow_across` on the hair, a narrowed Gaussian's move cut back (to 3/4, 1/2, 1/4 of
    it, or none) where it would leave its centre within `assemble.HAIR_MARGIN` of the rest
    head (the hair stays outside it; its outer edge then stands that much further out):
    (hair, narrowed, moves cut back)."""
    from avatarkit.recon.assemble import HAIR_MARGIN
    from avatarkit.recon.mesh_distance import signed_distance

    out, narrowed = narrow_across(hair, fit.camera, outline_distance(person), edge_sigmas, beyond_px, min_shrink)
    if not narrowed.any():
        return hair, 0, 0
    start = np.asarray(hair.means, np.float64)
    move = np.asarray(out.means, np.float64) - start                          # (N, 3)
    means = np.asarray(out.means).copy()
    todo = np.flatnonzero(narrowed)
    cut = np.zeros(len(hair), bool)
    for share in (1.0, 0.75, 0.5, 0.25):
        trial = (start[todo] + share * move[todo]).astype(np.float32)
        ok = signed_distance(trial, fit.rest_vertices, fit.model.faces) >= HAIR_MARGIN
        means[todo[ok]] = trial[ok]
        cut[todo[ok]] = share < 1.0
        todo = todo[~ok]
        if not len(todo):
            break
    means[todo] = hair.means[todo]
    cut[todo] = True
    return out.replace(means=means), int(narrowed.sum()), int(cut.sum())


def sharpen_outline(bald: GaussianSet, hair: GaussianSet, fit, person: np.ndarray,
                    edge_sigmas: float | None = None, beyond_px: float | None = None,
                    min_shrink: float | None = None, hair_rounds: int | None = None
                    ) -> tuple[GaussianSet, GaussianSet, dict]:
    """(bald, hair, figures): the bald discs whose edge stands past the photo's person outline
    narrowed across it, their inner edge kept (`narrow_across`), then the hair voted over the
    wall dropped as `trim_outline` drops it (`hair_rounds` rounds). Arguments as `trim_outline`'s."""
    from avatarkit.track.frame_hull import wall_image, wall_votes

    edge_sigmas = EDGE_SIGMAS if edge_sigmas is None else float(edge_sigmas)
    beyond_px = BEYOND_PX if beyond_px is None else float(beyond_px)
    min_shrink = MIN_SHRINK if min_shrink is None else float(min_shrink)
    hair_rounds = HAIR_ROUNDS if hair_rounds is None else int(hair_rounds)
    cam = fit.camera
    person = np.asarray(person, bool)
    info = {"bald_narrowed": 0, "hair_dropped": 0, "dropped": []}
    if len(bald) == 0 or person.shape != (cam.height, cam.width) or not person.any():
        return bald, hair, info
    bald, narrowed = narrow_across(bald, cam, outline_distance(person), edge_sigmas, beyond_px, min_shrink)
    info["bald_narrowed"] = int(narrowed.sum())
    if NARROW_HAIR and len(hair):
        hair, info["hair_narrowed"], info["hair_moves_cut"] = _narrow_hair(hair, fit, person, edge_sigmas,
                                                                             beyond_px, min_shrink)
    if hair_rounds <= 0 or len(hair) == 0:
        return bald, hair, info
    nb = len(bald)
    both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    opacities = np.asarray(both.opacities, np.float32)
    wall = wall_image(person, MARGIN)
    dropped = np.zeros(len(hair), bool)
    for _ in range(hair_rounds):
        gone = np.r_[np.zeros(nb, bool), dropped]
        _, outside = wall_votes(both.replace(opacities=np.where(gone, 0.0, opacities).astype(np.float32)),
                                cam, wall, SHARE)
        drop = outside[nb:] & ~dropped
        info["dropped"].append(int(drop.sum()))
        if not drop.any():
            break
        dropped |= drop
    info["hair_dropped"] = int(dropped.sum())
    if dropped.any():
        hair = hair.subset(np.flatnonzero(~dropped))
    return bald, hair, info


__all__ = ["BEYOND_PX", "EDGE_SIGMAS", "HAIR", "HAIR_ROUNDS", "MARGIN", "MIN_SHRINK", "NARROW_HAIR", "ROUNDS", "SHARE",
           "SHARPEN_OUTLINE", "STEP_PX", "TRIM_OUTLINE", "narrow_across", "outline_distance", "sharpen_outline",
           "trim_outline"]
