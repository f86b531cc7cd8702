"""Build an avatar from a whole video (`avatarkit build VIDEO`): every keyframe the tracker saw.

Steps (`build_video_avatar`; each timed into the build report's `timings_s`):

    track      the video with the template head (or --head-model)      track.video
    keyframes  face sharpness of every frame; keyframes by head pose    track.keyframes
    identity   one identity shape and every keyframe's head pose over   track.joint_identity
               the keyframes' landmarks
    (build)    the portrait build of the reference keyframe (its own    recon.pipeline
               shape fit, as a single-frame build) with the keyframes   recon.multiview
               as extra views, registered by the joint fit's poses
    frame_colours  (one keyframe only: a head that does not turn) the    track.frame_colours
               neck, lips, mouth interior and outline coloured from up
               to 24 tracked frames of the video

A video whose head never turns gives one keyframe: the build is then the single-frame build of
that frame (`build VIDEO --frame N`) with the frame_colours stage after it, and the report says
so.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

#: the video build's last stage colours the parts one frame cannot (`track.frame_colours`)
FRAME_COLOURS = True

#: expression coefficients fitted per keyframe in the joint identity fit (the keyframes are
#: chosen neutral; a few absorb what is left of a smile)
IDENTITY_EXPR = 10


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


def build_tracking(video: str | os.PathLike, options, progress: Callable[[int, int], None] | None = None):
    """The tracking the video build chooses its keyframes from (`BuildOptions`' head model)."""
    from avatarkit.track.tracker import TrackOptions
    from avatarkit.track.video import track_video

    return track_video(video, head_model=options.head_model, landmark_embedding=options.landmark_embedding,
                       options=TrackOptions(face_index=options.face_index or 0), progress=progress)


def build_video_avatar(video: str | os.PathLike, options=None, *, keyframes: int | None = None,
                       progress=None, track_progress: Callable[[int, int], None] | None = None,
                       tracking=None, colour_span: tuple[int, int] | None = None):
    """The Avatar built from the whole video (module docstring). options: `BuildOptions`;
    keyframes: at most this many (default `track.keyframes.KEYFRAMES`); progress: the portrait
    build's stage callback; track_progress(done, total) per tracked frame; tracking: the
    `TrackResult` of `build_tracking(video, options)` when the caller has it already
    (`evaluate` reuses its face meshes), else the video is tracked here. The provenance gets
    `source_video` {video, frame (the reference), keyframes, mode, colour_frames}. colour_span:
    [start, end) video frames the frame_colours stage may use (None: the whole video;
    `avatarkit evaluate` keeps the second half of the clip out of the build)."""
    from avatarkit.recon.multiview import Keyframe, VideoViews, pose_matrix
    from avatarkit.recon.pipeline import BuildOptions, build_avatar
    from avatarkit.track.keyframes import KEYFRAMES, choose_keyframes, read_frames, video_sharpness

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
    ref_frame = int(kf.frame_index[0])
    source = {"video": os.path.abspath(video), "frame": ref_frame, "mode": "video",
              "keyframes": kf.summary()}
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
                            "identity_shape": [round(float(c), 4) for c in jf.shape]})
    else:
        source["mode"] = "single frame (the head does not turn: one keyframe)"
    with tempfile.TemporaryDirectory(prefix="avatarkit-frame-") as tmp:
        from avatarkit.export.images import write_png

        png = Path(tmp) / f"frame{ref_frame}.png"
        write_png(png, images[ref_frame])
        if options.name is None:
            options.name = Path(video).stem
        avatar = build_avatar(png, options, progress, views=views)
    if FRAME_COLOURS and len(kf) == 1:
        # only when the head does not turn: with turned keyframes the views colour the sides, and
        # refitting the neck and mouth to the near-frontal frames cost the synthetic turning
        # video's sides up to 0.21 dB (docs/video-build.md)
        from avatarkit.recon.pipeline import STAGES
        from avatarkit.track.frame_colours import fuse_frame_colours

        last = len(STAGES) + 1            # told as one more stage after the portrait build's
        if progress is not None:
            progress("frame_colours", last, last, None)
        t0 = time.perf_counter()
        avatar, fused = fuse_frame_colours(avatar, video, result, ref_frame, span=colour_span)
        timings["frame_colours"] = time.perf_counter() - t0
        if progress is not None:
            progress("frame_colours", last, last, timings["frame_colours"])
        avatar.provenance["build"]["frame_colours"] = fused
        source["colour_frames"] = fused["frames"]
    avatar.provenance["source_video"] = source
    avatar.provenance["source_image"] = f"{os.path.abspath(video)} (frame {ref_frame})"
    build = avatar.provenance["build"]
    build["timings_s"] = {**{k: round(v, 3) for k, v in timings.items()}, **build["timings_s"]}
    build["total_s"] = round(sum(build["timings_s"].values()), 3)
    return avatar


__all__ = ["FRAME_COLOURS", "IDENTITY_EXPR", "build_tracking", "build_video_avatar", "joint_identity"]
