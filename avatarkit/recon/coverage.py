"""Silhouette coverage: Gaussians for the photo's head pixels that the assembled avatar leaves
uncovered in the input view.

The bald head is the fitted head model and the hair is grown from its scalp, so pixels of the
photo's head (skin + hair labels) can stay uncovered: ears that stand out beyond the model, a
face silhouette a little wider than the fit's, gaps the 3D hair segmentation and the push-out
opened. Seen from the input camera those pixels show the background, which is most of the
front view's error (measured on samples/portrait.jpg: 1.4 % of the head's pixels, alpha < 0.98,
gave 40 % of the squared error).

`cover_silhouette` renders the avatar from the input camera and gives every head pixel whose
alpha is below `COVER_ALPHA` one flat Gaussian facing the camera, one pixel and a half wide, at
the depth of the nearest covered head pixel (if that is within `COVER_REACH`), coloured from the photo (the colour matching that
follows refines it). Skin pixels become bald Gaussians bound to their nearest head triangle
(`part` skin), hair pixels hair Gaussians (`strand` -1, `seen` 1; kept `HAIR_MARGIN` outside the
head, the others dropped). At most `MAX_COVER` pixels are filled (evenly thinned, larger
Gaussians). Seen from the side they are thin, like the hair fill (`hair_fill.fill_coverage`).

Pixels at the label's edge mix the head with what is behind it (an ear's rim with the wall), and
a segmentation's mistake next to the head (a collar labelled skin) is the background's colour
outright. A disc coloured like that matches the photo from the front, but from the side the
discs are seen edge-on and a column of them reads as a pale (or dark) streak behind the ear. So
each pixel's colour c is unmixed between the photo's nearest covered pixel of the same label h
(what the head looks like there) and its nearest background b (`COVER_BG_GAP` pixels clear of
the head labels): its head share a = (c - b).(h - b) / |h - b|^2, clipped to [0, 1]. A pixel
with a < `COVER_MIN_SHARE` is mostly background and gets nothing; the others get the unmixed
colour (c - (1 - a) b) / a and opacity a times the usual, so that seen from the front over the
background they still show c, and seen from the side they show the head's colour, faintly. Where
h and b are too alike to tell apart (`COVER_MIN_CONTRAST`), a = 1, as before.

Under the jaw the photo's skin beyond the fitted head is not the head's outline but the neck's
shaded side, a collar's fold or the shadow between them: those pixels (`under_jaw`, past the
render's rim) get no disc (`COVER_NECK` off) and are left out of the colour matching.
"""
from __future__ import annotations

import numpy as np

from avatarkit.gaussians.gaussian_set import GaussianSet

#: head pixels whose rendered alpha is below this get a Gaussian
COVER_ALPHA = 0.9
#: at most this many Gaussians are added (larger ones when thinned)
MAX_COVER = 4000
#: only pixels this close (metres at the depth of the nearest covered pixel) to the rendered avatar
#: are filled: ears and gaps lie next to it, while head labels far from it are the segmentation's
#: mistakes (the sample's orange suit read as skin at the shoulders became floating Gaussians)
COVER_REACH = 0.025
#: the discs' width in pixels of their depth, and thickness relative to the width
COVER_WIDTH_PX = 1.5
COVER_FLATNESS = 0.15
#: opacity of a disc wholly of the head
COVER_OPACITY = 0.9
#: pixels whose head share (module docstring) is below this get no disc
COVER_MIN_SHARE = 0.35
#: the background colour is read this many pixels clear of the head labels (past the mixed rim)
COVER_BG_GAP = 2
#: head and background colours closer than this (RGB in [0, 1], Euclidean) cannot be unmixed
COVER_MIN_CONTRAST = 0.1
#: where the head's colour h read at the nearest covered pixel is too like the background to
#: unmix (`COVER_MIN_CONTRAST`), it is read again at the nearest covered pixel of the label inside
#: the fitted head mesh's silhouette eroded by this many pixels (`head_share(inside=)`; None: not,
#: a = 1 there, the rule before). The render covers the wall for a pixel or two past the mesh's
#: outline (the discs' overshoot), and where the segmentation took that wall in, the covered
#: pixel of the label there shows the wall: h was the background's colour and the pixels beyond
#: got opaque wall-coloured discs. On the mesh subject's reference frame the skin label reaches
#: 4 px into the white wall by the ear: the white crescent by its ear at the profile
#: (docs/video-build.md, "The back of the neck's colour (session 23)"). Only there: h read
#: inside the head for every pixel also moved the rim's unmixing (the mesh subject's video build
#: front -0.17 dB). Off: 1 takes the crescent away (mesh subject's video build -45 / +90 / -90
#: +0.30 / +0.06 / +0.16 dB) but its front loses 0.19 (where the white discs lay over the white
#: wall the build shows what is behind them) and its single-frame build 0.16 / 0.18 at -45 / -90 (the
#: photo's colour matching then pulls the side of the face's discs to the white skin-labelled
#: wall instead); the other subjects build the same to the digit
COVER_HEAD_INSIDE: int | None = None
#: False: the photo's skin pixels beyond the fitted head under the jaw get no disc: a skin disc
#: whose nearest head triangle is the neck's (the model's `neck` region), or a triangle skinned
#: to the jaw by at least `UNDER_JAW_WEIGHT` with the disc below it (its offset from the
#: triangle's centroid pointing down, -Y, more than sideways: `under_jaw`), farther than
#: `NECK_RIM_PX` from the render's covered pixels. True: they get one
#: (the builds before session 24). There the skin label beyond the model's neck is the neck's
#: shaded side, a collar's fold or the shadow between them, and a camera-facing disc of that
#: colour, right from the front, stands as a dark fin seen from the side: the grey clip's dark
#: line down the neck's side at 45 and 90 degrees and the bulge on its neck's right side at the
#: front, the glasses clip's collar fold below the ear (docs/building.md, "The neck's coverage
#: (session 24)"). Above the jaw (the ears, a face wider than the fit) nothing changes. Off since
#: session 24: the shared clips' held-out person PSNR (`evaluate --compare-single`) grey +0.34 /
#: +0.36 dB (video / single-frame build), glasses -0.04 / +0.00; the sample portrait and the
#: synthetic subjects' builds (their necks within `NECK_RIM_PX` of the fit) the same to the digit.
#: Single-frame builds only (`COVER_NECK_VIDEO` for the video builds)
COVER_NECK = False
UNDER_JAW_WEIGHT = 0.5
#: with `COVER_NECK` off, the under-the-jaw pixels this close (pixels) to the render's covered
#: pixels keep their discs: the render's own rim (the fit a pixel or two narrower than the photo's
#: outline), seen from the side a line no deeper than two discs. Dropped there too, the sample
#: portrait's jaw against its dark collar showed the white background through 38 pixels (its
#: front view in the head mask 28.19 -> 27.81 dB)
NECK_RIM_PX = 2.0
#: `COVER_NECK` for the video builds (two or more keyframes; `cover_silhouette(views=True)`):
#: True, they keep the neck's coverage discs. On the white and cluttered walls the synthetic
#: subjects' video builds are the same either way (no neck of theirs past the rim), but on the
#: dark wall the mesh subject's video build lost 0.07 / 0.17 / 0.26 / 0.04 / 0.26 dB (front /
#: +45 / -45 / +90 / -90; its single-frame build +0.01) with them dropped: not understood, so
#: the rule stays with the single-frame builds (the shared clips, every portrait)
COVER_NECK_VIDEO = True
#: a video build's (`cover_silhouette(views=True, plate=)`) skin pixels whose colour continues the
#: video's known wall get no disc and are left out of the photo's colour matching (`neck_out`):
#: at least `COVER_PLATE_MATCHES` pixels the wall plate knows (`track.background_plate`) within
#: this share of the longer side are within `background_plate.AGREE` of the pixel's colour in
#: every channel (`wall_continued`; None: no such test), where the unmixing reads the pixel as the
#: head's (`head_share` at least `COVER_MIN_SHARE`: a wall-coloured pixel next to the same wall
#: is background already, no disc; the white-wall sample avatar and bob are unchanged to the
#: digit, the white-wall mesh subject is not: below). Skin pixels only: between a strand's hairs the hair label shows the wall as a
#: matter of course (the white-wall bob's rim moved 0.15 dB with its hair pixels tested too). A
#: portrait segmentation takes in wall of
#: a skin-like colour beside the jaw (the cluttered wall's plaster, 6-17 px from any pixel the
#: plate knows: the head's zone covers it in every frame); the unmixing (`head_share`) read most
#: of it as all head, the discs stood opaque in the plaster's colour, and the rim's own discs
#: were matched to it: pale specks beside the jaw and down the neck at
#: every preview (session 26, second round, docs/video-build.md "The wall's specks beside the
#: jaw"). The head's own rim is not the wall's colour to within AGREE levels in every channel: on
#: the cluttered wall's sample avatar none of its 52 other discs' pixels has 3 such pixels within
#: 0.1, every one of its 31 plaster discs' 18 or more. The pipeline hands the plate to the final
#: build only, not to the registration drafts (`multiview.VideoViews.covers_plate`). Single-frame
#: builds (the shared real clips build from one keyframe) are not reached. On at 0.1 (None: off,
#: the rule before session 27): it clears the specks (the cluttered wall's sample avatar front +0.53 / +0.47 dB, seeds 0 /
#: 1) but the white-wall mesh subject's reference skin label runs into its white wall by the ear
#: (session 23's white crescent), which continues the white plate: its discs dropped there, front
#: -0.22 dB (-45 +0.40, -90 +0.22). The two are one case (session 27, docs/video-build.md "The
#: white crescent and the plaster"): the build's discs overshoot over the inner pixels of the wall
#: the label took in, so the nearest covered skin pixel `head_share` reads the head's colour at
#: is that wall, as its background is: too alike to unmix, a = 1 (22 of the plaster's 31 discs,
#: all 13 of the crescent's). The crescent's white discs cost the front nothing only because the
#: benchmark renders on white, the wall's colour: they paint the wall over the build's cheek where
#: it stands past the truth's outline. Scored on black (the web player's background) or mid-grey
#: the rule's mesh subject front gains 0.88 / 0.45 dB, and a white blob shows on main's cheek
#: (seeds 1 and 2 alike; the whip clip's sample avatar and mesh subject show the crescent too: front
#: -0.16 / -0.17 on white, +0.90 / +0.85 on black, -45 +1.07 / +0.43 on white). A
#: rule sparing the pixels the unmixing cannot read would spare the plaster with them (22 of its
#: 31 discs). Switched on by session 27's lead: wall-coloured opaque discs on the cheek are a
#: defect on every background but the wall's own, and every view the rule moves gains when the
#: same builds are scored on black or grey (the clutter mesh subject's front on black -0.01)
COVER_PLATE: float | None = 0.1
COVER_PLATE_MATCHES = 3


def wall_continued(plate, image: np.ndarray, region: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of `region` (H, W) bool of image (H, W, 3) uint8 whose colour
    agrees (`background_plate.AGREE`, every channel) with at least `COVER_PLATE_MATCHES` pixels
    the wall `plate` knows within `COVER_PLATE` of the longer side (`COVER_PLATE`); all False
    without a plate, with no known pixel or with `COVER_PLATE` None."""
    from avatarkit.track import background_plate

    region = np.asarray(region, bool)
    out = np.zeros(region.shape, bool)
    reach = COVER_PLATE
    if plate is None or reach is None or not region.any():
        return out
    colour, known = plate.at(region.shape)
    if not known.any():
        return out
    r = max(1, int(round(float(reach) * max(region.shape))))
    # the decision only: counting stops at the threshold (`continues`: a phone video's 1920 px
    # frame has a disc of ~116,000 offsets here)
    return region & background_plate.continues(known, colour, image, region, r, COVER_PLATE_MATCHES)


def under_jaw(means: np.ndarray, ids: np.ndarray, model, vertices: np.ndarray) -> np.ndarray:
    """(N,) bool: discs at `means` (N, 3) whose nearest head triangles `ids` (N,) are the neck's
    (`neck` region: 2 of 3 vertices) or are skinned to the jaw by at least `UNDER_JAW_WEIGHT`
    (their vertices' mean) with the disc below them: its offset from the triangle's centroid
    (on the rest head `vertices` (V, 3)) points down (-Y) by more than half its length."""
    from avatarkit.face.fit import JAW_JOINT

    faces = np.asarray(model.faces)[np.asarray(ids)]
    out = np.zeros(len(faces), bool)
    if "neck" in model.regions:
        out |= model.region_mask("neck")[faces].sum(axis=1) >= 2
    w = np.asarray(model.weights, np.float64)
    if w.shape[1] > JAW_JOINT:
        jaw = w[faces, JAW_JOINT].mean(axis=1) >= UNDER_JAW_WEIGHT
        off = np.asarray(means, np.float64) - np.asarray(vertices, np.float64)[faces].mean(axis=1)
        out |= jaw & (off[:, 1] < -0.5 * np.linalg.norm(off, axis=1))
    return out


def _extras_like(template: GaussianSet, n: int, values: dict) -> dict:
    """Extras for n new Gaussians with the keys (and dtypes) of `template`'s: `values` where
    given, zeros elsewhere."""
    out = {}
    for key, arr in template.extras.items():
        arr = np.asarray(arr)
        fill = values.get(key, 0)
        out[key] = np.broadcast_to(np.asarray(fill, arr.dtype), (n,) + arr.shape[1:]).copy()
    return out


def _smoothed(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1], a 3x3 box mean: one pixel's colour is too noisy (video codecs)
    to stand for a region's."""
    from scipy import ndimage

    return ndimage.uniform_filter(np.asarray(image, np.float32) / 255.0, size=(3, 3, 1), mode="nearest")


def _background_colour(image: np.ndarray, labels: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """(N, 3) the smoothed photo at the nearest pixel `COVER_BG_GAP` clear of the head labels
    (SKIN, HAIR) for pixels (ys, xs); the image's mean colour when there is no such pixel."""
    from scipy import ndimage

    from avatarkit.recon.segment import HAIR, SKIN

    smooth = _smoothed(image)
    clear = ~ndimage.binary_dilation(np.isin(labels, (SKIN, HAIR)), iterations=COVER_BG_GAP)
    if not clear.any():
        return np.broadcast_to(smooth.reshape(-1, 3).mean(axis=0), (len(ys), 3)).astype(np.float64)
    _, (by, bx) = ndimage.distance_transform_edt(~clear, return_indices=True)
    return smooth[by[ys, xs], bx[ys, xs]].astype(np.float64)


def _nearest_colour(smooth: np.ndarray, labels: np.ndarray, covered: np.ndarray, ys: np.ndarray,
                    xs: np.ndarray) -> np.ndarray:
    """(N, 3) the smoothed photo at the nearest `covered` (H, W) pixel of the same label as each
    pixel (ys, xs) (any covered pixel where none has it)."""
    from scipy import ndimage

    lab = labels[ys, xs]
    h = np.zeros((len(ys), 3))
    for value in np.unique(lab):
        ref = covered & (labels == value)
        ref = ref if ref.any() else covered
        _, (hy, hx) = ndimage.distance_transform_edt(~ref, return_indices=True)
        sel = lab == value
        h[sel] = smooth[hy[ys[sel], xs[sel]], hx[ys[sel], xs[sel]]]
    return h


def head_share(image: np.ndarray, labels: np.ndarray, covered: np.ndarray, ys: np.ndarray, xs: np.ndarray,
               rgb: np.ndarray, inside: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(share (N,) in [0, 1], background (N, 3)): how much of each pixel (ys, xs), colour rgb
    (N, 3) in [0, 1], is head rather than background (module docstring): unmixed between the
    smoothed photo at the nearest `covered` (H, W) pixel of the same label (any covered pixel if
    none has it) and the nearest background (`_background_colour`), and that background colour.
    inside: (H, W) bool, where the head is (`COVER_HEAD_INSIDE`): where the nearest covered pixel
    is too like the background to unmix, the head's colour is read at the nearest covered pixel
    of the label inside it instead."""
    smooth = _smoothed(image)
    h = _nearest_colour(smooth, labels, covered, ys, xs)
    b = _background_colour(image, labels, ys, xs)
    flat = np.einsum("ij,ij->i", h - b, h - b) < COVER_MIN_CONTRAST ** 2
    if inside is not None and flat.any() and (covered & inside).any():
        # the nearest covered pixel showed the wall (the discs' overshoot past the head's
        # outline, over wall the segmentation took in): the head's colour where the head is
        h[flat] = _nearest_colour(smooth, labels, covered & inside, ys[flat], xs[flat])
    hb = h - b
    n2 = np.einsum("ij,ij->i", hb, hb)
    share = np.einsum("ij,ij->i", rgb - b, hb) / np.maximum(n2, 1e-12)
    return np.where(n2 >= COVER_MIN_CONTRAST ** 2, np.clip(share, 0.0, 1.0), 1.0), b


def cover_silhouette(bald: GaussianSet, hair: GaussianSet, fit, image: np.ndarray, labels: np.ndarray,
                     margin: float | None = None, neck_out: np.ndarray | None = None,
                     views: bool = False, plate=None) -> tuple[GaussianSet, GaussianSet, dict]:
    """(bald, hair, figures) with Gaussians added on the uncovered head pixels (module
    docstring). image: (H, W, 3) uint8 seen by `fit.camera`; labels: (H, W) segmentation labels.
    neck_out: an (H, W) bool array or None; with `COVER_NECK` off, the pixels left without a
    disc under the jaw (`under_jaw`) are set True in it (the colour matching leaves them out:
    matched there, the neck's edge discs behind would take the photo's colour at the alpha's
    shortfall, an orange streak). views: a video build's (`COVER_NECK_VIDEO` instead of
    `COVER_NECK`). plate: the video's wall plate (`track.background_plate`), or None: with views,
    the head pixels whose colour continues its known wall get no disc and are set True in
    neck_out (left out of the colour matching; `COVER_PLATE`)."""
    from scipy import ndimage

    from avatarkit.recon.assemble import HAIR_MARGIN
    from avatarkit.recon.bald_discs import PART_SKIN
    from avatarkit.recon.hair_strands import back_project
    from avatarkit.recon.image_sampling import sample_image
    from avatarkit.recon.mesh_distance import signed_distance
    from avatarkit.recon.segment import HAIR, SKIN
    from avatarkit.render import render
    from avatarkit.rig.nearest import nearest_faces
    from avatarkit.rotations import matrix_to_quat

    margin = HAIR_MARGIN if margin is None else float(margin)
    cam = fit.camera
    labels = np.asarray(labels)
    info = {"uncovered": 0, "bald_added": 0, "hair_added": 0, "background_dropped": 0}
    if labels.shape != (cam.height, cam.width) or len(bald) + len(hair) == 0:
        return bald, hair, info
    both = GaussianSet.concat([bald.replace(extras={}), hair.replace(extras={})])
    r = render(both, cam)
    head = np.isin(labels, (SKIN, HAIR))
    hole = head & (r.alpha < COVER_ALPHA)
    known = (r.alpha >= COVER_ALPHA) & (r.depth > 0)
    wall = None
    if views and plate is not None and COVER_PLATE is not None:
        # the wall the segmentation took in beside the head, where the unmixing reads it as head
        # (`head_share`: a wall-coloured pixel next to the same wall is background already): no
        # disc, and left out of the colour matching too (`COVER_PLATE`): matched there, the
        # rim's own discs took the wall's colour
        wall = wall_continued(plate, image, labels == SKIN)
        if wall.any() and known.any():
            wy, wx = np.nonzero(wall)
            a, _ = head_share(image, labels, known, wy, wx, np.asarray(image, np.float64)[wy, wx] / 255.0)
            wall[wy[a < COVER_MIN_SHARE], wx[a < COVER_MIN_SHARE]] = False
        if neck_out is not None:
            neck_out[wall] = True
    info["uncovered"] = int(hole.sum())
    if not hole.any() or not known.any():
        return bald, hair, info
    gap, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    hole &= gap <= COVER_REACH * cam.fx / np.maximum(r.depth[iy, ix], 1e-6)
    info["beyond_reach"] = info["uncovered"] - int(hole.sum())
    if wall is not None:
        info["wall_dropped"] = int((hole & wall).sum())
        hole &= ~wall
    if not hole.any():
        return bald, hair, info
    ys, xs = np.nonzero(hole)
    spread = 1.0
    if len(ys) > MAX_COVER:
        keep = np.linspace(0, len(ys) - 1, MAX_COVER).round().astype(np.int64)
        ys, xs = ys[keep], xs[keep]
        spread = float(np.sqrt(hole.sum() / MAX_COVER))
    px = np.stack([xs + 0.5, ys + 0.5], axis=1).astype(np.float64)
    depth = r.depth[iy[ys, xs], ix[ys, xs]].astype(np.float64)
    centre = cam.camera_center
    means = centre + (back_project(fit, px, 1.0) - centre) * depth[:, None]
    means = means.astype(np.float32).astype(np.float64)    # as stored: bind what the set holds
    width = COVER_WIDTH_PX * spread * depth / cam.fx                 # metres
    scales = np.stack([width, width, COVER_FLATNESS * width], axis=1)
    # columns: the camera's x, y, z axes in the world: a disc facing the camera
    quat = np.tile(matrix_to_quat(np.asarray(cam.rotation, np.float64).T[None])[0], (len(ys), 1))
    rgb = np.clip(sample_image(image, px) / 255.0, 0, 1)
    is_hair = labels[ys, xs] == HAIR
    inside = None
    if COVER_HEAD_INSIDE is not None:
        from avatarkit.recon.multiview import head_silhouette

        inside = head_silhouette(fit.rest_vertices, fit.model.faces, cam)
        if int(COVER_HEAD_INSIDE) > 0:
            inside = ndimage.binary_erosion(inside, iterations=int(COVER_HEAD_INSIDE))
    share, b = head_share(image, labels, known, ys, xs, rgb, inside)
    keep = share >= COVER_MIN_SHARE
    info["background_dropped"] = int((~keep).sum())
    if not keep.all():
        means, scales, quat, rgb, is_hair, share, b, ys, xs = (a[keep] for a in (means, scales, quat, rgb, is_hair,
                                                                                share, b, ys, xs))
    rgb = np.clip((rgb - (1.0 - share[:, None]) * b) / np.maximum(share[:, None], 1e-6), 0, 1)
    opacity = COVER_OPACITY * share

    out_bald, out_hair = bald, hair
    skin = ~is_hair
    if skin.any():
        faces = np.asarray(fit.model.faces)
        ids, _ = nearest_faces(means[skin], np.asarray(fit.rest_vertices, np.float64), faces)
        if not (COVER_NECK_VIDEO if views else COVER_NECK):
            # the neck's and the jaw's underside's skin pixels: no disc (COVER_NECK)
            sel = np.flatnonzero(skin)
            keep = ~under_jaw(means[skin], ids, fit.model, fit.rest_vertices) | (gap[ys[sel], xs[sel]] <= NECK_RIM_PX)
            info["neck_dropped"] = int((~keep).sum())
            if neck_out is not None:
                neck_out[ys[sel[~keep]], xs[sel[~keep]]] = True
            skin = skin.copy()
            skin[sel[~keep]] = False
            ids = ids[keep]
    if skin.any():
        extras = _extras_like(bald, int(skin.sum()), {"binding": ids, "part": PART_SKIN})
        added = GaussianSet.from_colors(means[skin], quat[skin], scales[skin], opacity[skin],
                                        rgb[skin], extras=extras)
        out_bald = GaussianSet.concat([bald, added])
        info["bald_added"] = len(added)
    if is_hair.any():
        sel = np.flatnonzero(is_hair)
        sd = signed_distance(means[sel], fit.rest_vertices, fit.model.faces)
        sel = sel[sd >= margin]                 # hair stays outside the head
        if len(sel):
            extras = _extras_like(hair, len(sel), {"strand": -1, "seen": 1})
            added = GaussianSet.from_colors(means[sel], quat[sel], scales[sel], opacity[sel],
                                            rgb[sel], extras=extras)
            out_hair = GaussianSet.concat([hair, added])
            info["hair_added"] = len(added)
    return out_bald, out_hair, info


__all__ = ["COVER_ALPHA", "COVER_BG_GAP", "COVER_FLATNESS", "COVER_HEAD_INSIDE", "COVER_MIN_CONTRAST", "COVER_MIN_SHARE", "COVER_NECK", "COVER_NECK_VIDEO", "COVER_OPACITY",
           "COVER_PLATE", "COVER_PLATE_MATCHES", "COVER_REACH", "COVER_WIDTH_PX", "MAX_COVER", "NECK_RIM_PX", "UNDER_JAW_WEIGHT", "cover_silhouette", "head_share",
           "under_jaw", "wall_continued"]
