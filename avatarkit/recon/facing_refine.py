"""Colours matched to every keyframe of a turning video, each view weighted per Gaussian by how
squarely it sees it (`refine_facing`).

A turning video's keyframes colour the avatar twice before this: the colour blend projects each
keyframe onto the Gaussians that face it (`multiview.colour_from_views`), then the reference
photo's photometric matching (`assemble.refine_colours`) fits what the front view shows, and the
blend's colours come back where the photo sees only a grazing angle
(`multiview.VideoViews.keep_view_colours`). What the sides keep is a projection (one sample at
each centre, bilinear), not a fit of the render: where splats overlap, the render of the sides
is the blend of many samples, not the keyframes' pixels. `refine_colours_views` fitted the
render to every keyframe at once but weighted the views nearly alike (1e-3 + cos^2) and came
before the photo's matching: it traded the front for the sides (`pipeline.MULTIVIEW_REFINE`).

Here the render is matched to every labelled keyframe (the reference, the tracked ones and the
registered turned ones), after the photo's matching, and each Gaussian's update is the weighted
mean of its views' footprint residuals (`assemble.footprint_residuals`) with a weight per view
(`facing_weights`) that is nearly all the view that faces it best:
    bald: seen (its centre within `multiview.DEPTH_TOLERANCE` of the rendered depth, on a
          rendered pixel) x cos(normal, direction to the camera)^`POWER`, nothing below
          `multiview.MIN_COS`;
    hair: the share of its own footprint the renderer shows on the person
          (`multiview.footprint_visibility`, at least `multiview.HAIR_VISIBLE`) x the same
          cos^`POWER` of the head's outward normal there (a strand at the side of the head is
          seen squarely by the turned view, edge-on by the front one);
each x the keyframe's sharpness, the reference x `multiview.REFERENCE_WEIGHT`. With POWER 4 a
view at 30 degrees off the normal outweighs one at 60 by 9:1, so the profile's Gaussians take
the turned frames' residuals. The Gaussians the reference view sees (its weight > 0: the facing
rule of `VideoViews.keep_view_colours`) keep the photo's colours, matched just before: with
them refined too the mesh subject's reference view lost 1.3 dB of its own render and the
synthetic front views 0.3.
The neck's Gaussians are left alone (the head turns, the neck and the clothes do not).

Measured (docs/video-build.md, session 12): +0.1 dB at the profile of the synthetic turning
videos, the mesh subject's front -0.2, the held-out bob's -1.2 (its hair hangs beside the face:
seen squarely from the front where the head's normal says grazing); off
(`pipeline.FACING_REFINE`). Colours fitted to the
known subject's own renders at the profile, on the same geometry, buy +1.0-1.4 dB there on the
sample avatar (the outline carries 55-64 % of the error) and +4-6 dB on the mesh subject, whose
turned frames' pixels land on the wrong Gaussians (its 80-degree frames registered 10-15 degrees
short).
"""
from __future__ import annotations

import numpy as np

#: a view's weight is cos(angle between the outward normal and the direction to it) to this power
POWER = 4
#: rounds of the refine (as `track.frame_colours.ITERATIONS`: the first does most)
ITERATIONS = 2
#: the view's skin + hair pixels are eroded by this many pixels before the residual is taken:
#: a pose a pixel or two off puts the wall under the silhouette's Gaussians
MASK_ERODE = 2
#: a Gaussian takes a view's residual when its blending weight summed over the mask is at
#: least this many pixels (as `assemble.refine_colours`)
MIN_WEIGHT = 0.05


def facing_weights(gaussians, normals: np.ndarray, is_hair: np.ndarray, view, power: float | None = None,
                   render_result=None, person: np.ndarray | None = None) -> np.ndarray:
    """(N,) float64 >= 0: how squarely `view` (a `multiview.View`) sees each Gaussian (module
    docstring). normals: (N, 3) unit outward normals (the head SDF's gradient); is_hair (N,)
    bool; render_result: the view's render of `gaussians` (None: rendered here); person (H, W)
    bool: the pixels a hair Gaussian's footprint counts on (None: the whole image)."""
    power = POWER if power is None else power
    from avatarkit.recon.multiview import (ALPHA_MIN, DEPTH_TOLERANCE, HAIR_VISIBLE, MIN_COS, REFERENCE_WEIGHT,
                                           footprint_visibility)
    from avatarkit.recon.visibility import seen_from
    from avatarkit.render import render

    cam = view.camera
    r = render_result if render_result is not None else render(gaussians, cam, background=(0.0, 0.0, 0.0))
    means = np.asarray(gaussians.means, np.float64)
    seen, px, cos = seen_from(means, np.asarray(normals, np.float64), cam, r.depth, cam,
                              tol=DEPTH_TOLERANCE, min_facing=MIN_COS)
    px = np.asarray(px, np.float64)
    inside = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) \
        & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
    ix = np.clip(np.floor(np.where(np.isfinite(px), px, 0)).astype(np.int64), 0, [cam.width - 1, cam.height - 1])
    seen &= inside & (r.alpha[ix[:, 1], ix[:, 0]] > ALPHA_MIN)
    facing = np.clip(cos, 0.0, 1.0) ** power
    w = np.where(seen, facing, 0.0)
    is_hair = np.asarray(is_hair, bool)
    if is_hair.any():
        vis = footprint_visibility(gaussians, cam, person)
        ok = inside & (vis >= HAIR_VISIBLE) & (cos >= MIN_COS)
        w = np.where(is_hair, np.where(ok, vis * facing, 0.0), w)
    return w * float(view.sharpness) * (REFERENCE_WEIGHT if view.reference else 1.0)


def facing_weights_reference(gaussians, normals: np.ndarray, is_hair: np.ndarray, view, power: float | None = None,
                             person: np.ndarray | None = None) -> np.ndarray:
    """The slow, obvious twin of `facing_weights` (tests only): one Gaussian at a time, its
    camera-space depth against the render's depth at its pixel, its facing from its own
    normal, its hair visibility from `footprint_visibility`."""
    power = POWER if power is None else power
    from avatarkit.recon.multiview import (ALPHA_MIN, DEPTH_TOLERANCE, HAIR_VISIBLE, MIN_COS, REFERENCE_WEIGHT,
                                           footprint_visibility)
    from avatarkit.recon.image_sampling import lookup
    from avatarkit.render import render

    cam = view.camera
    r = render(gaussians, cam, background=(0.0, 0.0, 0.0))
    vis = footprint_visibility(gaussians, cam, person) if np.any(is_hair) else None
    centre = np.asarray(cam.camera_center, np.float64)
    out = np.zeros(len(gaussians))
    for i, m in enumerate(np.asarray(gaussians.means, np.float64)):
        px, z = cam.project(m[None])
        px = np.asarray(px, np.float64)[0]
        if not np.isfinite(px).all() or not (0 <= px[0] < cam.width and 0 <= px[1] < cam.height):
            continue
        d = centre - m
        cos = float(np.dot(d / np.linalg.norm(d), normals[i]))
        if cos < MIN_COS:
            continue
        if is_hair[i]:
            if vis[i] < HAIR_VISIBLE:
                continue
            w = vis[i] * cos ** power
        else:
            depth = float(lookup(r.depth, px[None])[0])
            if not (depth > 0 and float(np.asarray(z).reshape(-1)[0]) <= depth + DEPTH_TOLERANCE):
                continue
            if r.alpha[int(px[1]), int(px[0])] <= ALPHA_MIN:
                continue
            w = cos ** power
        out[i] = w * float(view.sharpness) * (REFERENCE_WEIGHT if view.reference else 1.0)
    return out


def residual_mask(view, erode: int | None = None) -> np.ndarray:
    """(H, W) bool: the view's skin + hair pixels (its labels, the background-coloured halo of
    `multiview.soft_person` removed), eroded by `erode` pixels."""
    erode = MASK_ERODE if erode is None else erode
    import cv2

    from avatarkit.recon.multiview import soft_person
    from avatarkit.recon.segment import HAIR, SKIN

    m = np.isin(view.labels, (SKIN, HAIR)) & (soft_person(view.labels, view.image) >= 0.5)
    if erode > 0:
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode + 1,) * 2)
        m = cv2.erode(m.astype(np.uint8), disc).astype(bool)
    return m


def refine_weighted(gaussians, views: list[dict], select: np.ndarray, iterations: int | None = None,
                    step: float = 1.0):
    """Colours (N, 3) float32 after `iterations` rounds: each round renders every view (dicts
    with camera, target (H, W, 3) float32, mask (H, W) bool, background (3,), weight (N,),
    shows (N,) bool), takes the residual target - render inside the mask averaged over each
    Gaussian's footprint (`assemble.footprint_residuals`), and moves each selected Gaussian by
    `step` x the weighted mean of its views' residuals (weights `weight` where `shows`).
    Returns (colours, updated (N,) bool, (PSNR per view before, after))."""
    iterations = ITERATIONS if iterations is None else iterations
    from avatarkit.recon.assemble import footprint_residuals, psnr
    from avatarkit.render import render

    n = len(gaussians)
    select = np.asarray(select, bool)
    rgb = gaussians.colors.astype(np.float32).copy()
    use = [select & v["shows"] & (v["weight"] > 0) for v in views]
    levels = [None] * len(views)
    history = []
    for it in range(iterations + 1):
        num = np.zeros((n, 3))
        den = np.zeros(n)
        scores = []
        g = gaussians.with_colors(rgb)
        for k, v in enumerate(views):
            r = render(g, v["camera"], background=v["background"])
            scores.append(psnr(r.rgb, v["target"], v["mask"]))
            if it == iterations or not use[k].any():
                continue
            u = use[k]
            px, _ = v["camera"].project(g.means[u])
            delta, levels[k] = footprint_residuals(r.rgb, v["target"], v["mask"], np.asarray(px, np.float64),
                                                   r.meta["radii"][u], levels[k])
            num[u] += v["weight"][u, None] * delta
            den[u] += v["weight"][u]
        history.append(scores)
        if it == iterations:
            break
        upd = den > 0
        rgb[upd] = np.clip(rgb[upd] + step * (num[upd] / den[upd, None]).astype(np.float32), 0.0, 1.0)
    updated = np.any(use, axis=0) if use else np.zeros(n, bool)
    return rgb, updated, (history[0], history[-1])


def refine_facing(bald, hair, views, normals: np.ndarray, keep: np.ndarray | None = None,
                  iterations: int | None = None, power: float | None = None):
    """Bald and hair (GaussianSets of the rest avatar) with their colours matched to every
    labelled view (`multiview.View`s: the keyframes in the avatar's rest frame) at once, each
    view weighted per Gaussian by `facing_weights`. normals: (N_bald + N_hair, 3) outward
    normals; keep: (N,) bool rows left as they are (the neck); the rows the reference view (if
    any) sees are left too. Returns (bald, hair, figures)."""
    iterations = ITERATIONS if iterations is None else iterations
    power = POWER if power is None else power
    from avatarkit.gaussians.gaussian_set import GaussianSet
    from avatarkit.recon.label_lifting import accumulate_weights
    from avatarkit.recon.multiview import soft_person
    from avatarkit.render import render

    both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    n = len(both)
    is_hair = np.zeros(n, bool)
    is_hair[len(bald):] = True
    select = np.ones(n, bool) if keep is None else ~np.asarray(keep, bool)
    prepared = []
    for v in views:
        if v.labels is None:
            continue
        mask = residual_mask(v)
        target = np.asarray(v.image, np.float32) / 255.0
        bg = np.median(target[~mask], axis=0) if (~mask).any() else np.zeros(3, np.float32)
        r = render(both, v.camera, background=(0.0, 0.0, 0.0))
        w = facing_weights(both, normals, is_hair, v, power, r, soft_person(v.labels, v.image) >= 0.5)
        shows = accumulate_weights(both, v.camera, mask.astype(np.int32), 2)[:, 1] >= MIN_WEIGHT
        prepared.append(dict(camera=v.camera, target=target, mask=mask, background=bg, weight=w, shows=shows,
                             frame=v.frame))
        if v.reference:
            # what the reference view sees keeps the photo's colours (matched just before)
            select &= ~(w > 0)
    if not prepared:
        return bald, hair, {"views": 0}
    rgb, updated, (before, after) = refine_weighted(both, prepared, select, iterations)
    before, after = np.asarray(before), np.asarray(after)
    # which view leads each updated Gaussian's mean (the share of its weight)
    w = np.stack([p["weight"] * (p["shows"] & select) for p in prepared])        # (V, N)
    lead = np.argmax(w, axis=0)
    figures = {"views": len(prepared), "updated": int(updated.sum()), "of": n,
               "led_by_view": {int(p["frame"]): int(((lead == k) & updated).sum()) for k, p in enumerate(prepared)},
               "psnr_before": round(float(before.mean()), 3), "psnr_after": round(float(after.mean()), 3),
               "psnr_per_view": {int(p["frame"]): [round(float(a), 2), round(float(b), 2)]
                                 for p, a, b in zip(prepared, before, after)}, "power": power,
               "iterations": iterations}
    both = both.with_colors(rgb)
    return bald.replace(sh=both.sh[:len(bald)]), hair.replace(sh=both.sh[len(bald):]), figures


__all__ = ["ITERATIONS", "MASK_ERODE", "MIN_WEIGHT", "POWER", "facing_weights", "facing_weights_reference",
           "refine_facing", "refine_weighted", "residual_mask"]
