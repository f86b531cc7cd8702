"""The frames' silhouettes bound the avatar: Gaussians the video build's colour frames show over
the background are cleared (`carve`), a visual hull made of the frame_colours stage's frames.

A single-frame build takes its outline from one photo: the head model's jaw and cheeks, the ears
and the hair's shell are as wide as that frame's fit and lifting made them, and a pixel or two of
pose or shape error puts the render's outline over the wall. On the shared clips' held-out frames
(session 17, docs/video-build.md "The outline on the talking clips") the render covers the
wall (the video's person segmentation says background) on 1.4-1.6 % of the scored pixels, 10-15 %
of the squared error, most of it within 3 px of the person's outline, on the hair, the ears and
the jaw.

The frame_colours stage poses the avatar at up to `frame_colours.FRAMES` frames of the video
(registered to about half a pixel when its tracking is refined). Each frame's person mask
(`person_masks`: `recon.segment`, the portrait build's segmentation, dilated by `MARGIN` px: the
segmentation's and the registration's error) says where the person is not: the wall. Per frame
a Gaussian votes "outside" when at least `SHARE` of its blending weight in that frame
(`recon.label_lifting.accumulate_weights`: the renderer's compositing) falls on the wall; a
Gaussian seen in at least `MIN_FRAMES` frames that at least `QUORUM` of them vote outside is
cleared (opacity 0: it keeps its place in the rig). Clearing exposes what was behind it, so the
votes are taken again, `ROUNDS` times. One frame that disagrees (a segmentation's slip, a frame
whose head moved) clears nothing: the frames vote.

The bald head is one layer of discs: clearing its outline leaves a hole a side view looks through
(`BALD` off). Its discs are moved instead (`recede`, `RECEDE`): a disc the frames vote outside
moves a millimetre inward along its triangle's normal, and the frames vote again on the moved
head, up to `RECEDE_ROUNDS` times. The neck's discs take the clothes as wall too
(`CLOTHES_NECK`): the head model's neck draws over the collar, which the person mask calls person.

Only the video build uses the frames; the single-frame build stays the baseline. `CARVE` turns it
on in the frame_colours stage (`frame_colours.fuse_frame_colours`), before the colours are fused
so the Gaussians it exposes get the frames' colours. `evaluate` scores the render's mask, so a
bound that shrinks the head always scores better: the settings were chosen by the silhouette's
disagreement both ways (the render over the wall, the person the render misses), not by the
score (docs/video-build.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: clear the Gaussians the colour frames show over the background in the frame_colours stage.
#: On (session 17, docs/video-build.md "The outline on the talking clips"): the shared clips'
#: held-out frames, each build tracked with itself, +0.11 / +0.11 dB with `evaluate --refine
#: photometric` (grey's lead over the single-frame build +0.89 -> +1.00, glasses +1.16 -> +1.28)
#: and +0.44 / +0.43 dB with the default tracking; the synthetic talking avatar +2.40 / +1.42 dB,
#: its render's mask brought from 34.9 % of the frame to 33.5 % (the true head's: 33.4-33.8 %)
CARVE = True
#: the bald set's Gaussians may be cleared too. Off: the bald head is one layer of discs on the
#: head mesh, so clearing the discs on its outline (an ear, the side of the head a frontal frame
#: sees edge-on over the wall) leaves a hole a side view looks through (the grey clip's default
#: build showed one by the ear at the profile); the hair is a volume, and clearing its outer
#: strands exposes hair or scalp. Only the hair is cleared (session 17, lead's review; default
#: evaluate --compare-single: grey +0.87, glasses +1.27 dB over the single-frame build, against
#: +0.93 / +1.25 with the bald discs cleared too; docs/video-build.md)
BALD = False
#: the bald set's discs the colour frames show over the wall are moved inward instead (`recede`):
#: along their host triangle's inward normal, `STEP` metres a round, `RECEDE_ROUNDS` rounds at
#: most, each round voting as `carve` does on the frames posed with the moves so far. The head
#: stays one closed layer (a side view sees the moved discs face on, a few millimetres deeper)
#: while its outline in the frames comes inside the person. On, with `CLOTHES_NECK` (session 18,
#: docs/video-build.md "The grey clip's last tenth of a decibel"; evaluate --compare-single, the
#: video build alone): grey 27.423 -> 27.747, glasses 28.567 -> 28.722, the synthetic talking
#: avatar 29.196 -> 30.109 (its mask 34.8 -> 33.8 % of the frame, the true head's 33.1-33.8 %);
#: without CLOTHES_NECK (the wall only: ears, jaw) grey +0.046 but glasses -0.038
RECEDE = True
#: the head model's regions whose bald discs recede (a disc whose host triangle has two vertices
#: in one); None: every bald disc
RECEDE_REGIONS = None
#: metres a voted bald disc moves inward per round (about a pixel of a 480 px talking-head frame)
STEP = 0.001
#: rounds of `recede` (at most RECEDE_ROUNDS x STEP metres inward; 5 rounds: grey 27.712 against
#: 3's 27.747)
RECEDE_ROUNDS = 3
#: with RECEDE, the neck's discs (the head model's "neck" region) recede from the clothes too: for
#: them the wall is everything but the frames' skin and hair (`recon.segment`'s labels: the
#: background and the body/clothes). The avatar's neck draws over the collar where the video
#: shows the clothes, which the person mask calls person (`neck_walls`): the largest part of the
#: talking clips' outline error (session 17). On (see RECEDE): the neck's discs alone, grey
#: +0.288, glasses +0.140; with the rest of the bald head receding from the wall +0.324 / +0.155
CLOTHES_NECK = True
#: the person mask is dilated by this many pixels before the wall is taken (the segmentation's
#: outline and the frames' registration are each good to about a pixel)
MARGIN = 1
#: a frame votes a Gaussian outside when this share of its blending weight there is on the wall
SHARE = 0.3
#: a Gaussian is cleared when this share of the frames it shows in vote it outside ...
QUORUM = 0.3
#: ... and it shows in at least this many frames
MIN_FRAMES = 3
#: rounds of votes (each round sees what the last one exposed)
ROUNDS = 2
#: a Gaussian shows in a frame when its blending weight summed over the frame is at least this
#: many pixels (as `frame_colours.MIN_WEIGHT`)
MIN_WEIGHT = 0.05


@dataclass
class Carved:
    """cleared (N,) bool: the Gaussians to clear; info: JSON-able figures (per round the count
    cleared, the frames that voted)."""

    cleared: np.ndarray
    info: dict = field(default_factory=dict)
    #: per view the wall image that voted (None: that frame did not), when `carve_frames` made them
    walls: list | None = None
    #: per view the segmentation's labels ((H, W) uint8, `recon.segment`) when `carve_frames` was
    #: asked for them, else None
    labels: list | None = None


def wall_image(person: np.ndarray, margin: int | None = None) -> np.ndarray:
    """(H, W) int32: 1 where the frame shows no person (`person` (H, W) bool dilated by `margin`
    px, an elliptic disc), 0 elsewhere: the label image `accumulate_weights` bins by."""
    margin = MARGIN if margin is None else margin
    import cv2

    p = np.asarray(person, np.uint8)
    if margin > 0:
        p = cv2.dilate(p, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1,) * 2))
    return (p == 0).astype(np.int32)


def wall_votes(gaussians, camera, wall: np.ndarray, share: float | None = None,
               min_weight: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One frame's votes: (shows (N,) bool: blending weight summed over the frame >= min_weight
    pixels, outside (N,) bool: shows, and at least `share` of that weight on the `wall` (H, W)
    int32 label image's 1s)."""
    share = SHARE if share is None else share
    min_weight = MIN_WEIGHT if min_weight is None else min_weight
    from avatarkit.recon.label_lifting import accumulate_weights

    return _votes(accumulate_weights(gaussians, camera, wall, 2), share, min_weight)


def _votes(w: np.ndarray, share: float, min_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """`wall_votes` from the (N, 2) float32 weights off / on the wall."""
    w = w.astype(np.float64)
    total = w.sum(axis=1)
    shows = total >= min_weight
    return shows, shows & (w[:, 1] >= share * total)


def wall_votes_pair(gaussians, camera, wall: np.ndarray, other: np.ndarray, share: float | None = None,
                    min_weight: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`wall_votes` with `wall` and with `other` (both (H, W) int32 0 / 1) from one compositing
    pass (4 labels: wall + 2 other; each wall's two weights are the sums of two of them, in
    float64 before the cast to float32 as `accumulate_weights` casts): (shows, outside,
    shows_other, outside_other). The weights are the same sums of the same pixels' terms as
    two passes give, added in another order (float64; the kernel's atomics add in no fixed
    order either)."""
    share = SHARE if share is None else share
    min_weight = MIN_WEIGHT if min_weight is None else min_weight
    from avatarkit.recon.label_lifting import accumulate_view, check_label_image

    both = check_label_image(np.asarray(wall, np.int32) + 2 * np.asarray(other, np.int32), camera, 4)
    w = accumulate_view(gaussians, camera, both, 4)[0]                       # (N, 4) float64
    mine = np.stack([w[:, 0] + w[:, 2], w[:, 1] + w[:, 3]], 1).astype(np.float32)
    theirs = np.stack([w[:, 0] + w[:, 1], w[:, 2] + w[:, 3]], 1).astype(np.float32)
    return (*_votes(mine, share, min_weight), *_votes(theirs, share, min_weight))


def carve(views, walls: list, rounds: int | None = None, share: float | None = None, quorum: float | None = None,
          min_frames: int | None = None, allowed: np.ndarray | None = None) -> Carved:
    """The Gaussians the frames show over the wall (module docstring). views: posed frames with
    `.gaussians` (N, the same order in each) and `.camera` (`frame_colours.FrameView`); walls:
    per view an (H, W) int32 `wall_image`, or None (that frame does not vote); allowed: (N,)
    bool, the Gaussians that may be cleared (None: all)."""
    rounds = ROUNDS if rounds is None else rounds
    share = SHARE if share is None else share
    quorum = QUORUM if quorum is None else quorum
    min_frames = MIN_FRAMES if min_frames is None else min_frames
    if len(views) != len(walls):
        raise ValueError("one wall image per view")
    n = len(views[0].gaussians) if views else 0
    cleared = np.zeros(n, bool)
    allowed = np.ones(n, bool) if allowed is None else np.asarray(allowed, bool).reshape(n)
    per_round = []
    voting = sum(w is not None for w in walls)
    for _ in range(rounds):
        seen, out = _tally(views, walls, cleared, share)
        new = allowed & ~cleared & _voted(seen, out, min_frames, quorum)
        per_round.append(int(new.sum()))
        if not new.any():
            break
        cleared |= new
    return Carved(cleared, {"frames": int(voting), "cleared": per_round, "total": int(cleared.sum())})


def _voted(seen: np.ndarray, out: np.ndarray, min_frames: int, quorum: float) -> np.ndarray:
    """(N,) bool: shown in at least min_frames frames, and at least quorum of them vote outside."""
    return (seen >= min_frames) & (out >= quorum * np.maximum(seen, 1))


def _tally(views, walls: list, cleared: np.ndarray | None, share: float,
           near: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Over the views whose wall is not None: (seen (N,): frames the Gaussian shows in, out (N,):
    frames that vote it outside), the `cleared` (N,) bool Gaussians drawn with opacity 0. With
    `near` (pixels), a frame counts a Gaussian as shown only where its centre lies within `near`
    of its render's outline (`near_outline`) or it votes it outside."""
    n = len(views[0].gaussians) if views else 0
    seen = np.zeros(n)
    out = np.zeros(n)
    for v, wall in zip(views, walls):
        if wall is None:
            continue
        g = v.gaussians
        if cleared is not None and cleared.any():
            g = g.replace(opacities=np.where(cleared, 0.0, g.opacities).astype(np.float32))
        shows, outside = wall_votes(g, v.camera, wall, share)
        if near is not None:
            # a frame that puts a Gaussian over its wall sees it at its outline whatever the
            # distance of its centre (a large disc); one that shows it well inside does not count
            shows = shows & (near_outline(g, v.camera, near) | outside)
        seen += shows
        out += outside
    return seen, out


def near_outline(gaussians, camera, pixels: float) -> np.ndarray:
    """(N,) bool: the Gaussians whose centre projects within `pixels` of the render's outline as
    `camera` sees them all (the distance from the centre's pixel to the nearest pixel the render
    leaves at alpha <= 0.5; 0 on and beyond the outline); False behind the camera or outside the
    image. Where a frame sees a disc face on, well inside the outline, its silhouette cannot tell
    whether the disc stands out of the surface: only the frames that see it at their outline can."""
    from scipy import ndimage

    from avatarkit.render import render

    covered = np.asarray(render(gaussians, camera, (0.0, 0.0, 0.0)).alpha) > 0.5      # (H, W)
    dist = ndimage.distance_transform_edt(covered)                                     # (H, W) px
    px, z = camera.project(np.asarray(gaussians.means, np.float64))
    px = np.asarray(px, np.float64)
    h, w = covered.shape
    ok = np.isfinite(px).all(axis=1) & (np.asarray(z) > 0)
    ok &= (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    ix = np.clip(np.floor(np.where(ok[:, None], px, 0)).astype(np.int64), 0, [w - 1, h - 1])
    return ok & (dist[ix[:, 1], ix[:, 0]] <= pixels)


def _tally_lead(views, walls: list, share: float, near_share: float, near: float, lead: list):
    """`recede`'s tally with lead frames, over the views whose wall is not None: (seen, out) as
    `_tally` without `near`; (seen_near, out_near) as `_tally` with it, voting at `near_share`;
    led: the lead frames voting outside at `near_share`. All (N,) float64."""
    from avatarkit.recon.label_lifting import accumulate_weights

    n = len(views[0].gaussians) if views else 0
    seen, out, seen_near, out_near, led = (np.zeros(n) for _ in range(5))
    for v, wall, first in zip(views, walls, lead):
        if wall is None:
            continue
        w = accumulate_weights(v.gaussians, v.camera, wall, 2)               # (N, 2) off / on the wall
        shows, outside = _votes(w, share, MIN_WEIGHT)
        _, outside_near = _votes(w, near_share, MIN_WEIGHT)
        seen += shows
        out += outside
        seen_near += shows & (near_outline(v.gaussians, v.camera, near) | outside_near)
        out_near += outside_near
        if first:
            led += outside_near
    return seen, out, seen_near, out_near, led


def _tally_pair(views, walls: list, other_walls: list, share: float):
    """`_tally(views, walls)` and `_tally(views, other_walls)` (nothing cleared) in one pass
    per view where both walls are given (`wall_votes_pair`): (seen, out, seen_other,
    out_other)."""
    n = len(views[0].gaussians) if views else 0
    seen, out, seen2, out2 = (np.zeros(n) for _ in range(4))
    for v, wall, other in zip(views, walls, other_walls):
        if wall is not None and other is not None:
            a, b, c, d = wall_votes_pair(v.gaussians, v.camera, wall, other, share)
            seen += a
            out += b
            seen2 += c
            out2 += d
        elif wall is not None:
            a, b = wall_votes(v.gaussians, v.camera, wall, share)
            seen += a
            out += b
        elif other is not None:
            c, d = wall_votes(v.gaussians, v.camera, other, share)
            seen2 += c
            out2 += d
    return seen, out, seen2, out2


@dataclass
class Receded:
    """offsets (M, 3) float64: each movable Gaussian's move in the rest pose (metres; 0 for the
    unmoved); moved (M,) bool; info: JSON-able figures (per round the count moved)."""

    offsets: np.ndarray
    moved: np.ndarray
    info: dict = field(default_factory=dict)


def inward_normals(vertices: np.ndarray, faces: np.ndarray, face_ids: np.ndarray) -> np.ndarray:
    """(M, 3) float64 unit normals of the host triangles `faces[face_ids]` of the mesh
    `vertices` (V, 3), turned to point into the mesh: the side the mesh's area-weighted normals
    point away from its centroid is out (one sign for the whole mesh, whatever its winding)."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    tri = v[f]                                                   # (F, 3, 3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])   # (F, 3), |.| = 2 area
    outward = np.einsum("fk,fk->", cross, tri.mean(axis=1) - v.mean(axis=0)) >= 0
    n = cross[np.asarray(face_ids, np.int64)]
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    return -n if outward else n


def recede(pose, walls: list, normals: np.ndarray, movable: np.ndarray, step: float | None = None,
           rounds: int | None = None, share: float | None = None, quorum: float | None = None,
           min_frames: int | None = None, other_walls: list | None = None,
           other: np.ndarray | None = None, near: float | None = None, lead: list | None = None,
           near_share: float | None = None, near_min_frames: int = 1, lead_rounds: int | None = None) -> Receded:
    """The movable Gaussians the frames show over the wall moved inward (module docstring):
    pose(offsets (M, 3)) -> the views (as `carve`'s, their first M Gaussians the movable set's
    M, moved by `offsets` in the rest pose); walls: per view an (H, W) int32 `wall_image` or
    None; normals (M, 3): unit directions to move along (`inward_normals`); movable (M,) bool;
    other (M,) bool: these vote with `other_walls` (per view, as walls) instead.
    Each round the views are posed with the moves so far and vote as in `carve`; a Gaussian
    voted outside moves `step` (None: `STEP`) further along its normal, `rounds` (None:
    `RECEDE_ROUNDS`) times at most. near (pixels, None: every frame that shows a Gaussian): a
    frame counts a Gaussian as shown only where its centre lies within `near` of that frame's
    render outline (`near_outline`) or it votes it outside (not with `other`).
    lead (per view bool, only with near): the frames whose votes `near` counts. A Gaussian then
    moves as the frames vote without `near` (every frame that shows it, `min_frames`, `share`), or
    when one of the lead frames votes it outside at `near_share` (None: `share`) and so do
    `quorum` of the frames that show it near their outline or vote it outside (at least
    `near_min_frames`): the frames that see it face on hold a Gaussian only against the others;
    lead_rounds (None: `rounds`): the rounds the lead frames' votes move Gaussians in, the rounds
    past `rounds` theirs only."""
    if near is not None and other is not None:
        raise ValueError("recede: near= is not taken with other=")
    if lead is not None and (near is None or len(lead) != len(walls)):
        raise ValueError("recede: lead= needs near= and one flag per view")
    share = SHARE if share is None else share
    quorum = QUORUM if quorum is None else quorum
    min_frames = MIN_FRAMES if min_frames is None else min_frames
    step = STEP if step is None else float(step)
    rounds = RECEDE_ROUNDS if rounds is None else int(rounds)
    normals = np.asarray(normals, np.float64)
    m = len(normals)
    movable = np.asarray(movable, bool).reshape(m)
    other = None if other is None or other_walls is None else np.asarray(other, bool).reshape(m)
    offsets = np.zeros((m, 3))
    moved = np.zeros(m, bool)
    per_round = []
    lead_rounds = rounds if lead is None or lead_rounds is None else max(int(lead_rounds), rounds)
    for r in range(lead_rounds):
        views = pose(offsets)
        if other is not None and other.any():
            # one compositing pass per frame for both walls (`_tally_pair`; two `_tally`s give the same)
            seen, out, seen2, out2 = _tally_pair(views, walls, other_walls, share)
            seen, out = np.where(other, seen2[:m], seen[:m]), np.where(other, out2[:m], out[:m])
        elif lead is not None:
            seen, out, seen_near, out_near, led = (t[:m] for t in _tally_lead(
                views, walls, share, share if near_share is None else near_share, near, lead))
            quorum_moves = _voted(seen, out, min_frames, quorum) if r < rounds else np.zeros(m, bool)
            new = movable & (quorum_moves
                             | ((led >= 1) & _voted(seen_near, out_near, near_min_frames, quorum)))
        else:
            seen, out = _tally(views, walls, None, share, near=near)
            seen, out = seen[:m], out[:m]
        if lead is None:
            new = movable & _voted(seen, out, min_frames, quorum)
        per_round.append(int(new.sum()))
        if not new.any():
            break
        offsets[new] += step * normals[new]
        moved |= new
    return Receded(offsets, moved, {"moved": per_round, "total": int(moved.sum()),
                                    "deepest": float(np.linalg.norm(offsets, axis=1).max(initial=0.0))})


def person_masks(images: list) -> list:
    """Per image ((H, W, 3) uint8) the person mask ((H, W) bool) of the portrait build's
    segmentation (`recon.segment.segment_person`: `segment_portrait`'s person without its hair
    step; the face found by `recon.portrait.analyze_portrait`), or None where no face is found.
    ~2 s a 480 px frame on a loaded 2-vCPU machine: most of the stage's added time."""
    from avatarkit.recon.segment import segment_person

    return _each_segmented(images, segment_person)


def person_labels(images: list) -> list:
    """Per image ((H, W, 3) uint8) the portrait build's segmentation's labels ((H, W) uint8:
    `recon.segment` BACKGROUND, SKIN, HAIR, BODY; `segment_portrait`, ~30 % dearer than
    `person_masks`), or None where no face is found."""
    from avatarkit.recon.segment import segment_portrait

    return _each_segmented(images, lambda image, analysis: segment_portrait(image, analysis).labels)


#: threads the frames are segmented on (None: one per core, as the Taichi kernels use:
#: `AVATARKIT_THREADS` or the CPU count). GrabCut, most of a segmentation's time, runs in
#: OpenCV without the GIL, and each segmentation seeds its own thread's OpenCV RNG
#: (`recon.segment._working_copy`), so each frame's labels are the same on any thread
SEGMENT_THREADS: int | None = None


def _each_segmented(images: list, segment, threads: int | None = None) -> list:
    """Per image segment(image, its `analyze_portrait` with the face front end's "auto"
    detector), or None where the analysis or the segmentation finds no face (AvatarKitError).
    The analyses run here, one after another (the face front end's interpreters are shared);
    the segmentations on `threads` threads (None: `SEGMENT_THREADS`), one frame each, in any
    order: each is a function of its own image and analysis alone. threads=1 is the plain
    loop (`_each_segmented_serial`)."""
    from avatarkit._taichi import _threads

    threads = SEGMENT_THREADS if threads is None else threads
    threads = min(len(images), _threads() if threads is None else int(threads))
    if threads <= 1:
        return _each_segmented_serial(images, segment)
    from concurrent.futures import ThreadPoolExecutor

    from avatarkit.errors import AvatarKitError
    from avatarkit.recon.portrait import analyze_portrait

    def one(image, analysis):
        try:
            return segment(image, analysis)
        except AvatarKitError:
            return None

    analyses = []
    for image in images:
        try:
            analyses.append(analyze_portrait(image, None, detector="auto"))
        except AvatarKitError:
            analyses.append(None)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        jobs = [None if a is None else pool.submit(one, image, a) for image, a in zip(images, analyses)]
        return [None if j is None else j.result() for j in jobs]


def _each_segmented_serial(images: list, segment) -> list:
    """`_each_segmented` one frame after another on this thread."""
    from avatarkit.errors import AvatarKitError
    from avatarkit.recon.portrait import analyze_portrait

    out = []
    for image in images:
        try:
            out.append(segment(image, analyze_portrait(image, None, detector="auto")))
        except AvatarKitError:
            out.append(None)
    return out


def neck_walls(labels: list, margin: int | None = None) -> list:
    """Per view (labels (H, W) uint8 or None) the wall the neck recedes from (`CLOTHES_NECK`):
    everything but skin and hair, as `wall_image` makes it (the skin and hair dilated by
    `margin`), or None."""
    margin = MARGIN if margin is None else margin
    from avatarkit.recon.segment import HAIR, SKIN

    return [None if lab is None else wall_image(np.isin(lab, (SKIN, HAIR)), margin) for lab in labels]


def carve_frames(views, margin: int | None = None, labels: bool = False, **kwargs) -> Carved:
    """`carve` with each view's wall from its own image's segmentation (`person_masks`; with
    labels, `person_labels`' non-background, the same masks, kept in the result)."""
    margin = MARGIN if margin is None else margin
    images = [v.image for v in views]
    labs = person_labels(images) if labels else None
    masks = person_masks(images) if labs is None else [None if lab is None else lab != 0 for lab in labs]
    walls = [None if m is None else wall_image(m, margin) for m in masks]
    out = carve(views, walls, **kwargs)
    out.walls = walls
    out.labels = labs
    return out


__all__ = ["BALD", "CARVE", "CLOTHES_NECK", "Carved", "MARGIN", "MIN_FRAMES", "MIN_WEIGHT", "QUORUM", "RECEDE", "RECEDE_REGIONS", "RECEDE_ROUNDS",
           "ROUNDS", "SEGMENT_THREADS", "Receded", "SHARE", "STEP", "carve", "carve_frames", "inward_normals", "near_outline", "neck_walls", "person_labels", "person_masks", "recede",
           "wall_image", "wall_votes", "wall_votes_pair"]
