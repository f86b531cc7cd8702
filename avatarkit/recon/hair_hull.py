"""The hair shell grown from a video build's keyframe silhouettes: hair that another keyframe
shows beyond the single-view shell (the back of the head, volume at the sides seen in profile).

The single-view shell (`recon.hair_strands.hair_shell`) extrapolates the reference photo's hair
silhouette around the head; the keyframes then only remove hair outside their silhouettes
(`multiview.silhouette_outside`). `grow_hull` adds hair where a keyframe shows more:

1. missing pixels: in each labelled keyframe other than the reference, the pixels its
   segmentation calls hair (eroded by `multiview.EDGE_MARGIN` of the image) that the current
   avatar (bald + hair) leaves uncovered (rendered alpha < `multiview.ALPHA_MIN`, and at least
   that margin from any covered pixel: a pose a few pixels off must not grow a rim); in the
   keyframes registered at the turns' ends the hair labels are eroded by `TURNED_MARGIN` only
   (the strands hanging off the nape seen from the side, a few pixels wide);
2. candidates along each missing pixel's ray, every `STEP` metres across the head's depth range,
   kept when they lie in the hair region (between `MIN_GAP` and `hair_strands.MAX_SHELL` above
   the scalp, within `REACH` of the existing hair) and inside the visual hull of the keyframes'
   hair: every labelled keyframe (the reference included) that would see the point (the
   image holds it and the avatar's rendered surface there is not in front of it) labels its
   pixel hair. Undilated masks, unlike the silhouette bound that removes hair: growing is
   held to what every view agrees on, so a pose a few pixels off leaves hair out rather than
   putting a rim of it around the head;
3. per ray, the shell is extended: the layer there is the median height above the scalp of the
   `NEIGHBOURS` nearest existing hair Gaussians, and the ray's first admissible sample within
   `LAYER_TOL` of it wins (the first crossing is what the pixel shows), else the admissible
   sample nearest the layer (a visual hull alone is a loose bound on where hair is: the
   existing shell's thickness decides the depth along the ray);
4. one hair Gaussian there, the size of the ray's pixel footprint (times the subsampling
   stride when there are more missing pixels than `budget`), lying along the nearest existing
   hair's direction in the head's tangent plane, coloured from that keyframe's pixel (the
   colour blend then mixes in every keyframe that sees it, `multiview.VideoViews.colour`).

With `GROW_BARE` (off) step 1 also takes bare scalp (`bare_hair`): pixels a keyframe labels hair
where the avatar is covered but shows its bald head, within `BARE_BAND` of its outline. Such a
ray needs no hair within `REACH` (the scalp anchors it, at most `BARE_SHELL` below), and its
splat is `BARE_FILL` of its height thick, so that it widens the outline seen from the side. It
was tried for the hair at the back of a head whose photo shows hair only on top (the lifter's
hidden strands stop at the height of the photo's hair beside the face): on the synthetic turns
it gained 0.3 dB at the sample avatar's profile and lost 1-3 dB at its front and +-45
(docs/video-build.md, "The hair at the back of the head").

The grown Gaussians carry `strand` -1 and `seen` 0 (the reference camera does not see them:
assemble keeps them free of the photo's landmarks), like the lifter's gap fill.
"""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon import multiview as _multiview
from avatarkit.recon.hair_strands import unit_vectors
from avatarkit.recon.image_sampling import lookup, sample_image
from avatarkit.recon.multiview import View
from avatarkit.rotations import matrix_to_quat, quat_to_matrix
from avatarkit.recon import hair_strands as _hair_strands  # its switches read at call time
from avatarkit.recon import visibility as _visibility  # its switches read at call time

#: ray samples are this far apart (metres)
STEP = 0.002
#: grown hair lies at least this far above the scalp (metres)
MIN_GAP = 0.002
#: and at most this far from the nearest existing hair Gaussian (metres)
REACH = 0.03
#: the shell's layer at a point: the median height above the scalp of this many nearest hair
NEIGHBOURS = 8
#: a ray sample this close (metres) to that layer lies on it
LAYER_TOL = 0.002
#: at most this share of the hair count is grown
GROW_SHARE = 0.15
#: rounds of growth (each reaches at most REACH beyond the hair so far)
ROUNDS = 3
#: rendering for the missing pixels at most this large (pixels)
RENDER_SIDE = 256
#: the missing pixels' margin (share of the image, as `multiview.EDGE_MARGIN`) in the keyframes
#: registered at the turns' ends (`track.video_build.register_turned`, marked
#: `View.info["turned_end"]`; None: `EDGE_MARGIN` there too). Those frames alone see the hair
#: hanging off the back of the head and the nape from the side, strips a few pixels wide that
#: EDGE_MARGIN's erosion (~3 px at 192) leaves no pixel of. Measured (session 20, with
#: `video_build.REGISTER_SHIFTED`, with `TURNED_COVERED_MARGIN`): the held-out bob +0.49 / +0.91
#: dB at +90 / -90 (seed 0), +0.11 / +0.49 (seed 1), +0.52 / +0.63 at +45 (seeds 0 / 1); the
#: sample avatar (seeds 0-2), the mesh subject and the whip's sample avatar within 0.03
#: (docs/video-build.md, "The bob's hair")
TURNED_MARGIN = 0.005
#: TURNED_MARGIN thins the hair labels' erosion; the covered pixels in those frames are dilated
#: by this share of the image (None: EDGE_MARGIN): a pose a few pixels off must not grow a rim
#: (with TURNED_MARGIN's 1 px the sample avatar lost 0.54 / 0.63 dB at +90 / -90). 0.01 (2 px at
#: 192) against EDGE_MARGIN's 3 px: the bob +0.08 / +0.24 dB at +90 / -90 (seed 0), seed 1 and the
#: other subjects within 0.04 (session 20)
TURNED_COVERED_MARGIN = 0.01
#: also grow over bare scalp: keyframe pixels labelled hair where the avatar shows its bald head
#: (`bare_hair`). Off: on the synthetic turns it grew hair over the back of the head but not at
#: the nape's outline that limits the profile, and added outline the truth lacks (the held-out
#: bob's front 2.5x); docs/video-build.md, session 12
GROW_BARE = False
#: bare scalp's hair lies at most this far above it (metres)
BARE_SHELL = 0.02
#: a bare-scalp splat's thickness (its normal scale) is this share of its height above the scalp
BARE_FILL = 0.5
#: bare pixels are eroded off the hair labels' edge by this share of the image (thinner than
#: `multiview.EDGE_MARGIN`: a profile frame shows the hair over the nape as a strip a few pixels
#: wide, and the visual hull keeps a misregistered frame's hair off what other views see as skin)
BARE_MARGIN = 0.005
#: bare pixels only this share of the image inside the avatar's outline (None: anywhere)
BARE_BAND = 0.03
#: a covered pixel shows bare scalp when the hair's share of its rendered colour is below this
BARE_SHARE = 0.2


def _shrunk(camera, side: int | None = None):
    side = RENDER_SIDE if side is None else side
    k = min(1.0, side / max(camera.width, camera.height))
    return camera if k >= 1 else camera.with_size(max(1, round(camera.width * k)), max(1, round(camera.height * k)))


def _disc(r: int):
    import cv2

    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def missing_hair(view: View, alpha: np.ndarray, margin: float | None = None,
                 hair_margin: float | None = None) -> np.ndarray:
    """(H, W) bool: the view's hair pixels (labels at alpha's size) the avatar leaves uncovered
    (module docstring, step 1). alpha: (H, W) the avatar's render from the view. The hair labels
    are eroded by hair_margin (None: margin), the covered pixels dilated by margin (shares of
    the image's longer side)."""
    margin = _multiview.EDGE_MARGIN if margin is None else margin
    import cv2

    from avatarkit.recon.segment import HAIR

    h, w = alpha.shape
    labels = np.asarray(view.labels)
    if labels.shape != (h, w):
        labels = cv2.resize(labels.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    hair = (labels == HAIR).astype(np.uint8)
    covered = (alpha > _multiview.ALPHA_MIN).astype(np.uint8)
    e = max(1, int(round(margin * max(h, w))))
    eh = e if hair_margin is None else max(1, int(round(hair_margin * max(h, w))))
    hair = cv2.erode(hair, _disc(eh))
    covered = cv2.dilate(covered, _disc(e))
    return (hair > 0) & (covered == 0)


def bare_hair(view: View, alpha: np.ndarray, hair_alpha: np.ndarray, margin: float | None = None) -> np.ndarray:
    """(H, W) bool: the view's hair pixels (labels at alpha's size, eroded by margin) where the
    avatar shows its bald head: covered (alpha > `ALPHA_MIN`) with the hair's share of what is
    rendered (hair_alpha: (H, W) the avatar rendered with hair white, bald black) below
    `BARE_SHARE`, at least margin from any pixel the hair shows on. The hair there lies on the
    scalp beneath the view's outline: the back of a head whose reference photo shows no hair
    there, seen in a profile frame."""
    margin = _multiview.EDGE_MARGIN if margin is None else margin
    import cv2

    from avatarkit.recon.segment import HAIR

    h, w = alpha.shape
    labels = np.asarray(view.labels)
    if labels.shape != (h, w):
        labels = cv2.resize(labels.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    e = max(1, int(round(margin * max(h, w))))
    hair = cv2.erode((labels == HAIR).astype(np.uint8), _disc(e))
    shown = cv2.dilate((hair_alpha >= BARE_SHARE).astype(np.uint8), _disc(e))
    bare = (hair > 0) & (alpha > _multiview.ALPHA_MIN) & (shown == 0)
    if BARE_BAND is not None:
        # only the band inside the avatar's outline: what sets the outline from the side
        b = max(1, int(round(BARE_BAND * max(h, w))))
        bare &= cv2.dilate((alpha <= _multiview.ALPHA_MIN).astype(np.uint8), _disc(b)) > 0
    return bare


def _contradicted(points: np.ndarray, labels: list[np.ndarray], depths: list[np.ndarray],
                  alphas: list[np.ndarray], cams) -> np.ndarray:
    """(P,) bool: some view (labels (H, W), the avatar's rendered depth and alpha (H, W),
    camera) would see the point (nothing rendered in front of it there) on a pixel it does not
    label hair."""
    from avatarkit.recon.segment import HAIR

    bad = np.zeros(len(points), bool)
    for lab_image, depth, alpha, cam in zip(labels, depths, alphas, cams):
        px, z = cam.project(points)
        inside = np.isfinite(px).all(axis=1) & (z > 0)
        px = np.where(inside[:, None], px, -1.0)
        inside &= (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        hidden = (lookup(alpha, px) > _multiview.ALPHA_MIN) & (z > lookup(depth, px) + _visibility.DEPTH_TOL)
        bad |= inside & ~hidden & (lookup(lab_image, px) != HAIR)
    return bad


def grow_hull(bald: GaussianSet, hair: GaussianSet, views: list[View], sdf, budget: int | None = None,
              rounds: int | None = None):
    """Hair Gaussians for what the keyframes show beyond the current shell (module docstring),
    in `rounds` rounds (each grows from the hair so far, at most `REACH` at a time).
    bald, hair: the avatar so far (hair with the lifter's `strand` / `seen` extras); views: the
    keyframes, the reference among them (`View.reference`); sdf: the rest head's `HeadSDF`;
    budget: at most this many (default `GROW_SHARE` of the hair). Returns (grown hair
    GaussianSet with the same extras, info: missing pixels per keyframe before and after)."""
    rounds = ROUNDS if rounds is None else rounds
    budget = int(GROW_SHARE * len(hair)) if budget is None else int(budget)
    grown = hair.subset(np.zeros(len(hair), bool))
    info = {"missing_px_before": None, "missing_px_after": None, "grown": 0, "rounds": 0}
    rounds = max(int(rounds), 1)
    for r in range(rounds + 1):
        # the last pass only counts what is still missing
        new, missing = _grow_once(bald, GaussianSet.concat([hair, grown]) if len(grown) else hair, views, sdf,
                                  0 if r == rounds else budget - len(grown))
        if info["missing_px_before"] is None:
            info["missing_px_before"] = missing
        info["missing_px_after"] = missing
        if len(new) == 0:
            break
        grown = GaussianSet.concat([grown, new]) if len(grown) else new
        info["rounds"] += 1
    info["grown"] = len(grown)
    return grown, info


def _grow_once(bald: GaussianSet, hair: GaussianSet, views: list[View], sdf, budget: int):
    """One round of `grow_hull`: (grown, missing pixels per keyframe). With budget <= 0 only the
    missing pixels are counted."""
    import cv2
    from scipy.spatial import cKDTree

    from avatarkit.render import render

    labelled = [v for v in views if v.labels is not None]
    others = [v for v in labelled if not v.reference]
    empty = hair.subset(np.zeros(len(hair), bool))
    info = {"missing_px": []}
    if not others or len(hair) == 0:
        return empty, info["missing_px"]
    union = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    # hair white, bald black: the rendered colour is the hair's share of each pixel
    shares = GaussianSet.concat([bald.replace(extras={}).with_colors(np.zeros((len(bald), 3), np.float32)),
                                 hair.replace(extras={}).with_colors(np.ones((len(hair), 3), np.float32))])
    cams, depths, labels, alphas, hair_alphas = [], [], [], [], []
    for v in labelled:
        cam = _shrunk(v.camera)
        r = render(union, cam, background=(0.0, 0.0, 0.0))
        hair_alphas.append(render(shares, cam, background=(0.0, 0.0, 0.0)).rgb[..., 0] if GROW_BARE and not v.reference
                           else None)
        lab = np.asarray(v.labels)
        if lab.shape != (cam.height, cam.width):
            lab = cv2.resize(lab.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)
        cams.append(cam)
        depths.append(r.depth)
        labels.append(lab.astype(np.int32))
        alphas.append(r.alpha)
    rays = []                                     # (view index, pixels (R, 2))
    for i, v in enumerate(labelled):
        if v.reference:
            continue
        # the frames registered at the turns' ends (`View.info["turned_end"]`) with the thinner
        # margin: the only views of the strands hanging off the back of the head
        turned_end = TURNED_MARGIN is not None and v.info.get("turned_end", False)
        if turned_end:
            covered_margin = _multiview.EDGE_MARGIN if TURNED_COVERED_MARGIN is None else TURNED_COVERED_MARGIN
            miss = missing_hair(v, alphas[i], covered_margin, TURNED_MARGIN)
        else:
            miss = missing_hair(v, alphas[i])
        bare = np.zeros_like(miss) if hair_alphas[i] is None else bare_hair(v, alphas[i], hair_alphas[i], BARE_MARGIN) & ~miss
        ys, xs = np.nonzero(miss | bare)
        info["missing_px"].append(int(len(ys)))
        if len(ys):
            rays.append((i, np.stack([xs + 0.5, ys + 0.5], axis=1), bare[ys, xs]))
    total = sum(len(p) for _, p, _ in rays)
    if total == 0 or budget <= 0:
        return empty, info["missing_px"]
    stride = max(1.0, total / budget)
    tree = cKDTree(np.asarray(hair.means, np.float64))
    hair_sd = sdf.query(np.asarray(hair.means, np.float64))[0]
    shell_height = float(np.median(hair_sd))
    hair_axes = quat_to_matrix(hair.quats.astype(np.float64))[:, :, 0]
    centre = np.asarray(bald.means, np.float64).mean(axis=0)
    extent = float(np.linalg.norm(np.ptp(np.asarray(bald.means, np.float64), axis=0))) / 2 + _hair_strands.MAX_SHELL
    out_means, out_px_size, out_dirs, out_rgb, out_bare = [], [], [], [], []
    rng = np.random.default_rng(0)
    for i, px, on_scalp in rays:
        v, cam = labelled[i], cams[i]
        if stride > 1:
            pick = np.sort(rng.choice(len(px), max(1, int(round(len(px) / stride))), replace=False))
            px, on_scalp = px[pick], on_scalp[pick]
        c = np.asarray(cam.camera_center, np.float64)
        r = cam.rotation
        d = unit_vectors(((px[:, :1] - cam.cx) / cam.fx) * r[0] + ((px[:, 1:] - cam.cy) / cam.fy) * r[1] + r[2])
        dist = float(np.linalg.norm(centre - c))
        ts = np.arange(dist - extent, dist + extent, STEP)
        pts = c[None, None] + d[:, None, :] * ts[None, :, None]             # (R, T, 3)
        flat = pts.reshape(-1, 3)
        sd, _ = sdf.query(flat)
        ok = (sd >= MIN_GAP) & (sd <= _hair_strands.MAX_SHELL)
        # bare scalp is its own anchor: hair there needs no hair nearby (the back of a head whose
        # photo shows hair only on top), only the scalp within BARE_SHELL beneath it
        scalp_ray = np.repeat(on_scalp, pts.shape[1])
        ok &= ~scalp_ray | (sd <= BARE_SHELL)
        idx = np.flatnonzero(ok)
        ok[idx[_contradicted(flat[idx], labels, depths, alphas, cams)]] = False
        idx = np.flatnonzero(ok)
        near, nb = tree.query(flat[idx], k=NEIGHBOURS, distance_upper_bound=REACH)
        found = np.isfinite(near)
        anchored = found[:, 0] | scalp_ray[idx]
        idx, found, nb = idx[anchored], found[anchored], nb[anchored]
        # the shell's layer here: the neighbours' height above the scalp (none near: the
        # shell's median height)
        heights = np.where(found, hair_sd[np.minimum(nb, len(hair) - 1)], np.nan)
        layer = np.full(len(idx), shell_height)
        some = found.any(axis=1)
        layer[some] = np.nanmedian(heights[some], axis=1)
        miss_by = np.full(len(flat), np.inf)
        miss_by[idx] = np.abs(sd[idx] - layer)
        miss_by = miss_by.reshape(pts.shape[:2])
        # the first crossing of the layer along the ray is what the pixel shows; without one,
        # the admissible point nearest the layer
        on_layer = miss_by <= LAYER_TOL
        best = np.where(on_layer.any(axis=1), np.argmax(on_layer, axis=1), np.argmin(miss_by, axis=1))
        hit = np.isfinite(miss_by[np.arange(len(px)), best])
        if not hit.any():
            continue
        p = pts[np.flatnonzero(hit), best[hit]]
        out_means.append(p)
        out_bare.append(on_scalp[hit])
        out_px_size.append(stride ** 0.5 * ts[best[hit]] / cam.fx)
        _, j = tree.query(p)
        out_dirs.append(hair_axes[j])
        out_rgb.append(sample_image(v.image.astype(np.float32) / 255.0,
                                    px[hit] * np.array([v.image.shape[1] / cam.width, v.image.shape[0] / cam.height])))
    if not out_means:
        return empty, info["missing_px"]
    means = np.concatenate(out_means)[:budget]
    size = np.concatenate(out_px_size)[:budget]
    axis = np.concatenate(out_dirs)[:budget]
    rgb = np.concatenate(out_rgb)[:budget]
    on_scalp = np.concatenate(out_bare)[:budget]
    height, normal = sdf.query(means)
    t = unit_vectors(axis - np.einsum("ij,ij->i", axis, normal)[:, None] * normal)
    nrm = unit_vectors(normal - np.einsum("ij,ij->i", normal, t)[:, None] * t)
    rot = np.stack([t, np.cross(nrm, t), nrm], axis=2)
    m = len(means)
    # over bare scalp the splat fills the hair's volume down to the scalp: a sheet as thin as
    # a strand lies edge-on at the outline of a view from the side and would not widen it
    strand_thickness = _hair_strands.HAIR_THICKNESS
    thick = np.where(on_scalp, np.maximum(strand_thickness, BARE_FILL * height), strand_thickness)
    scales = np.stack([1.6 * size, 0.8 * size, thick], axis=1)
    extras = {}
    for k, a in hair.extras.items():
        fill = -1 if k == "strand" else 0
        extras[k] = np.full((m,) + a.shape[1:], fill, dtype=a.dtype)
    grown = GaussianSet.from_colors(means, matrix_to_quat(rot), scales, np.full(m, 0.9), np.clip(rgb, 0, 1),
                                    extras=extras)
    return grown, info["missing_px"]


__all__ = ["BARE_BAND", "BARE_FILL", "BARE_MARGIN", "BARE_SHARE", "BARE_SHELL", "GROW_BARE", "GROW_SHARE", "LAYER_TOL", "MIN_GAP", "NEIGHBOURS", "REACH", "RENDER_SIDE", "ROUNDS", "STEP", "TURNED_COVERED_MARGIN", "TURNED_MARGIN", "bare_hair", "grow_hull", "missing_hair"]
