"""Build an avatar from a whole video (`avatarkit build VIDEO`): every keyframe the tracker saw.

Steps (`build_video_avatar`; each timed into the build report's `timings_s`):

    track      the video with the template head (or --head-model)      track.video
    keyframes  face sharpness of every frame; keyframes by head pose    track.keyframes
    plate      the wall behind the moving head, per pixel, from up to   track.background_plate
               64 tracked frames: the segmentation of the reference
               frame and of every keyframe takes it (`SEGMENT_PLATE`)
    identity   one identity shape and every keyframe's head pose over   track.joint_identity
               the keyframes' landmarks
    (build)    the portrait build of the reference keyframe (its own    recon.pipeline
               shape fit, as a single-frame build) with the keyframes   recon.multiview
               as extra views, registered by the joint fit's poses
    jaw_corrective  how this person's mouth opens beyond the head         track.jaw_corrective
               model's, learned from every tracked frame, added to the
               avatar's head model (its posedirs' jaw rows)
    frame_colours  (one keyframe only: a head that does not turn) the    track.frame_colours
               neck, lips, mouth interior and outline coloured from up
               to 24 tracked frames of the video

Where the head turns past what the face mesh follows (~50-60 degrees: the tracker loses the
face or its confidence collapses), the frame in the middle of each such stretch (one per side)
is registered by analysis by synthesis (`track.register`) against a first build from the
tracked keyframes, and the avatar is built again with those frames as extra keyframes
(`register_turned`).

With the hair's outline stage on (`recon.pipeline.FIT_HAIR_OUTLINE`), the turned keyframes are
registered against that first build too, and again against a second one built with those poses
(`refine_keyframes`, `SECOND_ROUND`): the outline stage measures their silhouettes at the poses
found (a fast turn's end is read a few degrees short by the landmarks without the face being lost).

A video whose head never turns gives one keyframe: the build is then the single-frame build of
that frame (`build VIDEO --frame N`) with the frame_colours stage after it, and the report says
so.
"""
from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

import numpy as np

from avatarkit.track.neck import clip_head_rotation
# a lost stretch is a turn beyond the tracking when a tracked frame beside it turned this much
# (`keyframes.TURNED_EDGE`, read at call time)
from avatarkit.track import keyframes as _keyframes

#: the video build's last stage colours the parts one frame cannot (`track.frame_colours`)
FRAME_COLOURS = True
#: the wall behind the moving head (`track.background_plate.video_plate`) is given to the
#: segmentation of the reference frame and of every keyframe (`recon.segment`, `plate=`): a
#: pixel matching it where it is well known is sure background (session 22, docs/video-build.md
#: "The wall behind the head")
SEGMENT_PLATE = True
#: the open mouth (`recon.mouth`: parted lips, teeth and a cavity) on the video build's avatar
#: where its frame_colours stage runs, just before it, so the stage colours the teeth and the
#: cavity from the frames that show them (a Gaussian no frame shows keeps the build's guess);
#: the single-frame build keeps `recon.pipeline.OPEN_MOUTH`. Off: on the shared clips' held-out
#: frames (session 16, docs/video-build.md) the video build with it scores grey -0.06 /
#: glasses +0.02 dB with `evaluate --refine photometric` (grey: the avatar's own refined
#: tracking reads the half-open jaw less open; on one tracking -0.006), -0.004 / -0.009 dB
#: without; grey's mouth box +0.15 dB, its wide-open frames (jaw > 0.2 rad) -0.16: the
#: template's lips part far less than the man's, so there is little opening to colour
OPEN_MOUTH = False
#: learn the subject's jaw corrective from the tracked frames (`track.jaw_corrective`;
#: `jaw_corrective=True` / `avatarkit build VIDEO --jaw-corrective` turns it on). Off: held out
#: on the shared clips (`evaluate --compare-single`, session 12) the guarded corrective gains
#: nothing on glasses (24.75 dB either way) and costs grey 0.02 dB and 0.49 px of the render's
#: landmark error (24.81 -> 24.79 dB, 2.49 -> 2.98 px), for ~9 s of build (docs/video-build.md)
JAW_CORRECTIVE = False

#: expression coefficients fitted per keyframe in the joint identity fit (the keyframes are
#: chosen neutral; a few absorb what is left of a smile)
IDENTITY_EXPR = 10
#: register the frames the tracker lost at a turn's ends against a first build (`register_turned`)
REGISTER_TURNED = True
#: the coarse yaw search spans this much (radians) before and beyond the last tracked yaw
SEARCH_BEFORE, SEARCH_BEYOND = math.radians(5.0), math.radians(55.0)
#: how a turned frame is registered: "plain" (`register.register_frame`: the colour error, the
#: whole pose searched) or "aligned" (`register.register_aligned`: each render laid over the
#: frame's silhouette by an image similarity first, so a first build of the wrong size or
#: centre still matches; docs/video-build.md, session 10)
#: Re-measured in session 18: "aligned" registers the held-out bob's -80 frame at -74 (plain -61)
#: and gains it +0.58 dB at +90, but costs the sample avatar 0.16 at -45 / -90 and the mesh
#: subject up to 0.09 (docs/video-build.md, "The profile on the other subjects")
REGISTER_MODE = "plain"
#: "plain" registration of a turned frame also searches its coarse yaws with the head shifted to
#: fit (`register.register_frame(shifted=True)`), and keeps whichever refinement ends lower. The
#: person turns about the neck, so a frame turned far from the guess shows the head centimetres
#: from the guess's position; the plain grid (at that position) then started the refinement in a
#: basin short of the true yaw: the held-out bob's -80-degree frame registered at -61 (seed 0)
#: against its draft, whose best error over the rest of the pose is at -76. Shifted: -74.6 (seed
#: 1: -59.9 -> -67.6), the bob +0.53 / +0.24 dB at +90 (seeds 0 / 1), its worst view -0.06 (-90,
#: seed 0); the sample avatar (seeds 0, 1), the mesh subject and the whip build as before, the
#: sample avatar at seed 2 +0.13 at -45 and -0.10 at -90 (its +80 frame a degree further) (session
#: 20, docs/video-build.md, "The bob's hair"). ~2-3x the renders of the turned frames' search
REGISTER_SHIFTED = True
#: the first build's Gaussian counts at most (it is only rendered, at `register.SIZE` pixels)
FIRST_BUILD_COUNTS = (8000, 4000)
#: the tracked keyframes' poses the hair's outline stage (`recon.hair_outline`) measures their
#: silhouettes with: "tracked" (the joint fit's), "registered" (each keyframe turned at least
#: `REFINE_MIN_YAW` registered against the draft build, `refine_keyframes`, for that stage only),
#: "registered-edge" (as "registered", and the keyframes at the tracking's edge and the frames
#: registered at the turns' ends take their registered pose for every stage) or "registered-all"
#: (the registered pose for every stage). The joint fit reads a fast turn's end a few degrees short
#: without losing the face (the 32-frame whip clip: 4-9 degrees), and the outline stage takes the
#: silhouette's disagreement for hair. The tracking's edge frames are read 5-10 degrees off (the
#: eased clip's sample avatar: +39.0 / -43.3 for a true +48.8 / -33.8; registered +49.3 / -35.3),
#: and their colours, hair votes and silhouette bound came from those poses. "registered-edge"
#: (session 15), against "registered": the eased clip's sample avatar +0.18..+0.46 dB at +90 and
#: +0.12..+0.22 at -90 (three seeds), fronts +0.04..+0.06; the mesh subject -0.14..+0.15 and the
#: held-out bob -0.14..+0.72 (two seeds); the whip -0.01..+0.20. "registered-all" also moves the
#: whip's keyframes turned 30-40 degrees: its sample avatar lost 0.68 dB at +90 at seed 1 (its
#: hair's labels flipped; docs/video-build.md, "Every stage sees the tracking's edge at its
#: registered pose"). Re-measured after session 17's fix of that flip (session 18): the eased
#: clip builds the same (mesh subject within 0.04 dB), the whip's sample avatar +0.00..+0.14, its
#: mesh subject -0.20 at -90 ("The profile on the other subjects")
OUTLINE_POSES = "registered-edge"
#: keyframes turned less than this (radians, the joint fit's yaw from the reference's) keep the
#: joint fit's pose: nearer the front the landmarks read the yaw as well as the draft does (eased
#: clip: the -17-degree keyframe's fit exact, registered 2 degrees off; whip: the +15-degree one's
#: fit 0.6 off, registered 1.1, and refining it cost the sample avatar 0.18 dB at -45)
REFINE_MIN_YAW = math.radians(25.0)
#: the refinement's yaw search spans this much (radians) before and beyond the tracked yaw
REFINE_BEFORE, REFINE_BEYOND = math.radians(6.0), math.radians(14.0)
#: the refinement searches the first this many of yaw, pitch, roll, tx, ty, tz (`register.REFINE_STEPS`;
#: the rest stay the joint fit's)
REFINE_SEARCH = 6
#: a refined yaw this close (radians) to its search's end is at the bound: not trusted
#: (`refine_keyframes`; the hair's outline stage skips the keyframe when `SKIP_AT_BOUND`)
BOUND_TOLERANCE = math.radians(0.3)
SKIP_AT_BOUND = True
#: the frames registered at the turns' ends (`register_turned`) are refined too, from their pose
#: (the whip's -42-degree end frame: registered at -36.6, refined -40.6; +45 +0.13 dB)
REFINE_TURNED = True
#: the longer side (pixels) `refine_keyframes` compares at (`register.SIZE`). 192 (the synthetic
#: clips' full size) reads the whip's +50-degree end frame 2.5 degrees nearer the truth and takes
#: its -45 loss away, but on the eased clip the +-80 frames' poses then take up the hair's missing
#: outline (the sample avatar's profile -0.97 / -0.90 dB): the draft's thin hair biases the pose
REFINE_SIZE = 96
#: a second round (None: none): a draft built with the registered poses (its outline fitted), and
#: the poses registered again against it at this many pixels. The first round's draft has the thin
#: outline the stage is to fix, and at 96 px the whip's +50-degree end frame stays 3 degrees short
#: (-45: -0.33 / -0.39 dB at two seeds); against a draft whose outline is fitted, at 192 px, it
#: reads 48.6 (true 49.6) and the whip's losses go (worst -0.04); the eased clip keeps its gains
#: (docs/video-build.md, "Keyframe poses the outline can trust")
SECOND_ROUND = 192
#: the draft the keyframes are registered against fits the hair's outline too (True) or not
DRAFT_OUTLINE = False
#: the registrations whose yaw is found with the draft's hair discounted (`register.register_frame(
#: discount_hair=True)`: each pixel's colour error weighted by the share of the render that is not
#: hair, the rest of the pose then searched at that yaw by the plain error, and the plain pose kept
#: unless that yaw is turned further by `register.HAIR_GATE`): "turned" (the frames at the turns'
#: ends, `register_turned`) and "refine" (`refine_keyframes`, both rounds). The draft's hair is
#: lifted from one photo and is its least faithful layer; where it lies off the frame's (the mesh
#: subject's wedge over the temples, strands where a short cap lies flat) the pose that matches it
#: is short of the truth: the mesh subject's turned keyframes all registered ~15 % short (eased
#: clip, seed 0: the +80-degree end at +68 relative, true +83.7), as short against a draft built
#: with every keyframe at its true yaw, +71 against the truth's own surface with the draft's hair
#: (session 24, docs/video-build.md, "The turned frames' yaw without the draft's hair"). Off (()):
#: both on, the mesh subject's profile gain rises +2.59 -> +2.76, +2.86 -> +3.06, +2.77 -> +3.00
#: (seeds 0 / 1 / 2), no view of it more than 0.02 below main's (the sample avatar's builds and
#: both whip builds are main's to the digit), but the held-out bob, whose keyframes it moves toward the truth,
#: loses 0.39 / 0.42 dB at -45 / -90 (seed 0) and 0.28 at -45 (seed 1), and on the cluttered wall
#: (where the plain registration already reads the turn ends long) the mesh subject's -90 0.70;
#: ~2.6x the registrations' time. A stage `SKIN_POSE` names ("refine", by default) keeps the plain
#: pose for its keyframes' `pose` whatever this says: turn that off to move every use of the pose
HAIR_DISCOUNT = ()
#: the registrations whose keyframes carry a second pose, for the bald layer (`multiview.Keyframe.
#: skin_pose`): "turned" (`register_turned`), "refine" (`refine_keyframes`, both rounds). Each is
#: registered as `HAIR_DISCOUNT` registers it (the yaw searched with the draft's hair discounted,
#: `register.HAIR_GATE`), and the plain search's pose stays the keyframe's pose (or `outline_pose`)
#: for everything the hair is made from (its labels' votes, hull, outline, directions, colours),
#: while the gated pose, where the gate takes the discounted one, colours the bald layer. The draft
#: is lifted from one photo: its hair, the least faithful layer, pulls a turned frame's plain pose
#: to where the draft's hair matches, and the hair the build lays on agrees with that pose; the
#: skin agrees with the pose found without the hair. A stage named here is not discounted by
#: `HAIR_DISCOUNT` too: its keyframes' `pose` is the plain search's. Session 25 (docs/video-build.md,
#: "Each layer coloured from the pose that registers it"): the mesh subject's profile gain +2.59 ->
#: +2.66, +2.86 -> +2.93, +2.77 -> +2.88 (seeds 0 / 1 / 2), no view of it more than 0.01 below
#: main's; the held-out bob (seed 0) +0.09 at +90, -0.01 at the front, seed 1 main's to the digit;
#: the sample avatar (seeds 0, 1) and both whip builds main's to the digit (no skin pose taken); on
#: the cluttered wall the mesh subject main's, the sample avatar +0.11 / +0.12 at +-90. The
#: registrations it names run the plain and the discounted search; the shared real clips have
#: one keyframe and register nothing. () turns it off. "turned" is left
#: out: with `REFINE_TURNED` the refine rounds register the turned frames again and decide their
#: skin pose, and the drafts keep the plain poses (`multiview.SKIN_POSE_IN_DRAFTS`), so the turned
#: stage's skin pose is never used: the builds with ("turned", "refine") are the same to the bit
#: (mesh subject and bob, seed 0) without the turned frames' double search (the mesh subject's
#: register stage, one process: off 45.7 s, ("turned", "refine") 137.6 s, ("refine",) 100.5 s)
SKIN_POSE = ("refine",)
#: the registrations that composite the draft's render over the video's wall plate
#: (`register.plate_background`: the plate's colour where it knows a wall unlike the frame's border,
#: the border's colour elsewhere) instead of over the border's colour: "turned"
#: (`register_turned`), "refine" (`refine_keyframes`, both rounds). On a busy wall the flat colour
#: leaves the poster and the post beside the head to be explained by the head's pose, and the wall
#: dominates the error (the sample avatar on the cluttered wall, seed 0: its -80 turn end's error
#: against the first draft 43.6-44.8e-3 at every yaw, flat within 3 %, registered at -30; over the
#: plate 11.3e-3 at the true yaw, 15.5 at -20; session 26, docs/video-build.md "The turn ends over
#: the wall"). A plain wall's plate adds nothing and the registration is the flat one, to the bit
#: (the white, dark and colour walls' builds are main's to the digit). On the cluttered wall the
#: turn ends register within 9 degrees of the truth (main: 50 and 24 off): the sample avatar's
#: +-90 views +1.51 / +1.27 dB (seed 0), +1.15 / +1.58 (seed 1); the bob +0.74 / +0.90 at +-90 but
#: -0.50 at -45 (seed 0; seed 1 -0.34), the mesh subject within -0.20..+0.31. Off: ()
REGISTER_PLATE = ("turned", "refine")
#: a frame at a turn's end whose registered yaw lies at its own search's end (`BOUND_TOLERANCE` of
#: the range `register_turned` searched, `TurnedFrame.lo` / `hi`) is no minimum: the draft prefers a
#: pose outside what was searched. "keep" (use it as any other), "far" (not a keyframe at the far
#: end; kept at the near end), "drop" (not a keyframe at either end), "beyond" (at the far end:
#: searched once more over the next `SEARCH_BEYOND` beyond it, dropped if that ends at a bound too;
#: at the near end dropped). The near end is kept: a fast turn's end lies a few degrees past its
#: tracked edge, and the whip clip's sample avatar registers its -46 end there (dropped: -0.96 dB at
#: +45). Over the border colour the cluttered wall's +80 end went to its far end (+98.8, 32.7 degrees
#: of pitch): dropped ("far"), the sample avatar's -90 view +0.65 dB (seed 0); but the bob's two
#: turn ends, both at their far ends (10 and 20 degrees long), dropped cost it 1.65 / 1.74 dB at
#: +-90: a pose a little long still colours the side it shows. Over the plate (`REGISTER_PLATE`) no
#: build measured ends at a bound. Off ("keep") (session 26, docs/video-build.md)
TURNED_AT_BOUND = "keep"


@dataclasses.dataclass
class TurnedFrame:
    """A frame to register: clip_index (its row of the tracking); edge: the tracked row beside
    the lost stretch that turned most; lo, hi: the yaws (radians) the coarse search spans."""

    clip_index: int
    edge: int
    lo: float
    hi: float


def turned_frames(result, yaw) -> list[TurnedFrame]:
    """The frames to register (module docstring): stretches of frames not eligible as keyframes
    (`keyframes.eligible_frames`) with a tracked frame beside them turned at least `TURNED_EDGE`
    (yaw (T,) radians, the tracked yaw); per side (left, right) the longest such stretch (ties:
    the one whose edge turned most); its middle frame."""
    from avatarkit.track.keyframes import eligible_frames, ineligible_stretches

    ok = eligible_frames(result)
    T = len(ok)
    best: dict[int, tuple[float, TurnedFrame]] = {}
    for a, t in ineligible_stretches(ok):
        edges = [e for e in (a - 1, t) if 0 <= e < T and ok[e]]
        if not edges:
            continue
        e = max(edges, key=lambda i: abs(yaw[i]))
        y = float(yaw[e])
        if abs(y) < _keyframes.TURNED_EDGE:
            continue
        side = 1 if y > 0 else -1
        far = side * (abs(y) + SEARCH_BEYOND)
        near = side * (abs(y) - SEARCH_BEFORE)
        cand = TurnedFrame((a + t - 1) // 2, e, min(near, far), max(near, far))
        # the longest stretch: the head stayed out of the tracking's reach longest there (a short
        # dropout on the way, with a turned edge, is no turn beyond it: on the bob subject one at
        # -26 degrees was taken over the stretch at the -80 pause)
        if side not in best or (t - a, abs(y)) > best[side][0]:
            best[side] = ((t - a, abs(y)), cand)
    return [best[k][1] for k in sorted(best)]


def joint_identity(result, keyframes, size: tuple[int, int]):
    """`track.joint_identity.JointFit` over the keyframes of a TrackResult (its model's
    identity coefficients, at most `recon.fit.FLAME_SHAPE_COMPONENTS` of a FLAME model)."""
    from avatarkit.face.fit import LandmarkModel
    from avatarkit.recon.fit import FLAME_SHAPE_COMPONENTS
    from avatarkit.track.joint_identity import fit_joint_identity, targets_from_points
    from avatarkit.track.solve import FrameProblem
    from avatarkit.track.tracker import model_embedding

    model = result.model
    emb = model_embedding(model)
    lm = LandmarkModel(model, emb)
    S = model.num_shape if model.name == "template" else min(model.num_shape, FLAME_SHAPE_COMPONENTS)
    problem = FrameProblem.from_landmark_model(lm, np.zeros(model.num_shape), min(IDENTITY_EXPR, model.num_expr),
                                               shape_components=S)
    idx = keyframes.clip_index
    targets = [targets_from_points(result.landmarks[t], emb, size) for t in idx]
    focal = float(result.camera.fx)
    return fit_joint_identity(problem, targets, focal, result.raw["rotation"][idx],
                              result.raw["translation"][idx], np.asarray(result.clip.shape, np.float64)[:S])


class StageCount:
    """The video build's progress told as one count: the registration before the portrait
    build's stages, the jaw corrective and the frame colours after them, so a progress line
    never reads "[14/14]" after "[13/13]". progress(stage, index, total, seconds): the portrait
    build's callback (seconds None when a stage starts); before / after: the extra stages'
    names, in order, that this build will run."""

    def __init__(self, progress, before: tuple[str, ...] = (), after: tuple[str, ...] = ()):
        from avatarkit.recon.pipeline import STAGES

        self.progress = progress
        self.before, self.after = tuple(before), tuple(after)
        self.total = len(self.before) + len(STAGES) + len(self.after)

    def portrait(self, stage: str, index: int, total: int, seconds) -> None:
        """The portrait build's callback, its index shifted past the stages told before it."""
        if self.progress is not None:
            self.progress(stage, index + len(self.before), self.total, seconds)

    def extra(self, stage: str, seconds) -> None:
        """One of the video build's own stages (`before` or `after`) starting or done."""
        if self.progress is None:
            return
        from avatarkit.recon.pipeline import STAGES

        if stage in self.before:
            index = self.before.index(stage) + 1
        else:
            index = len(self.before) + len(STAGES) + self.after.index(stage) + 1
        self.progress(stage, index, self.total, seconds)


def build_tracking(video: str | os.PathLike, options, progress: Callable[[int, int], None] | None = None):
    """The tracking the video build chooses its keyframes from (`BuildOptions`' head model)."""
    from avatarkit.track.tracker import TrackOptions
    from avatarkit.track.video import track_video

    return track_video(video, head_model=options.head_model, landmark_embedding=options.landmark_embedding,
                       options=TrackOptions(face_index=options.face_index or 0, focal_mm=options.focal_mm),
                       progress=progress)


def build_video_avatar(video: str | os.PathLike, options=None, *, keyframes: int | None = None,
                       progress=None, track_progress: Callable[[int, int], None] | None = None,
                       tracking=None, colour_span: tuple[int, int] | None = None,
                       register: bool | None = None, jaw_corrective: bool | None = None,
                       colour_refine: str | None = None, frame_colours: bool | None = None,
                       frame_hull: bool | None = None):
    """The Avatar built from the whole video (module docstring). options: `BuildOptions`;
    keyframes: at most this many (default `track.keyframes.KEYFRAMES`); progress: the portrait
    build's stage callback; track_progress(done, total) per tracked frame; tracking: the
    `TrackResult` of `build_tracking(video, options)` when the caller has it already
    (`evaluate` reuses its face meshes), else the video is tracked here. The provenance gets
    `source_video` {video, frame (the reference), keyframes, mode, colour_frames}. colour_span:
    [start, end) video frames the frame_colours stage may use (None: the whole video;
    `avatarkit evaluate` keeps the second half of the clip out of the build). register: register
    the frames the tracker lost at a turn's ends and fuse them as keyframes (`register_turned`;
    None: `REGISTER_TURNED`; `avatarkit build --no-register` passes False). jaw_corrective:
    learn the subject's jaw corrective (`track.jaw_corrective`; None: `JAW_CORRECTIVE`;
    `--no-jaw-corrective` passes False), from the frames in colour_span too; the provenance's
    `source_video.jaw_corrective` says what it learned. colour_refine: the refinement that
    registers the frame_colours stage's frames (`frame_colours.fuse_frame_colours(refine=)`;
    None: `frame_colours.REFINE`; "none": the landmark fit's poses; `avatarkit evaluate
    --refine` passes its own, `avatarkit build --frame-refine` the user's). frame_colours: run
    that stage where the video has one keyframe (None: `FRAME_COLOURS`; `--no-frame-colours`
    passes False); frame_hull: the stage's frames first clear the hair they show over the
    background and move the bald surface there inward (`fuse_frame_colours(carve=)`; None:
    `frame_hull.CARVE`; `--no-frame-hull`)."""
    from avatarkit.recon.multiview import Keyframe, VideoViews, pose_matrix
    from avatarkit.recon.pipeline import BuildOptions, build_avatar
    from avatarkit.track.keyframes import (KEYFRAMES, choose_keyframes, read_frames, tracking_edge, video_sharpness,
                                           yaw_pitch)

    options = options or BuildOptions()
    options.check()
    video = os.fspath(video)
    timings = {}
    result = tracking
    if result is None:
        t0 = time.perf_counter()
        result = build_tracking(video, options, track_progress)
        timings["track"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sharp = video_sharpness(video, result)
    kf = choose_keyframes(result, sharp, KEYFRAMES if keyframes is None else int(keyframes))
    images = read_frames(video, kf.frame_index)
    timings["keyframes"] = time.perf_counter() - t0
    plate = None
    if SEGMENT_PLATE:
        from avatarkit.track.background_plate import video_plate

        t0 = time.perf_counter()
        plate = video_plate(video, result)
        timings["plate"] = time.perf_counter() - t0
    ref_frame = int(kf.frame_index[0])
    # the frames whose tracked yaw is likely under-read (none where the face is never lost)
    edge = [int(f) for f in np.asarray(result.frame_index)[tracking_edge(result)]]
    source = {"video": os.path.abspath(video), "frame": ref_frame, "mode": "video",
              "keyframes": kf.summary(), "tracking_edge": edge}
    if plate is not None:
        source["plate"] = plate.summary()
    views = None
    if len(kf) > 1:
        t0 = time.perf_counter()
        size = (result.camera.width, result.camera.height)
        jf = joint_identity(result, kf, size)
        shape = np.zeros(result.model.num_shape)
        shape[:len(jf.shape)] = jf.shape
        timings["identity"] = time.perf_counter() - t0
        views = VideoViews(shape, [Keyframe(images[int(f)], pose_matrix(jf.rotation[k], jf.translation[k]),
                                            float(kf.sharpness[k]), int(f))
                                   for k, f in enumerate(kf.frame_index)],
                           {"keyframes": [int(f) for f in kf.frame_index],
                            "identity_median_error_px": [round(float(e), 3) for e in jf.median_error_px],
                            "identity_shape": [round(float(c), 4) for c in jf.shape],
                            "tracking_edge": edge}, plate)
    else:
        source["mode"] = "single frame (the head does not turn: one keyframe)"
    with tempfile.TemporaryDirectory(prefix="avatarkit-frame-") as tmp, _frame_errors(tmp, video, ref_frame):
        from avatarkit.export.images import write_png

        png = Path(tmp) / f"frame{ref_frame}.png"
        write_png(png, images[ref_frame])
        if options.name is None:
            options.name = Path(video).stem
        turned = []
        if views is not None and (REGISTER_TURNED if register is None else register):
            turned = turned_frames(result, yaw_pitch(clip_head_rotation(result.clip))[:, 0])
        jaw = JAW_CORRECTIVE if jaw_corrective is None else jaw_corrective
        fuse = (FRAME_COLOURS if frame_colours is None else frame_colours) and len(kf) == 1
        # the registration (a first build and a few hundred renders) told before the portrait
        # build's stages, the jaw corrective and the frame colours after them
        count = StageCount(progress, ("register",) if turned else (),
                           ("jaw_corrective",) * bool(jaw) + ("frame_colours",) * bool(fuse))
        if turned:
            count.extra("register", None)
            t0 = time.perf_counter()
            first = dataclasses.replace(options, n_bald=min(options.n_bald, FIRST_BUILD_COUNTS[0]),
                                        n_hair=min(options.n_hair, FIRST_BUILD_COUNTS[1]), preview=False)
            # the draft does not fit the hair's outline when the keyframes' poses are to be
            # registered against it: fitted to a keyframe read a few degrees short, its outline
            # matches that pose, and the registration confirms it (the whip clip)
            refine = OUTLINE_POSES != "tracked" and _outline_on()
            # the drafts' views carry info["draft"] (`multiview.DRAFT_SCALP_FILL`)
            draft = build_avatar(png, first, None,
                                 views=dataclasses.replace(views, info={**views.info, "draft": True,
                                                                        **({"fit_outline": False} if refine and DRAFT_OUTLINE is False else {})}),
                                 plate=plate)
            # no face crop to measure a registered frame's sharpness on: the keyframes' median
            added, figures = register_turned(draft, result, turned, views, video, float(np.median(kf.sharpness)))
            views.keyframes.extend(added)
            views.info["registered"] = figures
            source["registered"] = figures
            if refine:
                tracked = len(views.keyframes) if REFINE_TURNED else len(kf)
                # "registered-edge": the frames at the tracking's edge (the landmarks read them 5-10
                # degrees off) and those registered at the turns' ends (`register_turned`'s coarser
                # search against the first draft) take the pose found for every stage
                everywhere = {"registered-all": True,
                              "registered-edge": frozenset(edge) | {k.frame for k in added}}.get(OUTLINE_POSES, False)
                # a second round (SECOND_ROUND): a draft whose outline the first round's poses
                # fitted, and every pose registered again against it at that many pixels
                for size in (None, SECOND_ROUND) if SECOND_ROUND else (None,):
                    if size is not None:
                        draft = build_avatar(png, first, None, views=dataclasses.replace(views, info={**views.info, "draft": True}),
                                             plate=plate)
                    refined = refine_keyframes(draft, views, tracked, everywhere=everywhere, size=size)
                    views.info["refined"] = refined
                    if SKIP_AT_BOUND:
                        views.info["untrusted_poses"] = [f["frame"] for f in refined if f["at_bound"]]
                source["refined"] = refined
            timings["register"] = time.perf_counter() - t0
            count.extra("register", timings["register"])
        elif views is not None and OUTLINE_POSES != "tracked" and _outline_on():
            # no draft to register the keyframes against (the tracker lost no turn): a keyframe
            # turned past REFINE_MIN_YAW keeps the joint fit's pose, which a fast turn reads a few
            # degrees short (the whip clip, unregistered: -0.98 dB at +45), so the hair's outline
            # does not measure with it
            views.info["untrusted_poses"] = unregistered_turned(views)
        avatar = build_avatar(png, options, count.portrait if progress is not None else None, views=views,
                              plate=plate)
    if jaw:
        from avatarkit.head.jaw_corrective import apply_jaw_corrective
        from avatarkit.track.jaw_corrective import fit_avatar_corrective

        count.extra("jaw_corrective", None)
        t0 = time.perf_counter()
        # the frames the colours may come from: `evaluate` holds the clip's second half out
        learned = fit_avatar_corrective(avatar, video, result, span=colour_span)
        if learned.corrective is not None:
            avatar.head_model = apply_jaw_corrective(avatar.head_model, learned.corrective)
        timings["jaw_corrective"] = time.perf_counter() - t0
        count.extra("jaw_corrective", timings["jaw_corrective"])
        source["jaw_corrective"] = learned.figures
    if fuse:
        # only when the head does not turn: with turned keyframes the views colour the sides, and
        # refitting the neck and mouth to the near-frontal frames cost the synthetic turning
        # video's sides up to 0.21 dB (docs/video-build.md)
        from avatarkit.track.frame_colours import fuse_frame_colours

        count.extra("frame_colours", None)
        t0 = time.perf_counter()
        if OPEN_MOUTH:
            avatar, source["open_mouth"] = _open_mouth(avatar, result, images[ref_frame], ref_frame)
        avatar, fused = fuse_frame_colours(avatar, video, result, ref_frame, span=colour_span, refine=colour_refine,
                                           carve=frame_hull)
        timings["frame_colours"] = time.perf_counter() - t0
        count.extra("frame_colours", timings["frame_colours"])
        avatar.provenance["build"]["frame_colours"] = fused
        if options.preview:
            # the portrait build rendered its previews before the stage changed the colours
            from avatarkit.recon.pipeline import attach_previews

            attach_previews(avatar, options.preview_size)
        source["colour_frames"] = fused["frames"]
    avatar.provenance["source_video"] = source
    avatar.provenance["source_image"] = f"{os.path.abspath(video)} (frame {ref_frame})"
    build = avatar.provenance["build"]
    build["timings_s"] = {**{k: round(v, 3) for k, v in timings.items()}, **build["timings_s"]}
    build["total_s"] = round(sum(build["timings_s"].values()), 3)
    return avatar


@contextmanager
def _frame_errors(folder: str, video: str, frame: int):
    """An error the portrait build raises about the reference keyframe's PNG in the temporary
    `folder` names the video and the frame instead ("clip.mp4 (frame 50): face is too small"):
    the PNG is gone when the user reads the message."""
    from avatarkit.errors import AvatarKitError

    try:
        yield
    except AvatarKitError as e:
        if e.path is None or not os.path.abspath(e.path).startswith(os.path.abspath(folder) + os.sep):
            raise
        err = type(e)(e.message, f"{video} (frame {frame})")
        raise err from e.__cause__


def _open_mouth(avatar, result, image: np.ndarray, ref_frame: int):
    """The open mouth on the built avatar before the frame_colours stage (`OPEN_MOUTH`), its
    teeth's guess from the reference frame when it shows teeth -> (avatar, info). Nothing when
    the portrait build opened it already (`recon.pipeline.OPEN_MOUTH`)."""
    from avatarkit.recon import pipeline
    from avatarkit.recon.mouth import inner_lips, open_avatar_mouth, photo_teeth_colour

    if pipeline.OPEN_MOUTH:
        return avatar, {"by": "recon.pipeline"}
    row = np.flatnonzero(np.asarray(result.frame_index) == ref_frame)
    meshes = result.meshes or []
    mesh = meshes[int(row[0])] if len(row) and int(row[0]) < len(meshes) else None
    return open_avatar_mouth(avatar, photo_teeth_colour(image, inner_lips(mesh)))


def turned_guess(result, edge: int, reference: int, reference_pose) -> np.ndarray:
    """(4, 4) the search's starting pose for a frame lost beyond the tracked row `edge`: the
    reference keyframe's pose (the joint fit's: the frame the registration works in) turned
    about the vertical by the yaw the tracking measured between the reference row and the edge
    row. The head turns in place and about the vertical: the tracker's pitch, roll and depth
    near the edge are not to be trusted (on the eased 80-degree turn at 192 px the edge rows
    read up to 14 degrees of pitch and 7 cm of depth that the head never had)."""
    from avatarkit.track.keyframes import yaw_pitch
    from avatarkit.track.register import params_from_pose, pose_from_params

    yaw = yaw_pitch(np.asarray(result.raw["rotation"])[[edge, reference]])[:, 0]
    p = params_from_pose(reference_pose)
    p[0] += yaw[0] - yaw[1]
    return pose_from_params(p)


def _outline_on() -> bool:
    from avatarkit.recon import pipeline

    return bool(pipeline.FIT_HAIR_OUTLINE)


def unregistered_turned(views) -> list[int]:
    """The frames of views' keyframes (not the reference) turned at least `REFINE_MIN_YAW` from the
    reference keyframe that have no registered `outline_pose`."""
    from avatarkit.track.register import params_from_pose

    ref = params_from_pose(views.keyframes[0].pose)[0]
    return [k.frame for k in views.keyframes[1:]
            if k.outline_pose is None and abs(params_from_pose(k.pose)[0] - ref) >= REFINE_MIN_YAW]


def refine_keyframes(draft, views, tracked: int, everywhere: bool | frozenset = False,
                     size: int | None = None) -> list[dict]:
    """Register (`register.register_frame`) each tracked keyframe but the reference (the first
    `tracked` of views.keyframes) turned at least `REFINE_MIN_YAW` against `draft`, starting from
    its pose (the joint fit's, or a previous round's), the yaw searched from `REFINE_BEFORE` short
    of it to `REFINE_BEYOND` beyond. The pose found goes to the keyframe's `outline_pose`
    (everywhere: True, or a set of video frames holding the keyframe's: its `pose`, for every
    stage). Returns per keyframe refined {frame, yaw_deg (its pose's), registered_deg, error,
    renders, at_bound}, the yaws relative to the reference keyframe's."""
    from avatarkit.render.camera import Camera
    from avatarkit.track.register import REFINE_STEPS, head_rows, params_from_pose, pose_camera, register_frame

    gs = draft.rest_gaussians()
    camera = Camera.from_dict(draft.provenance["build"]["camera"])
    ref = views.keyframes[0]
    regions = draft.head_model.regions
    neck = draft.head_model.region_mask("neck") if "neck" in regions else None
    figures = []
    for k in views.keyframes[1:tracked]:
        # the yaw relative to the reference keyframe's (the frame the draft is built in)
        p = params_from_pose(k.pose)
        y = p[0] - params_from_pose(ref.pose)[0]
        if abs(y) < REFINE_MIN_YAW:
            continue
        side = 1.0 if y > 0 else -1.0
        near, far = p[0] - side * REFINE_BEFORE, p[0] + side * REFINE_BEYOND
        above = head_rows(draft.rest_head_vertices, neck, pose_camera(camera, ref.pose, k.pose))
        split = "refine" in SKIN_POSE
        reg = register_frame(gs, k.image, camera, ref.pose, k.pose, (min(near, far), max(near, far)),
                             size=size or REFINE_SIZE, steps=REFINE_STEPS[:REFINE_SEARCH], above=above,
                             discount_hair="refine" in HAIR_DISCOUNT or split, keep_plain=split,
                             plate=views.plate if "refine" in REGISTER_PLATE else None)
        pose, skin = _split_poses(reg, split)
        found = params_from_pose(pose)[0]
        # a yaw at the search's end is no minimum: the draft prefers a pose beyond what was
        # searched, and neither pose is to be trusted (the whip clip's keyframe at a true 38
        # degrees went to the near end, 29)
        bounded = at_bound(found, min(near, far), max(near, far), side) is not None
        if everywhere is True or (everywhere is not False and k.frame in everywhere):
            k.pose = pose
        else:
            k.outline_pose = pose
        if split:
            # this round's registration decides: a later round whose gate keeps the plain pose
            # leaves the bald layer to the keyframe's pose
            k.skin_pose = skin
        figures.append({"frame": k.frame, "yaw_deg": round(float(np.degrees(y)), 2),
                        "registered_deg": round(float(np.degrees(found - p[0] + y)), 2),
                        "error": round(reg.error, 5), "renders": reg.evaluations, "at_bound": bool(bounded),
                        "over_plate": reg.over_plate})
        if split:
            figures[-1]["skin_deg"] = None if skin is None else \
                round(float(np.degrees(params_from_pose(skin)[0] - p[0] + y)), 2)
    return figures


def _split_poses(reg, split: bool):
    """(pose, skin_pose) of a registration: with `SKIN_POSE`'s split, the plain search's pose and
    the gated one where the gate took the hair-discounted pose (else None: the bald layer takes
    the keyframe's pose too); without, (reg.pose, None)."""
    if not split or reg.plain_pose is None:
        return reg.pose, None
    return reg.plain_pose, (reg.pose if reg.discounted else None)


def register_turned(draft, result, turned: list[TurnedFrame], views, video, sharpness: float):
    """Keyframes for the `turned` frames, registered (`register.register_frame`) against
    `draft`, the avatar built from the tracked keyframes `views` (the reference first: its
    pose relates the draft's camera to the tracker's poses). Returns (keyframes, figures)."""
    from avatarkit.recon.multiview import Keyframe
    from avatarkit.render.camera import Camera
    from avatarkit.track.keyframes import read_frames
    from avatarkit.track.register import (head_rows, params_from_pose, pose_camera, register_frame,
                                          register_aligned)

    gs = draft.rest_gaussians()
    camera = Camera.from_dict(draft.provenance["build"]["camera"])
    ref = views.keyframes[0]
    ref_row = int(np.flatnonzero(np.asarray(result.frame_index) == ref.frame)[0])
    frames = [int(result.frame_index[t.clip_index]) for t in turned]
    images = read_frames(video, frames)
    regions = draft.head_model.regions
    neck = draft.head_model.region_mask("neck") if "neck" in regions else None
    out, figures = [], []
    for t, f in zip(turned, frames):
        guess = turned_guess(result, t.edge, int(ref_row), ref.pose)
        above = head_rows(draft.rest_head_vertices, neck, pose_camera(camera, ref.pose, guess))
        split = "turned" in SKIN_POSE and REGISTER_MODE == "plain"

        def search(start, yaws):
            return register_frame(gs, images[f], camera, ref.pose, start, yaws, above=above,
                                  shifted=REGISTER_SHIFTED, discount_hair="turned" in HAIR_DISCOUNT or split,
                                  keep_plain=split, plate=views.plate if "turned" in REGISTER_PLATE else None)

        if REGISTER_MODE == "plain":
            reg = search(guess, (t.lo, t.hi))
        else:
            centre = draft.rest_head_vertices[~neck].mean(0) if neck is not None else draft.rest_head_vertices.mean(0)
            reg = register_aligned(gs, images[f], camera, ref.pose, guess, (t.lo, t.hi), centre, above=above)
        pose, skin = _split_poses(reg, split)
        # the range the search used (its yaw is the pose's own decomposition, as the search's;
        # the tracker's yaw of the same rotation differs by ~0.2 degree)
        end = at_bound(params_from_pose(pose)[0], t.lo, t.hi, 1.0 if t.hi > 0 else -1.0)
        renders = reg.evaluations
        if end == "far" and TURNED_AT_BOUND == "beyond" and REGISTER_MODE == "plain":
            side = 1.0 if t.hi > 0 else -1.0
            lo, hi = sorted((t.hi if side > 0 else t.lo, (t.hi if side > 0 else t.lo) + side * SEARCH_BEYOND))
            reg = search(pose, (lo, hi))
            pose, skin = _split_poses(reg, split)
            renders += reg.evaluations
            end = at_bound(params_from_pose(pose)[0], lo, hi, side)
        y, p, _ = np.degrees(params_from_pose(pose)[:3])
        figures.append({"frame": f, "yaw_deg": round(float(y), 2), "pitch_deg": round(float(p), 2),
                        "error": round(reg.error, 5), "renders": renders, "at_bound": end,
                        "over_plate": reg.over_plate})
        if split:
            figures[-1]["skin_yaw_deg"] = None if skin is None else round(float(np.degrees(params_from_pose(skin)[0])), 2)
        if (end is not None and TURNED_AT_BOUND in ("drop", "beyond")) or (end == "far" and TURNED_AT_BOUND == "far"):
            figures[-1]["dropped"] = True
            continue
        out.append(Keyframe(images[f], pose, sharpness, f, skin_pose=skin))
    return out, figures


def at_bound(yaw: float, lo: float, hi: float, side: float) -> str | None:
    """Whether a yaw (radians) found by a search over [lo, hi] lies at one of its ends
    (`BOUND_TOLERANCE`): "near" (the end nearer the front for a turn to `side`, +1 / -1), "far",
    or None."""
    tol = BOUND_TOLERANCE
    near, far = (lo, hi) if side > 0 else (hi, lo)
    if abs(yaw - far) < tol:
        return "far"
    if abs(yaw - near) < tol:
        return "near"
    return None


__all__ = ["StageCount", "BOUND_TOLERANCE", "FIRST_BUILD_COUNTS", "FRAME_COLOURS", "HAIR_DISCOUNT", "SKIN_POSE", "REGISTER_PLATE", "TURNED_AT_BOUND", "SEGMENT_PLATE", "IDENTITY_EXPR", "JAW_CORRECTIVE", "DRAFT_OUTLINE", "OPEN_MOUTH", "OUTLINE_POSES", "REFINE_BEFORE",
           "REFINE_BEYOND", "REFINE_MIN_YAW", "REFINE_SEARCH", "REFINE_SIZE", "REFINE_TURNED", "REGISTER_SHIFTED", "REGISTER_TURNED", "SEARCH_BEFORE", "SECOND_ROUND", "SKIP_AT_BOUND", "SEARCH_BEYOND",
           "TurnedFrame",
           "at_bound", "build_tracking", "build_video_avatar", "joint_identity", "refine_keyframes", "register_turned", "turned_frames", "unregistered_turned",
           "turned_guess"]
