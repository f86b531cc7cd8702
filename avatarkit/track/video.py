"""`track_video`: open a video, choose the head model and identity, track, return the result.

Identity. With an avatar (`avatar=`), its head model and identity shape are used as they are,
so the clip drives that avatar exactly. Otherwise (the template, or `head_model=` a FLAME file)
the identity is fitted over the first frames: `IDENTITY_FRAMES` frames spread over the first
`IDENTITY_SECONDS` seconds that have a face (the first such window: a clip may open on the
empty wall, `NO_FACE_SCAN`), each fitted for pose + shape (+ expression and jaw,
so a talking mouth does not bend the face shape) by the tracker's Levenberg-Marquardt solver
(shape coefficients join the expression ones in `solve.FrameProblem`), and the shape is their
per-coefficient median.

Subject calibration. With an avatar and `TrackOptions(subject_calibration=True)`, the face
mesh's reading bias is calibrated on renders of the avatar at known poses before tracking
(`track.subject_calibration`), and the fit uses that view correction.

Pose refinement. With an avatar and `TrackOptions(refine="photometric")`, each frame's rigid
head pose and jaw opening are refined against the frame by rendering the avatar
(`track.photometric`) before the smoother (`"photometric-pose"`: the pose only); without an
avatar it is an InputError.

Frame rate. A clip has one fps. A variable-frame-rate video is resampled to its average rate
(`video.resample`: nearest frame in time; the clip's `frame_index` names the source frame of
each clip frame); a constant-rate one keeps its frames and rate.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Callable

import numpy as np

from avatarkit.errors import InputError
from avatarkit.track.tracker import (REFINE_CHOICES, REFINE_SETTINGS, FrameTracker, TrackOptions, TrackResult,
                                     model_embedding, track_frames, tracking_focal)

IDENTITY_FRAMES = 8
IDENTITY_SECONDS = 3.0
#: without a face in the first `IDENTITY_SECONDS`, look on window by window (`video_identity`):
#: a clip that opens on 3 s or more of empty wall failed as if it had no face (session 28)
NO_FACE_SCAN = True


def fit_identity(frames: list, model, size: tuple[int, int], options: TrackOptions, embedding) -> np.ndarray:
    """(S,) identity shape from a few frames (module docstring). InputError if none has a face."""
    shapes = _identity_shapes(frames, model, size, options, embedding)
    if not shapes:
        raise InputError(f"no face found in the first {len(frames)} frames used to fit the identity")
    return np.median(np.stack(shapes), axis=0)


def video_identity(video, start: int, end: int, model, size: tuple[int, int], options: TrackOptions,
                   embedding) -> np.ndarray:
    """(S,) identity shape from the first `IDENTITY_SECONDS` window of frames start..end-1 that
    shows a face: a clip may open on the empty wall (the person steps in, the phone is set up)
    for longer than one window. InputError naming how much was looked at when no window shows
    one (a video without a face)."""
    if not NO_FACE_SCAN:
        return fit_identity(_identity_frames(video, start, end), model, size, options, embedding)
    window = max(int(IDENTITY_SECONDS * video.info.fps), 1)
    looked = 0
    for first in range(start, end, window):
        frames = _identity_frames(video, first, end)
        looked += len(frames)
        shapes = _identity_shapes(frames, model, size, options, embedding)
        if shapes:
            return np.median(np.stack(shapes), axis=0)
    seconds = (end - start) / max(video.info.fps, 1e-9)
    raise InputError(f"no face found in the video ({looked} frames looked at, spread over its {seconds:.1f} s)")


def _identity_shapes(frames: list, model, size: tuple[int, int], options: TrackOptions, embedding) -> list:
    """Each frame's (S,) identity shape, for the frames with a face."""
    from avatarkit.face.fit import LandmarkTargets, initial_pose
    from avatarkit.track.solve import FrameProblem, fit_frame, rest_points

    ft = FrameTracker(model, np.zeros(model.num_shape), size, options, embedding)
    problem = FrameProblem.from_landmark_model(ft.lm, np.zeros(model.num_shape), ft.expr_components,
                                               shape_components=model.num_shape)
    shapes = []
    for frame in frames:
        ft.reset()
        mesh = ft.landmarks(frame.rgb)
        if mesh is None:
            continue
        targets = LandmarkTargets.from_mesh(mesh, ft.embedding, size)
        initial = initial_pose(rest_points(problem), targets, ft.focal)
        fit = fit_frame(problem, targets, ft.focal, initial=initial, iterations=40,
                        depth_weight=options.depth_weight, expr_prior=options.expr_prior,
                        jaw_prior=options.jaw_prior, shape=np.zeros(model.num_shape))
        shapes.append(fit.shape)
    return shapes


def _identity_frames(video, start: int, end: int) -> list:
    fps = video.info.fps
    stop = min(end, start + max(int(IDENTITY_SECONDS * fps), 1))
    pick = np.unique(np.linspace(start, stop - 1, IDENTITY_FRAMES).round().astype(int))
    return [f for f in video.frames(start, stop) if f.index in set(pick.tolist())]


def track_video(path: str | os.PathLike, *, avatar: str | os.PathLike | None = None,
                head_model: str | os.PathLike | None = None,
                landmark_embedding: str | os.PathLike | None = None, start: int = 0,
                end: int | None = None, options: TrackOptions | None = None,
                progress: Callable[[int, int], None] | None = None,
                meshes: list | None = None) -> TrackResult:
    """Track the face in the video (or image folder at 30 fps) at `path`, frames start..end-1.

    avatar: an avatar folder whose head model and identity drive the fit; head_model: a head
    model file (FLAME .pkl/.npz) whose identity is fitted; neither: the built-in template.
    landmark_embedding: FLAME's mediapipe_landmark_embedding.npz for a FLAME model.
    progress(done, total) after each frame. meshes: `TrackResult.meshes` of an earlier tracking
    of the same frames (`track_frames`): the face mesh is not run again. Raises AvatarKitError
    subclasses naming the file.
    """
    from avatarkit.video import open_video, resample

    if avatar is not None and head_model is not None:
        raise InputError("give either an avatar or a head model, not both")
    options = options or TrackOptions()
    if options.refine not in REFINE_CHOICES:
        raise InputError(f"pose refinement: {options.refine!r} (one of {', '.join(map(repr, REFINE_CHOICES[1:]))})")
    if options.refine is not None and avatar is None:
        raise InputError("the photometric pose refinement renders the avatar: it needs an avatar")
    p = os.fspath(path)
    try:
        return _track(p, avatar, head_model, landmark_embedding, start, end, options, progress, meshes)
    except InputError as e:
        raise e.with_path(p) from None   # messages without a file name get the video's


@contextmanager
def tracked_with_built_avatar(avatar, video: str | os.PathLike, meshes=None, options: TrackOptions | None = None):
    """Track `video` with an `Avatar` that exists only in memory (a video build's later stages):
    it is saved without its preview to a temporary folder, which `track_video(avatar=)` reads
    as a user's avatar would be read. Yields (folder, TrackResult); the folder is removed on
    exit. meshes: the face meshes of an earlier tracking of the same video, reused; options:
    the tracker's (default `TrackOptions()`)."""
    import tempfile
    from pathlib import Path

    from avatarkit.recon.pipeline import save_avatar

    with tempfile.TemporaryDirectory(prefix="avatarkit-tracked-") as tmp:
        folder = Path(tmp) / "avatar"
        preview, avatar.preview = avatar.preview, None
        try:
            save_avatar(avatar, folder)
        finally:
            avatar.preview = preview
        yield folder, track_video(video, avatar=folder, meshes=meshes, options=options)



def _track(p, avatar, head_model, landmark_embedding, start, end, options, progress,
           meshes=None) -> TrackResult:
    from avatarkit.video import open_video, resample

    with open_video(p, fps=30.0 if os.path.isdir(p) else None) as video:
        start, end = video.check_range(start, end)
        info = video.info
        size = (info.width, info.height)
        if avatar is not None:
            from avatarkit.avatar import load_avatar_head

            model, shape, _, _ = load_avatar_head(avatar)
        else:
            from avatarkit.head.io import load_head_model
            from avatarkit.head.model import HeadModel

            model = HeadModel.template() if head_model is None else load_head_model(head_model)
            shape = None
        embedding = model_embedding(model, landmark_embedding)
        if shape is None:
            shape = video_identity(video, start, end, model, size, options, embedding)
        calibration = None
        if avatar is not None and options.subject_calibration and options.view_correction is False:
            import dataclasses

            first = next(iter(video.frames(start, start + 1)))
            calibration = calibrate_on_avatar(avatar, model, shape, embedding, size, options, first.rgb)
            if calibration.correction is not None:
                options = dataclasses.replace(options, view_correction=calibration.correction)
        frames = video.frames(start, end)
        fps = info.fps
        total = end - start
        if info.variable_frame_rate:
            frames = resample(frames, fps)
            total = int(np.floor((video.times[end - 1] - video.times[start]) * fps + 1e-6)) + 1
        frames = _with_source_index(frames)
        step = (lambda i: progress(i + 1, total)) if progress is not None else None
        name = os.path.splitext(os.path.basename(p.rstrip("/")))[0]
        refiner = None
        if options.refine is not None:
            from avatarkit.avatar import load_avatar
            from avatarkit.track.photometric import PoseRefiner, Settings

            focal = tracking_focal(options, size)
            refiner = PoseRefiner(load_avatar(avatar), focal, size, Settings(**REFINE_SETTINGS[options.refine]))
        result = track_frames(frames, model, shape, size, fps, options, step, name, embedding, meshes, refiner)
        result.subject_calibration = calibration
        return result


def calibrate_on_avatar(avatar, model, shape, embedding, size: tuple[int, int], options: TrackOptions,
                        first_rgb: np.ndarray | None = None):
    """The avatar's own view correction (`subject_calibration.calibrate_subject`), rendered with
    the tracker's focal length for this video size over the background the video's first frame
    shows around the head (`subject_calibration.border_colour`; white without a frame)."""
    from avatarkit.avatar import load_avatar
    from avatarkit.track import subject_calibration as sc

    focal = tracking_focal(options, size)
    background = (1.0, 1.0, 1.0) if first_rgb is None else sc.border_colour(first_rgb)
    return sc.calibrate_subject(sc.rigid_avatar_renderer(load_avatar(avatar), background), model, shape, embedding,
                                focal, grid=sc.AVATAR_GRID, part=options.subject_part)


class _Indexed:
    __slots__ = ("index", "rgb")

    def __init__(self, index, rgb):
        self.index, self.rgb = index, rgb


def _with_source_index(frames):
    """Frames whose `.index` is the source video's frame number (resampled frames carry it in
    `source_index`)."""
    for f in frames:
        src = getattr(f, "source_index", None)
        yield _Indexed(f.index if src is None else src, f.rgb)
