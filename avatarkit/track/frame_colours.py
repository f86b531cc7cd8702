"""Colours fused over a video's frames: the video build's last stage (`fuse_frame_colours`).

A portrait build colours every Gaussian from one photo. Some parts of a head look different in
every frame of a talking video, and one frame is then one arbitrary sample of them:
- the neck and the collar: the avatar's neck rides the head, the clothes around it do not, so
  the build frame's collar pixels land on other pixels in every other frame;
- the lips and the mouth interior: one frame with the mouth closed says nothing about the
  mouth opened (the interior keeps a flat dark red, or the lips' colour the photo gave it).
- the outline: the head moves by a pixel or two from frame to frame, so the wall and the hair
  or skin swap under the Gaussians on the silhouette, and the build frame's colour there is one
  sample of that.
Measured on the shared clips (session 9, docs/video-build.md): the neck / collar carries 5 % of
the single-frame build's held-out squared error on one clip and 27 % on the other, the mouth and
lips 17 % and 3 %, the outline band 37 % and 28 %; the face's interior (eyes, brows, skin:
registered detail) 18-19 %. Fitting every Gaussian's colour to many frames blurs that detail
(the frames' registration differs by a pixel or two) and gained 0.03 dB; fitting only the parts
above gained +0.11 / +0.63 dB on the two clips' second halves.

The stage (`fuse_frame_colours`): track the video with the built avatar (as `avatarkit evaluate`
does: `track_video(avatar=)`, the clip aligned to the reference keyframe, the head carried on
the neck as `track.neck.DEFAULT_HEAD_ON` says), pose the avatar at up
to `FRAMES` frames spread evenly over the eligible frames of the span (face found, confidence at
least `track.keyframes.MIN_CONFIDENCE_SHARE` of the best, head pose within `MAX_TURN` of the reference's), render
each from the tracked camera, and refine the colours of the selected Gaussians
(`fusion_selection`: bald Gaussians on the head model's `REGIONS`; `outline_selection`: those on
the posed renders' outline) against all those frames at once (`refine_colours_frames`: each round, the residual
video - render inside the frame's render mask eroded by `MASK_ERODE` px, averaged over each
Gaussian's footprint as `recon.assemble.refine_colours` does, then averaged over the frames the
Gaussian shows in, leaving out those where it lies more than `HIDDEN_DEPTH` behind the surface
the frame shows). The other Gaussians keep the portrait build's colours. Before the colours,
the Gaussians the frames show over the background are cleared (`track.frame_hull`, `CARVE`).
The video build runs it only when it has one keyframe (a head that does not turn:
`track.video_build`).

With the stage's tracking refined by rendering the avatar (`REFINE`, photometric-fast since
session 17, or `fuse_frame_colours(refine=)`, which `avatarkit evaluate` passes; every
`stage_spacing`-th frame), the frames are registered to about half a pixel, and the blur that
kept the selection to the regions above is gone: the stage then fuses every bald Gaussian and
the hair (`stage_settings`) for `REGISTERED_ITERATIONS` rounds. Measured on the shared clips,
each build tracked with itself as `evaluate --compare-single` now does by default (photometric-
fast), with the frame hull clearing hair: the video build leads the single-frame build by +0.87
dB (grey) / +1.27 dB (glasses) on the held-out frames (+0.73 / +1.17 without the hull; +0.06 /
+0.72 with the stage and the tracking unregistered, the defaults before; docs/video-build.md,
sessions 15-17).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from avatarkit.track import neck as _neck
from avatarkit.track.neck import clip_head_rotation, place_head

#: head-model regions whose bald Gaussians are coloured from the frames (module docstring);
#: the Gaussians on the outline of the posed renders are too (`outline_selection`)
REGIONS = ("neck", "lips", "mouth_interior")
OUTLINE = True
#: the tracking that poses the fused frames refines each frame's head pose and jaw against it by
#: rendering the built avatar (`TrackOptions.refine`; None: the landmark fit's pose). Session 17:
#: photometric-fast (2 cheaper passes on every 5th frame) registers the frames for ~12-15 s of
#: a 250-frame clip (0.3x `photometric` every 3rd), and with `evaluate`'s tracking refined the
#: same way (its default since) the registered stage leads the unregistered one by +0.60 (grey) /
#: +1.70 dB (glasses); with the landmark fit's tracking it loses 0.19 dB on glasses
#: (docs/video-build.md, sessions 13, 15 and 17)
REFINE: str | None = "photometric-fast"
#: the stage's refined tracking refines every k-th frame, at least every REFINE_EVERY-th (a
#: setting's own sparser spacing holds: photometric-fast's 5, `stage_spacing`), the others get
#: the change interpolated (`TrackOptions.refine_every`): a third of the cost, and on the
#: shared clips it registered the colour frames no worse (session 15: the 24 frames' PSNR with
#: the built avatar +0.06 / +0.33 dB mean over refining every frame; the video build's lead
#: +0.87 -> +0.89 / +1.08 -> +1.18 dB)
REFINE_EVERY = 3
#: every bald Gaussian's colour is fused (`fusion_selection(regions=None)`), not only REGIONS'
#: and the outline's; None: when the frames are registered (the stage's refine is set). With
#: the landmark fit's poses the frames are a pixel or two apart and fusing every Gaussian
#: blurred the face (+0.03 dB, session 9); with the registered frames it gains on both shared
#: clips (session 13), but an avatar fused so is worse when the tracking that drives it is not
#: refined (glasses -0.37 dB): docs/video-build.md
FUSE_ALL: bool | None = None
#: the hair's Gaussians are fused too (`fusion_selection(hair=True)`); None: when the frames
#: are registered (session 15: +0.03 / +0.01 dB on the shared clips over FUSE_ALL alone)
FUSE_HAIR: bool | None = None
#: at most this many frames are fused
FRAMES = 24
#: only frames whose head pose is within this of the reference keyframe's (radians of yaw and
#: pitch: `track.keyframes.MIN_SPREAD`, the turn below which a frame adds no view) are fused:
#: this stage fuses what changes over time at the reference's view; turned views are the
#: keyframes' (`recon.multiview`). With every frame of a synthetic turning video it cost the
#: sides 0.1-0.2 dB of the keyframes' colours
MAX_TURN = math.radians(8.0)
#: rounds of the multi-frame refine (the first does most; more rounds sharpen toward single
#: frames' noise)
ITERATIONS = 2
#: the rounds when the frames are registered (the stage's refine set): a third round gains
#: 0.04-0.05 dB on both shared clips there (session 15)
REGISTERED_ITERATIONS = 6
#: the render's person mask is eroded by this many pixels before the residual is taken: the
#: outline's pixels mix the wall in the video and the background in the render
MASK_ERODE = 2
#: the silhouette's band: render-mask pixels within this share of the image's larger side of
#: its outline (6 px at 480)
OUTLINE_BAND = 0.0125
#: a Gaussian is on the outline when its centre falls in the band in at least this share of
#: the frames it shows in
OUTLINE_SHARE = 0.25
#: a Gaussian takes a frame's residual when its blending weight summed over the mask is at
#: least this many pixels (as `recon.assemble.refine_colours`)
MIN_WEIGHT = 0.05
#: a Gaussian's update from a frame is scaled by w / (w + HIDDEN_WEIGHT), w its blending weight
#: summed over the frame's mask (pixels); 0: off, every Gaussian that shows takes its footprint's
#: whole residual. A Gaussian mostly hidden there (under the chin, behind the jaw's edge) does not
#: change the render, so the residual it reads stays and, round after round, pushes its colour
#: toward whatever the pixels around it miss (the green band under the chin in the previews)
HIDDEN_WEIGHT = 0.0
#: a frame where a Gaussian's centre lies more than this (metres) behind the surface the frame
#: shows there (the render's depth at its projection) gives it no update, and with HIDDEN_COUNT
#: does not count in the mean over the frames it shows in either; 0: off. Such a disc shows a
#: sliver (its blending weight reaches MIN_WEIGHT) yet takes the residual of the surface in
#: front, and, changing the render hardly at all, takes it again every round: the back of the
#: neck (10-18 cm behind the front of the neck and the chin in the colour frames) drifted to
#: the specks and the dark blotch a profile or back view shows (session 19, docs/video-build.md).
#: At 3 cm: the grey clip's neck discs off their 12 neighbours' median by > 0.15 fall 177 -> 34
#: (the single-frame build: 24), the back view's PSNR against the single-frame build 25.6 ->
#: 30.1 dB (glasses 29.3 -> 30.3); `evaluate --compare-single` grey 27.747 -> 27.742, glasses
#: 28.721 -> 28.715, the synthetic talking video 30.109 -> 30.113
HIDDEN_DEPTH = 0.03
#: with HIDDEN_DEPTH, a Gaussian's update is the mean over the frames that see it (not hidden
#: so): a disc the mouth or the jaw hides in most frames takes the few that see it whole.
#: False (the hiding frames count, as zeros): grey 27.767, glasses 28.712 (session 19)
HIDDEN_COUNT = True


@dataclass
class FrameView:
    """One posed frame: gaussians (N, same order in every frame), camera, image (H, W, 3) uint8,
    mask (H, W) bool: the pixels whose residual counts; outline (H, W) bool or None: the band
    inside the render's silhouette (`outline_selection`); shows (N,) bool or None: `frame_shows`
    of this frame when already computed (the refine and the outline selection both need it)."""

    gaussians: object
    camera: object
    image: np.ndarray
    mask: np.ndarray
    outline: np.ndarray | None = None
    shows: np.ndarray | None = None
    #: (N,) float: each Gaussian's blending weight summed over the mask (`frame_weights`), or None
    weights: np.ndarray | None = None


def frame_weights(view: FrameView) -> np.ndarray:
    """(N,) float32: each Gaussian's blending weight summed over the frame's mask, in pixels
    (`label_lifting.accumulate_weights`)."""
    from avatarkit.recon.label_lifting import accumulate_weights

    return accumulate_weights(view.gaussians, view.camera, np.asarray(view.mask, np.int32), 2)[:, 1]


def frame_shows(view: FrameView, min_weight: float | None = None) -> np.ndarray:
    """(N,) bool: the Gaussians whose blending weight summed over the frame's mask is at least
    `min_weight` pixels (the renderer's compositing, `label_lifting.accumulate_weights`)."""
    min_weight = MIN_WEIGHT if min_weight is None else min_weight
    return frame_weights(view) >= min_weight


def _shows(view: FrameView, min_weight: float) -> np.ndarray:
    return view.shows if view.shows is not None and min_weight == MIN_WEIGHT else frame_shows(view, min_weight)


@dataclass
class FusedColours:
    """rgb (N, 3) float32 in [0, 1]; updated (N,) bool: the Gaussians the frames recoloured;
    info: JSON-able figures."""

    rgb: np.ndarray
    updated: np.ndarray
    info: dict = field(default_factory=dict)


def refine_colours_frames(views: list[FrameView], select: np.ndarray, iterations: int | None = None,
                          step: float = 1.0, min_weight: float | None = None,
                          background=None, hidden: float | None = None,
                          depth: float | None = None) -> FusedColours:
    """`recon.assemble.refine_colours` over several posed frames of the same Gaussians: each
    round renders every frame, takes the residual image - render inside its mask, per Gaussian
    that shows there (blending weight summed over the mask >= min_weight pixels) the residual
    averaged over about its own footprint (the blur scale matched to its projected radius);
    a selected Gaussian's update is the mean over the frames it shows in. Unselected Gaussians
    keep their colours. background: (3,) render background (None: each frame's median outside
    its mask); hidden: `HIDDEN_WEIGHT`, depth: `HIDDEN_DEPTH` (None: the module's): a frame
    where a Gaussian lies more than depth behind the render's depth at its projection gives it
    no update (and no count, with `HIDDEN_COUNT`). With one frame, every Gaussian selected,
    hidden and depth 0 this is refine_colours."""
    iterations = ITERATIONS if iterations is None else iterations
    min_weight = MIN_WEIGHT if min_weight is None else min_weight
    from avatarkit.recon.assemble import footprint_residuals, psnr
    from avatarkit.render import render

    if not views:
        raise ValueError("no frames to fuse")
    hidden = HIDDEN_WEIGHT if hidden is None else float(hidden)
    depth = HIDDEN_DEPTH if depth is None else float(depth)
    n = len(views[0].gaussians)
    select = np.asarray(select, bool).reshape(n)
    rgb = views[0].gaussians.colors.astype(np.float32).copy()
    prep = []
    for v in views:
        if len(v.gaussians) != n:
            raise ValueError("every frame must hold the same Gaussians")
        target = np.asarray(v.image, np.float32) / 255.0
        m = np.asarray(v.mask, bool)
        bg = (np.asarray(background, np.float32) if background is not None
              else np.median(target[~m], axis=0) if (~m).any() else np.zeros(3, np.float32))
        px, _ = v.camera.project(v.gaussians.means)
        shows = _shows(v, min_weight) & np.isfinite(px).all(axis=1) & select
        damp = None
        if hidden > 0:
            w = np.asarray(v.weights if getattr(v, "weights", None) is not None else frame_weights(v), np.float64)
            damp = (w / (w + hidden))[shows][:, None]
        prep.append(dict(v=v, m=m, target=target, bg=bg, px=px, shows=shows, level=None, damp=damp, scale=None))
    history = []
    for it in range(iterations + 1):
        num = np.zeros((n, 3))
        den = np.zeros(n)
        scores = []
        for p in prep:
            g = p["v"].gaussians.with_colors(rgb)
            r = render(g, p["v"].camera, background=p["bg"])
            scores.append(psnr(r.rgb, p["target"], p["m"]))
            sh = p["shows"]
            if it == iterations or not sh.any():
                continue
            if depth > 0 and p["scale"] is None:
                # the colours do not move the Gaussians: the first round's depths hold
                p["scale"] = (_depth_behind(r, sh) <= depth).astype(np.float64)
            delta, p["level"] = footprint_residuals(r.rgb, p["target"], p["m"], p["px"][sh],
                                                    r.meta["radii"][sh], p["level"])
            if p["damp"] is not None:
                delta = delta * p["damp"]
            if p["scale"] is not None:
                delta = delta * p["scale"][:, None]
            num[sh] += delta
            # a frame that does not see it (behind the surface) neither drives it nor counts
            den[sh] += p["scale"] if p["scale"] is not None and HIDDEN_COUNT else 1.0
        history.append(float(np.mean(scores)))
        if it == iterations or not (den > 0).any():
            break
        upd = den > 0
        rgb[upd] = np.clip(rgb[upd] + step * (num[upd] / den[upd, None]).astype(np.float32), 0.0, 1.0)
    updated = np.zeros(n, bool)
    for p in prep:
        # a frame that hides a Gaussian (HIDDEN_DEPTH) did not update it
        updated[p["shows"]] |= True if p["scale"] is None else p["scale"] > 0
    return FusedColours(rgb, updated, {"frames": len(views), "selected": int(select.sum()),
                                       "updated": int(updated.sum()),
                                       "psnr_before": round(history[0], 3), "psnr_after": round(history[-1], 3)})


def _depth_behind(r, idx: np.ndarray) -> np.ndarray:
    """(k,) metres: how far the Gaussians idx (bool (N,) or indices) lie behind the render r's
    depth (the alpha-weighted expected depth of what the pixel shows) at the pixel of their
    projected centre; 0 off the image or where the render is empty."""
    xy = np.asarray(r.meta["means2d"])[idx]
    z = np.asarray(r.meta["depths"], np.float64)[idx]
    h, w = r.depth.shape
    q = np.round(np.nan_to_num(xy, nan=-1.0)).astype(np.int64)
    ok = np.isfinite(xy).all(axis=1) & (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
    out = np.zeros(len(z))
    front = np.asarray(r.depth, np.float64)[q[ok, 1], q[ok, 0]]
    out[ok] = np.where(front > 0, z[ok] - front, 0.0)
    return out


def colour_frames(result, span: tuple[int, int] | None = None, count: int | None = None,
                  reference: int | None = None, max_turn: float | None = None) -> np.ndarray:
    """(K,) rows of a TrackResult to fuse: up to `count` (None: `FRAMES`) spread evenly over the
    eligible rows (those a keyframe may be: `keyframes.eligible_frames`, and, given the
    reference row, a head pose within `max_turn` (None: `MAX_TURN`) of its yaw / pitch) whose
    video frame is within span = [start, end) (None: all). The module's constants are read at
    the call, so setting them (a benchmark's switch) takes effect."""
    from avatarkit.track.keyframes import eligible_frames, yaw_pitch

    count = FRAMES if count is None else count
    max_turn = MAX_TURN if max_turn is None else max_turn

    frames = np.asarray(result.frame_index, np.int64)
    ok = eligible_frames(result)
    if span is not None:
        ok &= (frames >= span[0]) & (frames < span[1])
    if reference is not None:
        yp = yaw_pitch(clip_head_rotation(result.clip))
        ok &= np.linalg.norm(yp - yp[int(reference)], axis=1) <= max_turn
    rows = np.flatnonzero(ok)
    if len(rows) <= count:
        return rows
    return rows[np.unique(np.round(np.linspace(0, len(rows) - 1, count)).astype(np.int64))]


@dataclass
class StageSettings:
    """What the stage fuses and how often it refines: fuse_all (every bald Gaussian, not only
    REGIONS'), hair (the hair's Gaussians too), iterations (rounds of `refine_colours_frames`)."""

    fuse_all: bool
    hair: bool
    iterations: int


def stage_refine(refine: str | None) -> str | None:
    """The refinement the stage registers its frames with, from what a caller asked: None ->
    `REFINE` (read when called); "none" -> None, the landmark fit's poses (`avatarkit build
    --frame-refine none`: a caller has no other way to ask for them while `REFINE` is set)."""
    if refine is None:
        return REFINE
    return None if refine == "none" else refine


def stage_spacing(refine: str | None) -> int:
    """Every how many frames the stage's tracking refines with `refine`: REFINE_EVERY, or the
    setting's own spacing where that is sparser (`tracker.refine_spacing`: photometric-fast's
    5; session 17: against every 3rd, grey -0.04 / glasses +0.13 dB under evaluate's
    photometric-fast tracking, 2/3 of the time); 1 with no refinement."""
    from avatarkit.track.tracker import TrackOptions, refine_spacing

    if refine is None:
        return 1
    return max(int(REFINE_EVERY), refine_spacing(TrackOptions(refine=refine)))


def stage_settings(refine: str | None) -> StageSettings:
    """The stage's settings for frames posed by a tracking refined by `refine` (None: the
    landmark fit's poses): FUSE_ALL / FUSE_HAIR where set, else on exactly when the frames are
    registered; REGISTERED_ITERATIONS rounds then, ITERATIONS otherwise."""
    registered = refine is not None
    return StageSettings(registered if FUSE_ALL is None else bool(FUSE_ALL),
                         registered if FUSE_HAIR is None else bool(FUSE_HAIR),
                         REGISTERED_ITERATIONS if registered else ITERATIONS)


_UNSET = object()  # regions' default: REGIONS read at call time (None is a value: every Gaussian)


def fusion_selection(avatar, regions=_UNSET, hair: bool = False) -> np.ndarray:
    """(N_bald + N_hair,) bool: the bald Gaussians whose host triangle has at least two vertices
    in one of the head model's `regions` (None: every bald Gaussian), and with `hair` every hair
    Gaussian (`FUSE_HAIR`)."""
    regions = REGIONS if regions is _UNSET else regions
    nb = len(avatar.bald)
    sel = np.zeros(nb + len(avatar.hair), bool)
    sel[nb:] = hair
    if regions is None:
        sel[:nb] = True
        return sel
    model = avatar.head_model
    faces = np.asarray(model.faces)[np.asarray(avatar.bald.extras["binding"], np.int64)]
    for name in regions:
        if name in model.regions:
            sel[:nb] |= model.region_mask(name)[faces].sum(axis=1) >= 2
    return sel


def outline_band(person: np.ndarray, band: float | None = None) -> np.ndarray:
    """(H, W) bool: the pixels of `person` (H, W) bool within `band` of the image's larger side
    of its outline (a square erosion: max(|dx|, |dy|) <= r)."""
    band = OUTLINE_BAND if band is None else band
    import cv2

    r = max(1, int(round(band * max(person.shape))))
    inner = cv2.erode(person.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8),
                      borderType=cv2.BORDER_CONSTANT, borderValue=1).astype(bool)
    return person & ~inner


def outline_selection(views: list[FrameView], share: float | None = None,
                      min_weight: float | None = None) -> np.ndarray:
    """(N,) bool: the Gaussians whose projected centre lies in a frame's `outline` band in at
    least `share` of the frames where they show (blending weight summed over the frame's mask
    >= min_weight pixels). A head that moves by a pixel or two between frames swaps the wall
    and the hair / skin under these: the build frame's colour there is one sample of that."""
    share = OUTLINE_SHARE if share is None else share
    min_weight = MIN_WEIGHT if min_weight is None else min_weight
    n = len(views[0].gaussians)
    hits = np.zeros(n)
    seen = np.zeros(n)
    for v in views:
        if v.outline is None:
            continue
        shows = _shows(v, min_weight)
        px, _ = v.camera.project(v.gaussians.means)
        h, w = v.outline.shape
        ok = np.isfinite(px).all(axis=1)
        q = np.zeros((n, 2), np.int64)
        q[ok] = np.round(px[ok]).astype(np.int64)
        ok &= (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        inside = np.zeros(n, bool)
        inside[ok] = v.outline[q[ok, 1], q[ok, 0]]
        hits += inside & shows
        seen += shows
    return (seen > 0) & (hits >= share * np.maximum(seen, 1))


def posed_frames(avatar, result, rows, images: dict, masks: bool = True) -> list[FrameView]:
    """The avatar posed by the tracked clip (`result`: a TrackResult) at `rows` (static hair),
    each with its video frame (images: video frame number -> (H, W, 3) uint8) and the render's
    person mask (alpha > 0.5) eroded by MASK_ERODE px; masks False: the posed Gaussians alone
    (mask, outline, weights and shows None: what the frame hull's votes need)."""
    import cv2

    from avatarkit.render import render

    static, baked = _baked_rows(avatar, result, rows)
    kernel = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * MASK_ERODE + 1,) * 2) if MASK_ERODE else None)
    out = []
    for i, frame in zip(rows, baked):
        g = frame.person(static, avatar.has_hair)
        if not masks:
            out.append(FrameView(g, result.camera, images[int(result.frame_index[i])], None))
            continue
        person = render(g, result.camera, np.ones(3)).alpha > 0.5
        mask = cv2.erode(person.astype(np.uint8), kernel).astype(bool) if kernel is not None else person
        view = FrameView(g, result.camera, images[int(result.frame_index[i])], mask, outline_band(person))
        view.weights = frame_weights(view)
        view.shows = view.weights >= MIN_WEIGHT
        out.append(view)
    return out


def _baked_rows(avatar, result, rows):
    """(BakeStatic, [BakeFrame] per row): the avatar baked at the tracked clip's `rows`, the
    hair riding the head (no simulation: the frames are independent, only these are baked)."""
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.motion.clip import CHANNELS
    from avatarkit.sim.config import SimConfig

    rows = [int(r) for r in rows]
    clip = result.clip.replace(**{k: np.asarray(getattr(result.clip, k))[rows] for k in CHANNELS})
    static, baked = bake(avatar, clip, BakeConfig(sim=SimConfig(static=True)))
    return static, list(baked)


def bald_reposer(avatar, result, rows, images: dict):
    """pose() -> `posed_frames(avatar, result, rows, images, masks=False)` for the avatar's
    bald Gaussians as they are at the call (the frame hull's `recede` moves them between
    calls; nothing else of the avatar may change). The first call bakes; later calls keep its
    head meshes and hair (neither depends on the bald Gaussians) and pose only the bald ones
    again on the avatar's current binding, as the bake does (`binding_to_world` of the same
    head mesh): the same Gaussians, without the head model, the cage and the hair's deformation
    per frame again."""
    import dataclasses

    from avatarkit.baked import SplatFrame
    from avatarkit.rig.binding_kernel import binding_to_world

    kept: list = []

    def pose() -> list[FrameView]:
        if not kept:
            kept.append(_baked_rows(avatar, result, rows))
        static, baked = kept[0]
        static = dataclasses.replace(static, face=avatar.bald)
        binding = avatar.binding
        out = []
        for i, frame in zip(rows, baked):
            frame = dataclasses.replace(frame, face=SplatFrame(*binding_to_world(binding, frame.head_vertices)))
            out.append(FrameView(frame.person(static, avatar.has_hair), result.camera,
                                 images[int(result.frame_index[int(i)])], None))
        return out

    return pose


def fuse_frame_colours(avatar, video: str | os.PathLike, tracking, reference_frame: int,
                       span: tuple[int, int] | None = None, count: int | None = None, outline: bool | None = None,
                       refine: str | None = None, carve: bool | None = None):
    """The stage (module docstring) on a built `Avatar` of `video`: tracking is the template
    tracking the build chose its keyframes from (its face meshes are reused), reference_frame
    the frame the avatar was built from; outline: the outline's Gaussians are fused too;
    refine: the refinement that registers the fused frames (`TrackOptions.refine`; None:
    `REFINE`, photometric-fast; "none": the landmark fit's poses, as with `REFINE = None`),
    which sets what is fused (`stage_settings`) and how often the stage's tracking refines
    (`stage_spacing`);
    carve: first clear the Gaussians the frames show over the background (`track.frame_hull`;
    None: `frame_hull.CARVE`).
    Returns (the avatar with the fused colours, info). The video build runs it only when it has
    one keyframe (`track.video_build`)."""
    count = FRAMES if count is None else count
    outline = OUTLINE if outline is None else outline
    from avatarkit.avatar import load_avatar
    from avatarkit.track.build_pose import align_to_build
    from avatarkit.track.video import tracked_with_built_avatar

    from avatarkit.track.tracker import TrackOptions

    refine = stage_refine(refine)
    settings = stage_settings(refine)
    # the build's tracking's lens (the user's `BuildOptions.focal_mm`, else the assumed one)
    options = TrackOptions(refine=refine, refine_every=stage_spacing(refine), focal=float(tracking.camera.fx))
    with tracked_with_built_avatar(avatar, video, tracking.meshes, options) as (folder, result):
        align_to_build(result, folder, reference_frame)
        # the frames posed as `evaluate` and `track` will drive the avatar: the neck's colours
        # are fitted where the neck will be
        place_head(result, reference_frame, _neck.DEFAULT_HEAD_ON)
        saved = load_avatar(folder)
    ref = np.flatnonzero(np.asarray(result.frame_index) == reference_frame)
    rows = colour_frames(result, span, count, int(ref[0]) if len(ref) else None)
    select = fusion_selection(saved, None if settings.fuse_all else REGIONS, hair=settings.hair)
    if len(rows) == 0:
        return avatar, {"frames": [], "updated": 0}
    from avatarkit.track.keyframes import read_frames

    images = read_frames(video, np.asarray(result.frame_index)[rows])
    from avatarkit.track import frame_hull

    # the frame hull votes on the posed Gaussians alone (no render, no weights) and nearly always
    # changes them: the masks and weights the colours need are made after it, once
    hull = frame_hull.CARVE if carve is None else carve
    views = posed_frames(saved, result, rows, images, masks=not hull)
    carved = _carve(saved, avatar, views, hull)
    # the recession's rounds move only the bald Gaussians: the head meshes and the hair are baked once
    receded = _recede(saved, avatar, carved, bald_reposer(saved, result, rows, images))
    if (views[0].mask is None or (carved is not None and carved.cleared.any())
            or (receded is not None and receded.moved.any())):
        views = posed_frames(saved, result, rows, images)       # the masks without the cleared
    regions = int(select.sum())
    if outline:
        select = select | outline_selection(views)
    fused = refine_colours_frames(views, select, iterations=settings.iterations)
    nb = len(avatar.bald)
    rgb = np.where(fused.updated[:, None], fused.rgb, np.concatenate([avatar.bald.colors, avatar.hair.colors]))
    avatar.bald = avatar.bald.with_colors(rgb[:nb])
    if len(avatar.hair):
        avatar.hair = avatar.hair.with_colors(rgb[nb:])
    info = {**fused.info, "frames": [int(f) for f in np.asarray(result.frame_index)[rows]],
            "regions": None if settings.fuse_all else list(REGIONS), "hair": settings.hair, "in_regions": regions,
            "outline": bool(outline), "refine": refine, "refine_every": options.refine_every,
            "iterations": settings.iterations}
    if carved is not None:
        info["carved"] = carved.info
    if receded is not None:
        info["receded"] = receded.info
    return avatar, info


def _carve(saved, avatar, views, carve: bool | None):
    """`track.frame_hull.carve_frames` on the posed views when carve (None: `frame_hull.CARVE`):
    the cleared Gaussians' opacities set to 0 on both `saved` (what the views pose) and `avatar`
    (what the stage returns); only the hair's unless `frame_hull.BALD`. -> the `Carved`, or None
    when off."""
    from avatarkit.track import frame_hull

    if not (frame_hull.CARVE if carve is None else carve):
        return None
    nb = len(avatar.bald)
    allowed = None if frame_hull.BALD else np.arange(nb + len(avatar.hair)) >= nb
    # the neck recedes from the clothes: the segmentations' labels kept
    carved = frame_hull.carve_frames(views, allowed=allowed, labels=frame_hull.RECEDE and frame_hull.CLOTHES_NECK)
    for a in (saved, avatar):
        a.bald = a.bald.replace(opacities=np.where(carved.cleared[:nb], 0.0, a.bald.opacities).astype(np.float32))
        a.__dict__.pop("binding", None)     # the cached binding holds the old opacities: pose the new
        if len(a.hair):
            a.hair = a.hair.replace(opacities=np.where(carved.cleared[nb:], 0.0, a.hair.opacities).astype(np.float32))
    return carved


def _set_bald_means(avatar, means: np.ndarray) -> None:
    """The avatar's bald Gaussians moved to means (N, 3) in the rest pose; its cached triangle
    binding (what posing reads) is dropped so the next pose sees them."""
    avatar.bald = avatar.bald.replace(means=np.asarray(means, np.float32))
    avatar.__dict__.pop("binding", None)


def _recede(saved, avatar, carved, pose_views):
    """`track.frame_hull.recede` on the bald discs when `frame_hull.RECEDE` and the frame hull
    ran (`carved`, whose walls it votes with): pose_views() poses `saved` at the stage's frames;
    the moves are applied to both `saved` and `avatar`. -> the `Receded`, or None when off."""
    from avatarkit.track import frame_hull

    if carved is None or carved.walls is None or not frame_hull.RECEDE:
        return None
    nb = len(saved.bald)
    normals = frame_hull.inward_normals(saved.rest_head_vertices, saved.head_model.faces,
                                        saved.bald.extras["binding"])
    rest = np.asarray(saved.bald.means, np.float64)
    mine = np.asarray(avatar.bald.means, np.float64)

    def pose(offsets):
        _set_bald_means(saved, rest + offsets)
        return pose_views()

    other = other_walls = None
    if frame_hull.CLOTHES_NECK and carved.labels is not None:
        other = fusion_selection(saved, ("neck",))[:nb]
        other_walls = frame_hull.neck_walls(carved.labels)
    regions = frame_hull.RECEDE_REGIONS
    movable = np.ones(nb, bool) if regions is None else fusion_selection(saved, tuple(regions))[:nb]
    receded = frame_hull.recede(pose, carved.walls, normals, movable, other_walls=other_walls, other=other)
    _set_bald_means(saved, rest + receded.offsets)
    _set_bald_means(avatar, mine + receded.offsets)
    return receded


__all__ = ["FRAMES", "FrameView", "FusedColours", "ITERATIONS", "MASK_ERODE", "MAX_TURN",
           "FUSE_ALL", "FUSE_HAIR", "HIDDEN_WEIGHT", "HIDDEN_DEPTH", "HIDDEN_COUNT", "OUTLINE", "OUTLINE_BAND", "OUTLINE_SHARE", "REFINE", "REFINE_EVERY", "REGIONS",
           "REGISTERED_ITERATIONS", "StageSettings", "colour_frames", "stage_refine", "stage_spacing", "frame_shows", "frame_weights", "fuse_frame_colours",
           "fusion_selection", "outline_band", "stage_settings", "outline_selection", "posed_frames", "bald_reposer", "refine_colours_frames"]
