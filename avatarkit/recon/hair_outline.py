"""The hair's outline fitted to the keyframes' silhouettes: hair Gaussians moved out where a
keyframe shows the person's hair standing beyond the avatar's outline.

The lifter's hair shell is as thick as the reference photo's silhouette says at each polar
angle, and the back of the head borrows the front view's thickness; where a keyframe looks
edge-on at hair the photo never showed edge-on (the strand tips standing off the back of the
head and the nape, the crown seen from the side), the subject's hair stands millimetres beyond
the avatar's outline. Session 14 put 42-47 % of the sample avatar's profile error there, 20-24 %
of the mesh subject's and 53-66 % of the bob's, and the video build left it where the
single-frame build has it (docs/video-build.md, "Where the profile's error is").

For each labelled keyframe but the tracking's edge (`fit_outline`'s skip: frames whose yaw the
landmark fit under-reads, whose silhouettes sit degrees off the avatar's; the video build also
skips a keyframe whose pose registered against its draft stopped at the search's end, and gives
the others that registered pose: `track.video_build.refine_keyframes`, `OUTLINE_POSES`):
1. the avatar (bald + hair) is rendered from it (at most `hair_hull.RENDER_SIDE` px); a hair
   Gaussian is on its outline when its centre lies within `ON_OUTLINE` px of an uncovered
   pixel (alpha <= `multiview.ALPHA_MIN`);
2. from that nearest uncovered pixel, outward (away from the centre's own pixel), the pixels the
   keyframe shows as the person's hair (the soft person mask >= 0.5, within `HAIR_NEAR` px of a
   hair label) that the avatar leaves uncovered are the gap (at most `MAX_GAP` px), less
   `GAP_MARGIN`;
3. the gap becomes a push: across the view's ray in the image's outward direction (`DIRECTION`
   "image", the least motion that closes it) or along the scalp's normal ("normal").
A Gaussian on several keyframes' outlines takes the least of their pushes, and one within
`VETO_BAND` px of a keyframe's outline that shows no gap there does not move (each silhouette
bounds the hair from its side); only the Gaussians measured so move, at most `MAX_PUSH`, and a
pushed centre must still project inside every such keyframe's person mask
(`multiview.silhouette_outside`), else its push is halved (three times, then none).
With `VETO` "direction" a view with no gap holds only its own side: it cuts the part of a
push that moves the centre toward its outline in its image (`held_push`), and lets a push along
its rays pass. With "contour" (the default) it does so only against a push asked by a keyframe
that sees another contour of the head; against one whose line of sight lies within
`SAME_CONTOUR` degrees of its own (either way round) it holds as "band": the two see nearly the
same contour, so one's gap where the other shows none is their poses' or labels' disagreement.
"""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet
from avatarkit.recon.hair_hull import _shrunk
from avatarkit.recon.hair_strands import unit_vectors
from avatarkit.recon.multiview import View, silhouette_outside, soft_person
from avatarkit.recon import multiview as _multiview  # its switches read at call time

#: a hair Gaussian is on a view's outline within this many pixels (render scale) of it
ON_OUTLINE = 2.0
#: a person pixel counts as hair within this many pixels of a hair label
HAIR_NEAR = 2
#: pixels of a gap not counted: the render's edge and the person mask's are each read to the
#: pixel, so a gap of one pixel is no evidence
GAP_MARGIN = 1.0
#: the longest gap measured, pixels (render scale)
MAX_GAP = 12
#: a hair Gaussian within this many pixels of a view's outline (but not on it) is held by that
#: view where it shows no gap: the neighbouring keyframes' silhouettes bound what one of them
#: (its pose a few degrees off) asks for. 8 rather than 4: on the 32-frame whip clip, whose
#: turn-end frames' yaw is read 4-9 degrees short without the face being lost (so not the
#: tracking's edge), 4 px let them cost the sample avatar 3.7 dB at -45 (8 px: 0.04)
VETO_BAND = 8.0
#: what a keyframe showing no gap near a Gaussian holds: "band" (any push of a Gaussian within
#: `VETO_BAND` px of its outline), "direction" (only the part of a push that moves the centre
#: toward its outline in its image, `held_push`: a push along its rays, which it cannot see,
#: passes) or "contour" ("band" against a push asked by a keyframe whose line of sight lies within
#: `SAME_CONTOUR` of its own, "direction" against the others). "direction" alone moved the mesh
#: subject's crown (+0.23 / +0.32 dB at the profiles) but cost the sample avatar (-0.18 at -45) and
#: the bob (-0.27 at -90): its extra pushes there were asked by a keyframe that sees the holding
#: one's contour (the near-frontal keyframes against the reference, the two turns' ends against
#: each other at the back of the head). "contour": the mesh subject's profile gain +1.73 -> +1.92
#: (seed 1 +1.75 -> +1.97), the sample avatar the same to the digit, the bob within 0.02 dB
#: (docs/video-build.md, "The crown on the mesh subject (session 22)")
VETO = "contour"
#: degrees between two keyframes' lines of sight (either way round: a view from behind sees the
#: contour a view from the front sees) within which they see nearly the same contour of the head
#: (`VETO` "contour"). The eased clips' near-frontal keyframes lie 13-25 degrees from the
#: reference, the turns' ends registered at 64-80 degrees (the bob's lines of sight 25 apart, the
#: sample avatar's 20): 15 lets the near-frontal keyframes' pushes through as "direction" does, 25
#: the bob's turns' ends' at the back of its head; 30-40 push the same Gaussians on the three
#: subjects; 45 holds the mesh subject's -23-degree keyframe against its -64 one (41 apart) and
#: loses half its crown (offline, outline pixels)
SAME_CONTOUR = 30.0
#: the veto in a draft the video build registers the keyframes' poses against (`fit_outline`'s
#: draft): "band". The pushes "contour" lets through are the turned keyframes' own silhouettes,
#: and a draft fitted to them is what those keyframes are registered against (the reason the
#: first draft fits no outline, `track.video_build.DRAFT_OUTLINE`). With "contour" in the draft
#: too the sample avatar lost 0.21 dB at -45 although "contour" gives its final outline band's
#: pushes bit for bit (the drafts' poses moved it, by less than 0.01 degree of yaw); with "band"
#: there it builds main's figures to the digit
DRAFT_VETO = "band"
#: which way a Gaussian moves: "image" (across the view's ray, the image's outward direction)
#: or "normal" (along the scalp's normal)
DIRECTION = "image"
#: pixels a holding keyframe lets a centre move toward its outline beyond the centre's own
#: distance to it less `ON_OUTLINE` (`VETO` "direction", and "contour" against a keyframe that
#: sees another contour): 1, as `GAP_MARGIN`, since the holding view's outline and the centre's
#: distance to it are each read to the pixel. Session 18 measured 0.5 under "direction" and lost
#: the bob's front (-0.31 dB): the near-frontal keyframes' pushes, which "contour" holds whole.
#: With "contour": the mesh subject +0.02..+0.07 dB at every three-quarter and profile view (eased
#: seeds 0 / 1, whip), the sample avatar and the bob the same to the digit
HOLD_TOLERANCE = 1.0
#: the largest push, metres
MAX_PUSH = 0.012
#: a view moves a Gaussian outward by less than this many pixels per millimetre of push: the
#: normal points along the ray, the view cannot tell its height
MIN_PX_PER_MM = 0.1


def view_gaps(view: View, alpha: np.ndarray, camera, points: np.ndarray,
              normals: np.ndarray, detail: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One keyframe's measurement (module docstring, steps 1-3) for hair centres points (N, 3)
    with scalp normals (N, 3) -> (on (N,) bool: measured by this view (on its outline, or
    within `VETO_BAND` of it with no gap), push (N, 3) metres (0 where the view shows no gap),
    beyond (N,) bool: on the outline with the centre's own pixel not the person's, the avatar
    standing beyond the silhouette there). alpha: (H, W) the avatar rendered by `camera` (the
    view's camera at the render's size); the view's labels and image are resized to it.
    detail: a dict to fill with "outward" (N, 2) the image's outward unit direction and "slack"
    (N,) the pixels from the centre to the render's outline (zero where not near it)."""
    import cv2
    from scipy import ndimage

    from avatarkit.recon.segment import HAIR

    h, w = alpha.shape
    n = len(points)
    on = np.zeros(n, bool)
    push = np.zeros((n, 3), np.float64)
    beyond = np.zeros(n, bool)
    if view.labels is None or n == 0:
        return on, push, beyond
    labels = np.asarray(view.labels)
    image = view.image
    if labels.shape != (h, w):
        labels = cv2.resize(labels.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
        image = cv2.resize(np.asarray(image), (w, h), interpolation=cv2.INTER_AREA) if image is not None else None
    covered = alpha > _multiview.ALPHA_MIN
    person = soft_person(labels, image) >= 0.5
    near_hair = ndimage.binary_dilation(labels == HAIR, iterations=HAIR_NEAR)
    hair_gap = person & near_hair & ~covered
    # the nearest uncovered pixel to every pixel, and how far it is
    dist, (iy, ix) = ndimage.distance_transform_edt(covered, return_indices=True)
    px, z = camera.project(points)
    ok = np.isfinite(px).all(axis=1) & (z > 0)
    px = np.where(ok[:, None], px, -1.0)
    ok &= (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    xi = np.clip(px[:, 0].astype(np.int64), 0, w - 1)
    yi = np.clip(px[:, 1].astype(np.int64), 0, h - 1)
    # no depth test: near the outline the rendered depth is the near side of a surface seen
    # edge-on, centimetres in front of the contour's own Gaussians
    near = ok & (dist[yi, xi] <= max(ON_OUTLINE, VETO_BAND))
    on = near & (dist[yi, xi] <= ON_OUTLINE)
    idx = np.flatnonzero(near)
    if len(idx) == 0:
        return on, push, beyond
    # outward: from the centre to its nearest uncovered pixel (a centre already uncovered: the
    # direction away from the nearest covered pixel is unknown, take the normal's projection)
    q = np.stack([ix[yi[idx], xi[idx]] + 0.5, iy[yi[idx], xi[idx]] + 0.5], axis=1)
    d2 = q - px[idx]
    eps = 1e-3
    moved, _ = camera.project(points[idx] + eps * normals[idx])
    along = (moved - px[idx]) / eps                                       # px per metre of push
    small = np.linalg.norm(d2, axis=1) < 0.5
    d2[small] = along[small]
    u = d2 / np.maximum(np.linalg.norm(d2, axis=1, keepdims=True), 1e-9)
    # march outward from the nearest uncovered pixel over the hair the avatar leaves uncovered
    gap = np.zeros(len(idx))
    live = np.ones(len(idx), bool)
    for k in range(MAX_GAP):
        s = q + u * k
        inside = (s[:, 0] >= 0) & (s[:, 0] < w) & (s[:, 1] >= 0) & (s[:, 1] < h)
        sx = np.clip(s[:, 0].astype(np.int64), 0, w - 1)
        sy = np.clip(s[:, 1].astype(np.int64), 0, h - 1)
        live &= inside & hair_gap[sy, sx]
        gap += live
        if not live.any():
            break
    # the other side of the disagreement: the centre's own pixel not the person's (the
    # avatar beyond the silhouette there)
    beyond[idx] = ~person[yi[idx], xi[idx]]
    # both edges are read to the pixel (the render's alpha and the person mask, each at 0.5)
    gap = np.maximum(gap - GAP_MARGIN, 0.0)
    rate = np.einsum("ij,ij->i", along, u)                                # px per metre, outward
    can = rate > MIN_PX_PER_MM * 1000.0
    if DIRECTION == "image":
        # the least motion that closes the gap: across the ray, in the image's outward direction
        # (a strand tip standing off the back of the head seen from the side moves back, not out
        # along the scalp's normal, which also moves it sideways)
        r = np.asarray(camera.rotation, np.float64)
        u3 = u[:, :1] * r[0] / camera.fx + u[:, 1:] * r[1] / camera.fy           # metres per px at z 1
        push[idx[can]] = (gap * z[idx])[can, None] * u3[can]
    else:
        push[idx[can]] = (gap[can] / rate[can])[:, None] * normals[idx[can]]
    on[idx[~can]] = False
    # within the band but not on the outline: only a view showing no gap there counts (a veto)
    no_gap = np.zeros(n, bool)
    no_gap[idx] = (gap == 0) & can
    if detail is not None:
        detail["outward"] = np.zeros((n, 2))
        detail["outward"][idx] = u
        detail["slack"] = np.zeros(n)
        detail["slack"][idx] = dist[yi[idx], xi[idx]]
    return on | (near & ~on & no_gap), push, beyond & on


def held_push(push: np.ndarray, points: np.ndarray, camera, outward: np.ndarray, slack: np.ndarray) -> np.ndarray:
    """(N,) the factor in [0, 1] that keeps each push (N, 3) metres of centres points (N, 3) from
    moving them more than slack (N,) + `HOLD_TOLERANCE` pixels along outward (N, 2) in camera's
    image (`VETO` "direction": a keyframe that shows no gap there holds its side only)."""
    p0, _ = camera.project(points)
    p1, _ = camera.project(points + push)
    a = np.einsum("ij,ij->i", p1 - p0, outward)
    allowed = np.maximum(slack - ON_OUTLINE, 0.0) + HOLD_TOLERANCE
    return np.where(np.isfinite(a) & (a > allowed), allowed / np.maximum(a, 1e-9), 1.0)


def fit_outline(bald: GaussianSet, hair: GaussianSet, views: list[View], sdf,
                skip: frozenset | set = frozenset(), draft: bool = False) -> tuple[GaussianSet, dict]:
    """Hair pushed out to the keyframes' silhouettes (module docstring). bald, hair: the avatar
    so far; views: the keyframes (the reference among them); sdf: the rest head's `HeadSDF`
    (the normals); skip: frames whose keyframes do not count (the tracking's edge). Returns
    (hair with moved centres, info: Gaussians measured, pushed, the pushes' median and 90th
    percentile in mm, per keyframe its outline's Gaussians, those with a gap and those beyond
    the silhouette). With fewer than two such labelled keyframes nothing moves. draft: the build
    is a draft the keyframes' poses are registered against (`DRAFT_VETO` holds, not `VETO`)."""
    from avatarkit.render import render

    labelled = [v for v in views if v.labels is not None and v.frame not in skip]
    info = {"measured": 0, "pushed": 0, "push_mm_p50": 0.0, "push_mm_p90": 0.0}
    if len(labelled) < 2 or len(hair) == 0:
        return hair, info
    means = np.asarray(hair.means, np.float64)
    _, normals = sdf.query(means)
    normals = unit_vectors(normals)
    union = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    best = np.zeros((len(means), 3))
    size = np.full(len(means), np.inf)
    count = np.zeros(len(means), np.int64)             # keyframes the Gaussian is measured in
    holds = []                       # VETO "direction" / "contour": (view index, camera, held, outward, slack)
    veto = DRAFT_VETO if draft else VETO
    by_side = veto in ("direction", "contour")
    # (V, 3) each keyframe's line of sight in the rest frame, and the keyframe whose push each
    # Gaussian takes (-1: none)
    sight = np.array([np.asarray(v.camera.rotation, np.float64)[2] for v in labelled])
    asker = np.full(len(means), -1)
    info["views"] = []
    for vi, v in enumerate(labelled):
        cam = _shrunk(v.camera)
        r = render(union, cam, background=(0.0, 0.0, 0.0))
        detail = {}
        on, push, beyond = view_gaps(v, r.alpha, cam, means, normals, detail)
        norm = np.linalg.norm(push, axis=1)
        measured_here = on
        if by_side:
            # a view with no gap there holds only its own side (`held_push`, below); the least
            # push among the views that show a gap
            held = on & (norm == 0)
            holds.append((vi, cam, held, detail["outward"], detail["slack"]))
            on = on & ~held
        # the least push any view on whose outline the Gaussian lies asks for
        take = on & (norm < size)
        best[take], size[take] = push[take], norm[take]
        asker[take] = vi
        count += on
        gap = on & (norm > 0)
        info["views"].append({"frame": v.frame, "on_outline": int(measured_here.sum()), "with_gap": int(gap.sum()),
                              "beyond": int(beyond.sum()),
                              "push_mm_p50": round(float(np.median(norm[gap])) * 1000, 2) if gap.any() else 0.0})
    if by_side:
        count += np.sum([h[2] for h in holds], axis=0).astype(np.int64) if holds else 0
    measured = count > 0
    info["measured"] = int(measured.sum())
    if not measured.any():
        return hair, info
    # only the measured move: the same push spread to their neighbours (6 mm) put hair beyond
    # the sample avatar's outline at -45 degrees, where no trusted keyframe looks (-0.6 dB)
    push = np.where(measured[:, None] & np.isfinite(size)[:, None], best, 0.0)
    norm = np.linalg.norm(push, axis=1)
    push *= (np.minimum(norm, MAX_PUSH) / np.maximum(norm, 1e-12))[:, None]
    for vi, cam, held, outward, slack in holds:
        if veto == "contour":
            # the asking keyframe sees nearly this one's contour: one shows a gap where the other
            # shows none on the same surface (a pose or a label a pixel or two off, not hair the
            # holding view cannot see), so the hold is whole, as "band"
            same = np.abs(sight[np.maximum(asker, 0)] @ sight[vi]) >= np.cos(np.radians(SAME_CONTOUR))
            push[held & (asker >= 0) & same] = 0.0
        k = np.flatnonzero(held & (np.linalg.norm(push, axis=1) > 0))
        if len(k):
            push[k] *= held_push(push[k], means[k], cam, outward[k], slack[k])[:, None]
    # the visual hull: a pushed centre must stay inside every keyframe's person mask; the push
    # is halved up to three times until it does, else dropped (all four tried in one test)
    moved = np.flatnonzero(np.linalg.norm(push, axis=1) > 0)
    if len(moved):
        s = 0.5 ** np.arange(4)
        trial = means[moved][None] + s[:, None, None] * push[moved][None]          # (4, M, 3)
        out = (silhouette_outside(trial.reshape(-1, 3), labelled) > 0).reshape(4, -1)
        push[moved] *= np.where(out.all(0), 0.0, s[np.argmax(~out, 0)])[:, None]
    size = np.linalg.norm(push, axis=1)
    pushed = size > 1e-4
    info["pushed"] = int(pushed.sum())
    if pushed.any():
        info["push_mm_p50"] = round(float(np.median(size[pushed])) * 1000, 2)
        info["push_mm_p90"] = round(float(np.percentile(size[pushed], 90)) * 1000, 2)
    return hair.replace(means=(means + push).astype(np.float32)), info


__all__ = ["DIRECTION", "DRAFT_VETO", "GAP_MARGIN", "HAIR_NEAR", "HOLD_TOLERANCE", "MAX_GAP", "MAX_PUSH", "ON_OUTLINE", "SAME_CONTOUR",
           "VETO", "VETO_BAND", "fit_outline", "held_push", "view_gaps"]
