"""Video -> FLAME-style motion: per-frame face mesh, per-frame landmark fit, zero-lag smoothing.

Per frame (`track_frames`):
1. Landmarks. The face mesh runs in the region made from the previous frame's mesh (as
   MediaPipe's tracking graph does); the detectors run only on the first frame, after a frame
   without a face, or when the mesh's presence score drops below `min_presence`. On
   re-detection the face nearest the last one seen is kept (`face_index` picks, left to right,
   on the first detection); a face much smaller than the person's (`MINOR_FACE`: a photo on the
   wall, a passer-by) is never taken, on the first detection or later.
2. Fit (`solve.fit_frame`: the objective of `face.fit`, the core the portrait build uses,
   minimised by Levenberg-Marquardt): the head's rotation and translation, the jaw and the head
   model's expression coefficients, with the identity shape fixed, warm-started from the
   previous frame. Eyes from the iris centres (`gaze.eyes_pose`). Once the first
   `calibration_frames` frames with a face are in, the landmark correspondence is calibrated
   to this face (`FrameTracker.calibrate`) and those frames are fitted again.
3. Confidence = presence / (1 + (median landmark error / (0.05 IOD))^2): 1 for a clean fit,
   falling as the fitted head misses the landmarks, IOD the fitted head's eye distance in
   pixels as if it faced the camera (`face_scale`: a turn does not shrink it, so a turned
   frame that fits well keeps its weight in the smoother). A frame without a face has
   confidence 0.

After the last frame every channel is smoothed by a confidence-weighted Whittaker smoother
(`smooth.whittaker`): symmetric in time, so it does not lag; frames without a face are filled
by it (interpolated) and flagged in `found`.

Frames and camera. The fit poses the head in front of a fixed pinhole at the origin
(`face.fit`'s view frame: X_view = R X_head + t, OpenCV camera C = diag(1, -1, -1)). The clip
moves the head instead: its world is the view frame shifted by the head's median position
`o`, so the head stays near the origin, and the tracked camera is the fixed one,
world_to_camera = [C | C o], fx = fy = the focal used (the build's assumed portrait lens,
`recon.fit.portrait_focal`, unless given), principal point at the image centre. FLAME turns the
head about its root joint J0, so the clip's translation is t - o - J0 + R J0.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np

from avatarkit.errors import InputError
from avatarkit.motion.clip import MotionClip
from avatarkit.render.camera import Camera
from avatarkit.rotations import axis_angle_to_matrix
from avatarkit.track import gaze
from avatarkit.track.photometric import CHEAP_PASS
from avatarkit.track.smooth import whittaker

_C = np.diag([1.0, -1.0, -1.0])
#: a frame whose median landmark error is this many eye distances has confidence presence / 2
ERROR_SCALE = 0.05
#: expression coefficients tracked at most (FLAME has 100; the leading ones carry the motion)
MAX_EXPR = 50
#: a detected face narrower than this share of the widest face in the frame, or of the widest box
#: the followed face has had, is not followed (`_pick_face`; the portrait analysis's
#: `recon.portrait.MINOR_FACE_FRACTION`, 0.4, so the tracker and the reference keyframe's
#: portrait build take the same face); 0 follows any face, as before session 28
MINOR_FACE = 0.4
#: frames with a face the landmark calibration looks at (`FrameTracker.calibrate`); fewer than
#: CALIBRATION_MIN in the whole video: no calibration
CALIBRATION_FRAMES = 30
CALIBRATION_MIN = 5
CALIBRATION_ROUNDS = 2


# TrackOptions.refine's values (None: no refinement) and the `photometric.Settings` fields each
# sets: "photometric" refines the jaw's opening with the pose, from the render's depth, in 3 passes
# (docs/tracking.md, session 14: better than the pose alone on the synthetic avatar video and both
# real clips, and ~1.2x faster); "photometric-pose" is session 13's pose-only refinement (4 passes
# from the head mesh's points), kept for comparison
# "photometric-fast" (session 16): the same refinement in 2 of the cheaper passes
# (`photometric.CHEAP_PASS`) on every 5th frame with a face (`REFINE_EVERY`), the speed setting
# (docs/tracking.md, session 16: against 1 ordinary pass on every 5th frame, the first version,
# about the same speed and better on the synthetic avatar video and both real clips)
REFINE_SETTINGS = {"photometric": dict(jaw=True, render_depth=True, iterations=3), "photometric-pose": {},
                   "photometric-fast": dict(jaw=True, render_depth=True, iterations=2, **CHEAP_PASS)}
REFINE_CHOICES = (None, *REFINE_SETTINGS)
#: the refined frames' spacing of a setting when `TrackOptions.refine_every` is None (others: 1)
REFINE_EVERY = {"photometric-fast": 5}


@dataclass
class TrackOptions:
    """face_index: which face, left to right, on the first detection (among the faces at least
    `MINOR_FACE` of the widest, as the portrait analysis numbers them); smoothing: the Whittaker
    smoother's lambda (frames^4, 0 = off); min_presence: re-detect below this face-mesh presence;
    expr_components: expression coefficients fitted (None: the model's, at most MAX_EXPR);
    focal: pixels (None: `focal_mm`'s lens, else the portrait lens of `recon.fit.portrait_focal`);
    focal_mm: the lens, 35 mm-equivalent across the frame's longer side (`tracking_focal`); iterations:
    Levenberg-Marquardt steps per frame (`solve.fit_frame`); depth_weight, expr_prior,
    jaw_prior, outline_weight: the objective's weights (`face.fit`); calibration_frames: frames with a face the
    per-landmark calibration uses (`FrameTracker.calibrate`; below CALIBRATION_MIN: none).
    view_correction: the landmarks follow the built-in view- and jaw-dependent correction
    (`face.view_correction`; only with the template's embedding) at the pose being fitted.
    Off by default: calibrated on renders of the template head, it removes the template's
    bias (shaded template video: rotation 3.23 -> 2.15 deg, jaw 0.045 -> 0.034 rad) but puts
    it on other faces (the avatar built from samples/portrait.jpg: 4.15 -> 7.46 deg).
    view_correction may also be a `ViewCorrection` (e.g. one fitted for this subject).
    subject_calibration: with an avatar (`track_video(avatar=)`), fit a view correction for it
    from renders of the avatar at known poses (`track.subject_calibration`) and track with it
    (unless view_correction is set); subject_part: what of that correction is used
    (`subject_calibration.PARTS`: "full", "rigid", "nonrigid"; docs/tracking.md, session 12).
    mirror_landmarks: the face mesh averaged with its answer on the mirror image
    (`face.landmarks`, module docstring; what `avatarkit face` fits). Off (session 9,
    benchmarks/track.py, median over the video and its mirror): it hardly moves the shaded
    template (3.23 -> 3.18 deg, jaw 0.045 -> 0.044 rad) or the avatar from samples/portrait.jpg
    (4.15 -> 4.08 deg), makes the flat template worse (5.97 -> 6.75 deg), and costs a mesh-model
    run per frame.
    Tracking departs from the portrait fit's
    defaults, as measured on rendered heads with known motion: the face mesh's relative depth
    biased the pitch (median rotation error 5.0 deg with it, 3.4 without), and a jaw prior
    stronger than the expression prior let expressions mimic an open jaw (jaw error 0.044 rad
    against 0.034). The face outline's points count at 0.3 of the inner ones (session 7: on the
    shaded template video with a mouth interior, median rotation error over the video and its
    mirror 3.71 -> 3.23 deg, jaw 0.041 -> 0.045 rad; the real clips 2.19 / 1.55 -> 2.17 / 1.53
    px): the outline is a silhouette that the face mesh places with a pose-dependent bias.
    The expression prior is 1e-3 (session 10; it was 1e-2, the portrait fit's): a real smile or
    wide-open mouth needs coefficients the stronger prior held back (glasses clip, chosen there:
    the fitted mouth width followed the detected one with slope 0.02, now 0.38; landmark error
    2.16 -> 1.84 px), and the rendered heads do not pay for it (shaded template video 3.11 ->
    3.10 deg, jaw 0.046 -> 0.047 rad; grey clip 1.48 -> 1.36 px).
    refine: "photometric", with an avatar (`track_video(avatar=)`): each frame's rigid head pose
    and the jaw's opening refined against the frame by rendering the avatar (`track.photometric`;
    the other two jaw axes, expression and eyes stay the landmark fit's; docs/tracking.md,
    sessions 13-14), before the smoother; "photometric-pose": the rigid pose only (session 13's);
    "photometric-fast": "photometric" in fewer, cheaper passes on fewer frames (`REFINE_SETTINGS`,
    `REFINE_EVERY`); None: the landmark fit's. refine_every: only every k-th frame with a face is
    refined, the others get the change interpolated from their refined neighbours (None: the
    setting's own, `refine_spacing`). refine_smoothing: lam (frames^4) of a Whittaker smoother
    on the refinement's changes over the refined frames (`apply_refinement`); 0, the default:
    linear interpolation between them (session 16: smoothing them lost, docs/tracking.md)."""

    face_index: int = 0
    smoothing: float = 4.0
    min_presence: float = 0.5
    expr_components: int | None = None
    focal: float | None = None
    focal_mm: float | None = None
    iterations: int = 8
    depth_weight: float = 0.0
    expr_prior: float = 1e-3
    jaw_prior: float = 1e-3
    calibration_frames: int = field(default_factory=lambda: CALIBRATION_FRAMES)  # read when made
    outline_weight: float = 0.3
    view_correction: Any = False
    mirror_landmarks: bool = False
    subject_calibration: bool = False
    subject_part: str = "full"
    refine: str | None = None
    refine_every: int | None = None
    refine_smoothing: float = 0.0


@dataclass(eq=False)
class TrackResult:
    """A tracked clip and what goes with it.

    clip: the motion (world frame above); camera: the fixed tracked camera; frame_index (T,)
    source frame numbers; found (T,) bool (False: no face, channels interpolated);
    confidence (T,) in [0, 1]; landmarks (T, 468, 2) float32 detected face-mesh points (NaN where
    no face); landmark_error (T,) median pixels between the smoothed fit's landmarks and the
    detected ones (NaN where no face); raw: the per-frame fits before smoothing (channel -> (T, k)).
    """

    clip: MotionClip
    camera: Camera
    frame_index: np.ndarray
    found: np.ndarray
    confidence: np.ndarray
    landmarks: np.ndarray
    landmark_error: np.ndarray
    raw: dict = field(default_factory=dict)
    model: Any = None          # the head model tracked with (not stored in the file)
    embedding: Any = None      # its landmark embedding, calibrated offsets included (not stored)
    meshes: list | None = None  # the per-frame face meshes (None: no face), for `track_frames(meshes=)`
    subject_calibration: Any = None  # `subject_calibration.SubjectCalibration` when one was made
    refinement: dict | None = None   # `track_frames(refiner=)`'s figures when the pose was refined

    @property
    def num_frames(self) -> int:
        return len(self.frame_index)


def model_embedding(model, path=None):
    """The face-mesh embedding for `model` (`path`: a FLAME-style embedding file); InputError
    when a model other than the template comes without one."""
    from avatarkit.face.correspondence import embedding_for

    emb = embedding_for(model, path)
    if emb is None:
        raise InputError(f"tracking with the head model {model.name!r} needs its face-mesh landmark "
                         "embedding: pass --landmark-embedding (FLAME's mediapipe_landmark_embedding.npz)")
    return emb


def _pick_face(faces, face_index: int, last_centre, face_width: float | None = None):
    """The face to follow among `faces` (left to right), or None. Faces narrower than
    `MINOR_FACE` of the widest one in the frame, or of the widest box the followed face has
    had (`face_width`, pixels; None before the first), are passed over: a photo on the wall, a
    passer-by, a phone screen or a false detection behind the person. The portrait analysis drops
    the same ones (`recon.portrait.MINOR_FACE_FRACTION`). Without that, the first detection took
    the leftmost face (a smaller face top left of the head: the build followed it), and a
    re-detection where the person's face is not found (a profile) took the nearest face left,
    the small one, and followed it from then on (docs/video-build.md, session 28). First
    detection (`last_centre` None): the `face_index`-th of the faces kept; then the nearest to
    `last_centre`."""
    if not faces:
        return None
    widest = max([f.width for f in faces] + ([face_width] if face_width else []))
    kept = [f for f in faces if f.width >= MINOR_FACE * widest]
    if not kept:
        return None
    if last_centre is None:
        if face_index >= len(kept):
            return None
        return kept[face_index]
    d = [float(np.linalg.norm(np.asarray(f.center) - last_centre)) for f in kept]
    return kept[int(np.argmin(d))]


def face_scale(eye_centres: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
               focal: float) -> float:
    """Pixels between the eye centres `eye_centres` (2, 3) (head frame) of a head at the fitted
    `rotation` (3,) and `translation` (3,) (view frame) as if it faced the camera: the
    confidence's unit. It does not shrink as the head turns; the image distance between the
    irises (`LandmarkTargets.iod`, the unit it replaces) does, and faster than the turn's
    cosine: on the mesh subject's turning video 42.7 px facing the camera, 17.4 px at 46
    degrees of yaw (cos: 29.5), which took the confidence of well-fitted turned frames to ~0.2
    and let the smoother pull the turn's ends back by 12-17 degrees."""
    R = axis_angle_to_matrix(np.asarray(rotation, np.float64)).astype(np.float64)
    mid = R @ np.asarray(eye_centres, np.float64).mean(axis=0) + np.asarray(translation, np.float64)
    depth = max(-float(mid[2]), 1e-6)                       # the view frame looks down -Z
    return float(focal) * float(np.linalg.norm(eye_centres[1] - eye_centres[0])) / depth


def confidence(presence: float, median_error: float, scale: float) -> float:
    """presence / (1 + (median_error / (ERROR_SCALE scale))^2): 1 for a clean fit, falling as the
    fitted head misses the landmarks; errors and `scale` (`face_scale`) in pixels."""
    return float(presence) / (1.0 + (float(median_error) / (ERROR_SCALE * max(float(scale), 1e-6))) ** 2)


def tracking_focal(options: TrackOptions, size: tuple[int, int]) -> float:
    """The tracker's focal length in pixels for frames of `size` (W, H): `options.focal` if given,
    else the lens `options.focal_mm` (None: the assumed one) by `recon.fit.portrait_focal`."""
    from avatarkit.recon.fit import portrait_focal

    return float(options.focal) if options.focal else portrait_focal(*size, options.focal_mm)


class FrameTracker:
    """The per-frame half of tracking: landmarks with ROI propagation, and the landmark fit."""

    def __init__(self, model, shape: np.ndarray, size: tuple[int, int], options: TrackOptions,
                 embedding=None):
        from avatarkit.face.fit import LandmarkModel

        self.model, self.options = model, options
        self.size = (int(size[0]), int(size[1]))
        self.shape = np.asarray(shape, np.float64).reshape(-1)
        self.embedding = embedding if embedding is not None else model_embedding(model)
        self.lm = LandmarkModel(model, self.embedding)
        self.focal = tracking_focal(options, self.size)
        E = model.num_expr if options.expr_components is None else options.expr_components
        self.expr_components = int(max(0, min(model.num_expr, E, MAX_EXPR)))
        from avatarkit.head.model import HeadParams

        joints = model.rest_joints(HeadParams(shape=self.shape[None].astype(np.float32)[0],
                                              expr=np.zeros((1, model.num_expr), np.float32)))[0]
        self.joints = joints.astype(np.float64)                   # (J, 3) rest joints, shaped
        self.eye_centres = self.joints[[gaze.LEFT_EYE_JOINT, gaze.RIGHT_EYE_JOINT]]
        from avatarkit.track.solve import FrameProblem

        from avatarkit.face.view_correction import resolve

        # True: the built-in template's correction; a ViewCorrection (e.g. calibrated on this
        # subject, `track.subject_calibration`): that one
        self.correction = resolve(options.view_correction or None, self.embedding)
        if options.view_correction not in (None, False, True) and not options.view_correction.matches(self.embedding):
            raise InputError("the view correction was calibrated for another landmark embedding")
        self.problem = FrameProblem.from_landmark_model(self.lm, self.shape, self.expr_components
                                                        ).with_view(self.correction)
        self.prev_mesh = None
        self.prev_fit = None
        self.last_centre = None
        # the widest detector box the followed face has had (pixels; `_pick_face`)
        self.face_width = None

    def landmarks(self, rgb: np.ndarray):
        """The face mesh of this frame, or None."""
        from avatarkit.face import detect_faces, face_landmarks, roi_from_mesh

        o = self.options
        mesh = None
        if self.prev_mesh is not None:
            mesh = face_landmarks(rgb, roi_from_mesh(self.prev_mesh.points), mirror=o.mirror_landmarks)
            if mesh.presence < o.min_presence:
                mesh = None
        if mesh is None:
            face = _pick_face(detect_faces(rgb), o.face_index, self.last_centre, self.face_width)
            if face is not None:
                mesh = face_landmarks(rgb, face, mirror=o.mirror_landmarks)
                if mesh.presence < o.min_presence:
                    mesh = None
                else:
                    self.face_width = max(self.face_width or 0.0, face.width)
        self.prev_mesh = mesh
        if mesh is not None:
            self.last_centre = np.asarray(mesh.points[:, :2], np.float64).mean(0)
        return mesh

    def fit(self, mesh):
        """(fit, eyes (6,), confidence) of one frame's mesh."""
        from avatarkit.face.fit import LandmarkTargets

        targets = LandmarkTargets.from_mesh(mesh, self.embedding, self.size)
        fit = self._fit_targets(targets)
        eyes = self.eyes(mesh, fit.rotation, fit.translation)
        scale = face_scale(self.eye_centres, fit.rotation, fit.translation, self.focal)
        return fit, eyes, confidence(float(mesh.presence), fit.median_error, scale)

    def eyes(self, mesh, rotation, translation) -> np.ndarray:
        """(6,) FLAME eyes_pose of `mesh`'s irises seen by the head at `rotation` (3,),
        `translation` (3,) (`gaze.eyes_pose`: the gaze is relative to the head, so it depends
        on the head's pose)."""
        return gaze.eyes_pose(np.asarray(mesh.iris_centers, np.float64), self.eye_centres,
                              rotation, translation, self.focal, (self.size[0] / 2, self.size[1] / 2))

    def calibrate(self, meshes: list) -> None:
        """Per-landmark calibration from a few frames' meshes: the identity's coefficients
        shape the head only coarsely (the template has 8), so a person's face-mesh points sit
        a few pixels off the model's in the same place frame after frame (measured on the
        real clips: 2.7-3.8 px of a 3.3-4.3 px median error stays put in the image). Fit the
        frames, move each landmark by its median residual carried into the head's frame
        (`solve.landmark_offsets`), refit, repeat `CALIBRATION_ROUNDS` times. Only the
        landmark correspondence changes: the identity shape, and so the avatar a clip
        drives, does not."""
        from avatarkit.face.fit import LandmarkModel, LandmarkTargets
        from avatarkit.track.solve import FrameProblem, landmark_offsets

        targets = [LandmarkTargets.from_mesh(m, self.embedding, self.size) for m in meshes]
        offset = np.zeros((len(self.embedding), 3)) if self.embedding.offset is None else self.embedding.offset
        for _ in range(CALIBRATION_ROUNDS):
            self.prev_fit = None
            fits = [self._fit_targets(t) for t in targets]
            offset = offset + landmark_offsets(self.problem, fits, targets, self.focal)
            self.embedding = self.embedding.with_offset(offset)
            self.lm = LandmarkModel(self.model, self.embedding)
            self.problem = FrameProblem.from_landmark_model(self.lm, self.shape, self.expr_components
                                                            ).with_view(self.correction)
        self.prev_fit = None

    def fit_targets(self, targets):
        """The fit of one frame's `LandmarkTargets`, warm-started from the previous frame's
        (`reset` forgets it)."""
        return self._fit_targets(targets)

    def _fit_targets(self, targets):
        from avatarkit.face.fit import initial_pose, with_outline_weight
        from avatarkit.track.solve import fit_frame, rest_points

        if self.options.outline_weight != 1.0:
            targets = with_outline_weight(targets, self.options.outline_weight)
        initial = None
        if self.prev_fit is None:
            initial = initial_pose(rest_points(self.problem), targets, self.focal)
        fit = fit_frame(self.problem, targets, self.focal, start=self.prev_fit, initial=initial,
                        iterations=self.options.iterations if self.prev_fit is not None else 30,
                        depth_weight=self.options.depth_weight, expr_prior=self.options.expr_prior,
                        jaw_prior=self.options.jaw_prior, shape=self.shape)
        self.prev_fit = fit
        return fit

    def reset(self):
        """Forget the previous frame (after a frame without a face)."""
        self.prev_mesh = None
        self.prev_fit = None


def track_frames(frames: Iterable, model, shape: np.ndarray, size: tuple[int, int], fps: float,
                 options: TrackOptions | None = None, progress: Callable[[int], None] | None = None,
                 name: str = "", embedding=None, meshes: list | None = None, refiner=None) -> TrackResult:
    """Track `frames` (objects with `.index` and `.rgb` (H, W, 3) uint8, e.g. `video.Frame`s)
    of size (width, height) at `fps` with `model` and identity `shape` (S,). `progress(i)` is
    called after each frame. Raises InputError when no frame has a face.

    meshes: the face meshes of these frames from an earlier tracking (`TrackResult.meshes`),
    used instead of running the face mesh again. The landmark step does not depend on the head
    model (its regions come from the previous mesh), so a second tracking of the same frames
    with another model gives the same result as tracking from scratch, at the fits' cost only.

    refiner: a `photometric.PoseRefiner` for these frames (their size and the tracker's focal):
    each frame's rigid pose is refined against the frame after the landmark fit (every
    `options.refine_every`-th frame with a face; the others get their neighbours' change,
    interpolated), and every frame's eyes are read again from its irises at the refined pose
    (`FrameTracker.eyes`), before the smoother. The first frames, whose fits wait for the landmark
    calibration, keep a small copy of the frame until then.
    """
    options = options or TrackOptions()
    ft = FrameTracker(model, shape, size, options, embedding)
    E = model.num_expr
    rows = {k: [] for k in ("rotation", "translation", "jaw", "expr", "eyes")}
    index, found, conf, marks, seen = [], [], [], [], []
    # the first frames with a face wait for the landmark calibration, then are fitted again
    pending = [] if options.calibration_frames >= CALIBRATION_MIN else None

    def store(row, fit, eyes, c):
        values = {"rotation": fit.rotation, "translation": fit.translation, "jaw": fit.jaw,
                  "expr": np.concatenate([fit.expr, np.zeros(E)])[:E], "eyes": eyes}
        for k, v in values.items():
            if row == len(rows[k]):
                rows[k].append(v)
            else:
                rows[k][row] = v
        if row == len(conf):
            conf.append(c)
        else:
            conf[row] = c

    refined: dict = {}                # row -> (rotation change (3,), translation change (3,), jaw change (3,))
    waiting: dict = {}                # row -> the small frame, until the calibration refits it
    every = refine_spacing(options)
    stats = {"frames": 0, "seconds": 0.0, "before": [], "after": [], "renders": []}

    def refine(row, small):
        import time

        from avatarkit.rotations import matrix_to_axis_angle

        t0 = time.perf_counter()
        r0, t0_ = rows["rotation"][row], rows["translation"][row]
        out = refiner.refine(small, r0, t0_, rows["jaw"][row], rows["expr"][row][:ft.expr_components],
                             rows["eyes"][row])
        dR = axis_angle_to_matrix(out.rotation).astype(np.float64) @ axis_angle_to_matrix(r0).astype(np.float64).T
        jaw = rows["jaw"][row] if out.jaw is None else out.jaw
        refined[row] = (np.asarray(matrix_to_axis_angle(dR), np.float64).reshape(3),
                        np.asarray(out.translation, np.float64) - np.asarray(t0_, np.float64),
                        np.asarray(jaw, np.float64).reshape(3) - np.asarray(rows["jaw"][row], np.float64).reshape(3))
        stats["frames"] += 1
        stats["seconds"] += time.perf_counter() - t0
        stats["before"].append(out.start_residual)
        stats["after"].append(out.residual)
        stats["renders"].append(out.renders)

    def calibrate():
        ft.calibrate([m for _, m in pending])
        for row, m in pending:
            store(row, *ft.fit(m))
            if row in waiting:
                refine(row, waiting.pop(row))
    faces = 0
    for i, frame in enumerate(frames):
        if meshes is None:
            mesh = ft.landmarks(frame.rgb)
        elif i < len(meshes):
            mesh = meshes[i]
        else:
            raise ValueError(f"meshes holds {len(meshes)} frames, the frames go on past that")
        seen.append(mesh)
        index.append(int(frame.index))
        if mesh is None:
            ft.reset()
            found.append(False)
            conf.append(0.0)
            marks.append(np.full((468, 2), np.nan, np.float32))
            for k, w in (("rotation", 3), ("translation", 3), ("jaw", 3), ("expr", E), ("eyes", 6)):
                rows[k].append(np.zeros(w))
        else:
            found.append(True)
            marks.append(np.asarray(mesh.points[:, :2], np.float32))
            row = len(index) - 1
            store(row, *ft.fit(mesh))
            if refiner is not None and faces % every == 0:
                if pending is not None:
                    waiting[row] = refiner.shrink(frame.rgb)
                else:
                    refine(row, frame.rgb)
            faces += 1
            if pending is not None:
                pending.append((len(index) - 1, mesh))
                if len(pending) == options.calibration_frames:
                    calibrate()
                    pending = None
        if progress is not None:
            progress(i)
    if pending is not None and len(pending) >= CALIBRATION_MIN:
        calibrate()
    if not index:
        raise InputError("the video has no frames in the chosen range")
    found = np.asarray(found)
    if not found.any():
        raise InputError(f"no face found in any of the {len(index)} frames")
    for row, small in list(waiting.items()):       # too few frames for the calibration
        refine(row, small)
    raw = {k: np.asarray(v, np.float64).reshape(len(index), -1) for k, v in rows.items()}
    if refiner is not None:
        apply_refinement(raw, refined, found, options.refine_smoothing)
        # the gaze was read from the irises relative to the landmark fit's head; the refined
        # head is turned and shifted, so the same irises mean other eye rotations
        for row in np.flatnonzero(found):
            raw["eyes"][row] = ft.eyes(seen[row], raw["rotation"][row], raw["translation"][row])
    conf = np.asarray(conf, np.float64)
    landmarks = np.stack(marks)
    result = finish(raw, conf, found, np.asarray(index), landmarks, ft, fps, options, name)
    result.meshes = seen
    if refiner is not None:
        result.refinement = {"frames": stats["frames"], "seconds": stats["seconds"],
                             "residual_before_px": float(np.nanmedian(stats["before"])) if stats["before"] else None,
                             "residual_after_px": float(np.nanmedian(stats["after"])) if stats["after"] else None,
                             "renders": float(np.mean(stats["renders"])) if stats["renders"] else None,
                             "size": refiner.camera.width}
    return result


def refine_spacing(options: TrackOptions) -> int:
    """Every how many frames with a face `options` refine: refine_every, or (None) the setting's
    own (`REFINE_EVERY`, else 1)."""
    if options.refine_every is not None:
        return max(1, int(options.refine_every))
    return REFINE_EVERY.get(options.refine, 1)


def apply_refinement(raw: dict, refined: dict, found: np.ndarray, smoothing: float = 0.0) -> None:
    """Move raw["rotation"] / raw["translation"] (T, 3) (and raw["jaw"] (T, 3)) in place by the
    refinement's changes `refined` {row: (rotation change (3,) axis-angle, applied on the left;
    translation change (3,)[; jaw change (3,), added])}.

    smoothing 0 (`TrackOptions.refine_smoothing`'s default): the rows with a face that were not
    refined get the changes interpolated linearly between their refined neighbours (held at the
    ends), the refined rows their own. smoothing > 0: the changes through a Whittaker smoother
    over the refined rows (`smoothed_changes`). Off because the changes are not noise about a
    slow bias: they follow the motion (the jaw's with the opening), and smoothing them lost on
    the synthetic avatar video and both real clips (docs/tracking.md, session 16)."""
    from avatarkit.rotations import matrix_to_axis_angle

    if not refined:
        return
    done = np.array(sorted(refined))
    d = np.concatenate([np.stack([refined[k][0] for k in done]), np.stack([refined[k][1] for k in done]),
                        np.stack([refined[k][2] if len(refined[k]) > 2 else np.zeros(3) for k in done])], 1)  # (R, 9)
    rows = np.flatnonzero(found)
    change = smoothed_changes(done, d, rows, smoothing)
    ir, it, ij = change[:, :3], change[:, 3:6], change[:, 6:]
    for k, row in enumerate(rows):
        R = axis_angle_to_matrix(ir[k]).astype(np.float64) @ axis_angle_to_matrix(raw["rotation"][row]).astype(np.float64)
        raw["rotation"][row] = np.asarray(matrix_to_axis_angle(R), np.float64).reshape(3)
        raw["translation"][row] = raw["translation"][row] + it[k]
        if "jaw" in raw:
            raw["jaw"][row] = raw["jaw"][row] + ij[k]


def smoothed_changes(done: np.ndarray, changes: np.ndarray, rows: np.ndarray, smoothing: float = 0.0) -> np.ndarray:
    """The refinement's changes (R, C) at the refined rows `done` (R,) (increasing), read at
    `rows` (N,): smoothing 0, linear interpolation; > 0, a weighted Whittaker smoother
    (`smooth.whittaker`, lam = smoothing in frames^4) over the rows done[0]..done[-1], the
    refined rows weight 1 and the others 0 (so it interpolates them: a spline-like curve where
    interpolation draws straight lines); held at the ends either way. -> (N, C)."""
    changes = np.asarray(changes, np.float64)
    if smoothing > 0 and len(done) >= 3:
        span = np.arange(done[0], done[-1] + 1)
        x = np.zeros((len(span), changes.shape[1]))
        w = np.zeros(len(span))
        x[done - done[0]] = changes
        w[done - done[0]] = 1.0
        z = whittaker(x, w, smoothing)
        return z[np.clip(rows, done[0], done[-1]) - done[0]]
    return np.stack([np.interp(rows, done, changes[:, j]) for j in range(changes.shape[1])], 1)


def finish(raw: dict, confidence: np.ndarray, found: np.ndarray, frame_index: np.ndarray,
           landmarks: np.ndarray, ft: FrameTracker, fps: float, options: TrackOptions,
           name: str = "") -> TrackResult:
    """Smooth the per-frame fits, move them into the clip's world, measure the landmark error."""
    w = np.where(found, np.maximum(confidence, 1e-3), 0.0)
    smooth = {k: whittaker(v, w, options.smoothing) if options.smoothing > 0 else
              _interpolate(v, found) for k, v in raw.items()}
    o = np.median(smooth["translation"][found], axis=0)
    J0 = ft.joints[0]
    T = len(frame_index)
    R = np.stack([axis_angle_to_matrix(r).astype(np.float64) for r in smooth["rotation"]])  # (T, 3, 3)
    translation = smooth["translation"] - o - J0 + R @ J0
    clip = MotionClip(fps=fps, rotation=smooth["rotation"], translation=translation,
                      neck=np.zeros((T, 3)), jaw=smooth["jaw"], eyes=smooth["eyes"], expr=smooth["expr"],
                      shape=ft.shape.astype(np.float32), name=name)
    w2c = np.eye(4)
    w2c[:3, :3] = _C
    w2c[:3, 3] = _C @ o
    W, H = ft.size
    camera = Camera(ft.focal, ft.focal, W / 2, H / 2, W, H, w2c)
    err = landmark_errors(ft, smooth, landmarks, found)
    return TrackResult(clip, camera, frame_index, found, confidence, landmarks, err, raw, ft.model, ft.embedding)


def _interpolate(v: np.ndarray, found: np.ndarray) -> np.ndarray:
    t = np.arange(len(v))
    return np.stack([np.interp(t, t[found], v[found, j]) for j in range(v.shape[1])], axis=1)


def landmark_errors(ft: FrameTracker, params: dict, landmarks: np.ndarray, found: np.ndarray) -> np.ndarray:
    """(T,) median pixel distance between the fitted head's projected landmarks (every embedded
    face-mesh point, outline points included) and the detected ones; NaN where no face."""
    from avatarkit.track.solve import project

    out = np.full(len(found), np.nan)
    idx = ft.embedding.mesh_index
    E = ft.expr_components
    for t in np.flatnonzero(found):
        px = project(ft.problem, params["rotation"][t], params["translation"][t], params["jaw"][t],
                     params["expr"][t][:E], ft.focal, ft.size)
        out[t] = float(np.median(np.linalg.norm(px - landmarks[t, idx], axis=1)))
    return out
