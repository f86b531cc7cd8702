"""Calibrate the face mesh's reading bias on renders of the subject itself.

Why: the face mesh reads each appearance with a view- and jaw-dependent bias of its own
(docs/face.md; session 8: one skin sample of the template read with its own bias). The
template's correction (`face.view_correction`, calibrated on renders of the template) removes
the template's bias and puts it on other faces, so it is off. When the tracker is given the
subject's appearance - an avatar built from the person (`track --avatar`) - the subject can be
rendered at poses and jaw openings chosen here, so that where each landmark truly is on every
render is known exactly; the face mesh runs on the renders as the tracker runs it, and a
`ViewCorrection` is fitted to what it reads (`view_correction.fit_correction`), for this
subject. Unlike the tracker's per-landmark calibration (`FrameTracker.calibrate`: the median
residual over the first frames, at whatever pose the fit found), this also sees the part of
the bias that moves the fitted pose (a constant nod, a yaw read short), since the renders'
pose is known.

What is rendered is the MODEL of the subject (the avatar, or for the benchmark's synthetic
videos the renderer that made the video) at poses chosen here (`CalibrationGrid`), never the
video's frames or their poses.

The camera (`calibration_camera`): the tracker's focal length for the video's size, the head
`distance` metres away, a square crop 2 CROP_HALF_WIDTH metres wide at the head (486 px for a
480 x 480 video at 0.55 m: about the frame's size, so the crop bounds the cost rather than
cutting it; a far-away head in a large frame gains more). Cost (session 11, 2 busy cores): 45
renders + face mesh 11.5-16.9 s, the fit 0.1-0.4 s. An avatar at `AVATAR_GRID`'s poses is drawn
by `rigid_avatar_renderer` (no bake: session 12, a fresh calibration on the real clips'
avatars 11.2-28.5 -> 9.4-10.1 s at load 6.5-8; what is left is the 35 splat renders).

What of the correction is used (`PARTS`, `fit_subject`): all of it; its rigid part, one turn and
shift of the whole face per basis term (the reading bias of the pose); or the rest. Session 12
(docs/tracking.md): the rigid part is what brings the synthetic avatar video to 2 degrees and
what loses the real clips' PSNR; the rest gains PSNR on the real clips and does nothing for the
synthetic pose.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from avatarkit.render.camera import Camera

_C = np.diag([1.0, -1.0, -1.0])
#: half the crop's side in metres at the head (the head is ~0.2 m wide with its hair; the
#: detector wants margin around the face: at 0.14 the chin met the crop's edge with the jaw
#: open, and the calibrated avatar tracked the grey clip worse, 24.48 against 24.94 dB at 0.2
#: with the video's background)
CROP_HALF_WIDTH = 0.2
#: the height above the head model's origin (its neck joint) the camera looks at: the eyes sit
#: ~5 cm above it (as `synthetic.head_video.head_video_camera`)
LOOK_HEIGHT = 0.05

#: A subject's renderer: (clip, camera) -> one (H, W, 3) uint8 image per clip frame
Renderer = Callable[[object, Camera], Iterable[np.ndarray]]


@dataclass(frozen=True)
class CalibrationGrid:
    """The renders' poses: every combination of yaw and pitch (degrees) and jaw opening (rad).
    The default's 45 renders span a talking head's range (session 11: yaw +-35 with pitch +-20
    lost 9 of 45 renders of the shaded template to the detector - the head turned and looking
    down - and fitted worse, 3.06 / 3.14 -> 2.65 / 1.65 deg against 2.31 / 1.98 deg here)."""

    yaw: tuple = (-30.0, -15.0, 0.0, 15.0, 30.0)
    pitch: tuple = (-15.0, 0.0, 15.0)
    jaw: tuple = (0.0, 0.15, 0.3)

    def __len__(self) -> int:
        return len(self.yaw) * len(self.pitch) * len(self.jaw)

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """(rotation (N, 3) axis-angle, jaw (N,) rad) of every render."""
        from scipy.spatial.transform import Rotation

        y, p, j = np.meshgrid(self.yaw, self.pitch, self.jaw, indexing="ij")
        euler = np.stack([y.ravel(), p.ravel(), np.zeros(y.size)], 1)
        return Rotation.from_euler("YXZ", euler, degrees=True).as_rotvec(), j.ravel().astype(np.float64)


#: the grid `track --avatar --subject-calibration` renders an avatar at: the jaw closed. An
#: avatar's open mouth is its build's guess (no mouth interior: a stretched lip) and does not
#: look like the person's, so the jaw's reading on it does not carry over to the video
#: (session 11, `avatarkit evaluate`, glasses clip: 23.66 dB with the default grid's jaw
#: openings, 23.86 with the jaw closed; grey clip 24.94 / 24.90 dB)
AVATAR_GRID = CalibrationGrid((-30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0), (-15.0, -7.5, 0.0, 7.5, 15.0), (0.0,))


def pose_clip(rotation: np.ndarray, jaw: np.ndarray, fps: float = 30.0):
    """A MotionClip holding the head at `rotation` (N, 3) with the jaw open by `jaw` (N,)."""
    from avatarkit.motion.clip import MotionClip

    n = len(rotation)
    return MotionClip(fps=fps, rotation=np.asarray(rotation, np.float64), translation=np.zeros((n, 3)),
                      neck=np.zeros((n, 3)), jaw=np.stack([jaw, np.zeros(n), np.zeros(n)], 1),
                      eyes=np.zeros((n, 6)), expr=np.zeros((n, 9)))


def calibration_camera(focal: float, distance: float) -> Camera:
    """A square crop of a camera of focal length `focal` px looking down -Z at the point
    LOOK_HEIGHT above the head's origin from `distance` metres; the crop is centred on that
    point (principal point at its centre, so mirroring the image mirrors the camera) and covers
    2 CROP_HALF_WIDTH metres there."""
    half = int(np.ceil(CROP_HALF_WIDTH * focal / distance))
    w2c = np.eye(4)
    w2c[:3, :3] = _C
    w2c[:3, 3] = _C @ np.array([0.0, -LOOK_HEIGHT, -distance])
    return Camera(focal, focal, float(half), float(half), 2 * half, 2 * half, w2c)


def mirrored(render: Renderer) -> Renderer:
    """The renderer of the subject's mirror image (left and right swapped): the subject at the
    mirrored pose, the image flipped. Needs a camera symmetric about its principal point's
    column (`calibration_camera`'s is)."""
    def draw(clip, camera):
        import dataclasses

        flip = np.array([1.0, -1.0, -1.0])
        m = dataclasses.replace(clip, rotation=clip.rotation * flip, jaw=clip.jaw * flip,
                                translation=clip.translation * np.array([-1.0, 1.0, 1.0]))
        for rgb in render(m, camera):
            yield np.ascontiguousarray(rgb[:, ::-1])
    return draw


def avatar_renderer(avatar, background=(1.0, 1.0, 1.0)) -> Renderer:
    """An avatar's own renderer (baked, hair static) over a flat background."""
    def draw(clip, camera):
        from avatarkit.synthetic.head_video import avatar_video

        for f in avatar_video(avatar, clip, camera, background=background):
            yield f.rgb
    return draw


def rigid_avatar_renderer(avatar, background=(1.0, 1.0, 1.0)) -> Renderer:
    """`avatar_renderer` without the bake, for the poses a calibration renders: when a clip
    only turns and shifts the whole model (neck, jaw, eyes and expression zero: `pose_clip`
    with the jaw closed, as `AVATAR_GRID`), every frame is the avatar at rest as a whole
    turned and shifted by the frame's root transform; the avatar at rest is posed once (its
    bald Gaussians on the rest head, its hair as it rests). Why: the bake computes the hair
    cage's mean-value weights on its first frame and poses 80k Gaussians per frame (together
    1-19 s of a fresh calibration on 2 busy cores, session 12); neither changes what a rigid turn shows (static
    hair rides the head; no pose corrective moves without a neck, jaw or eye turn). Any other
    clip is drawn by `avatar_renderer`; tests compare the two on a rigid clip."""
    slow = avatar_renderer(avatar, background)
    rest: list = []

    def draw(clip, camera):
        from avatarkit.export.images import to_uint8
        from avatarkit.head.model import HeadParams
        from avatarkit.render import render

        moving = [np.asarray(getattr(clip, k)) for k in ("neck", "jaw", "eyes", "expr")]
        if any(np.any(m != 0) for m in moving):
            yield from slow(clip, camera)
            return
        if not rest:
            rest.append(_rest_person(avatar))
        params = HeadParams.from_clip(clip)
        params.shape = np.asarray(avatar.shape, np.float32).reshape(-1)
        root = avatar.head_model.forward(params)[1][:, 0].astype(np.float64)           # (T, 4, 4)
        for a in root:
            yield to_uint8(render(_turned(*rest[0], a), camera, background).rgb)
    return draw


def _turned(rest, axis, a: np.ndarray):
    """`_rest_person`'s (rest, axis) turned and shifted as a whole by a (4, 4), as the bake
    moves it: the hair's Gaussians, when its deformer carries principal axes, by the smallest
    rotation taking each rest long axis to the turned one (`cage.deform`), not by the turn
    itself (the two differ by a twist about the axis, which the renders show)."""
    from avatarkit.rotations import matrix_to_quat, quat_multiply, shortest_arc

    means, quats = np.asarray(rest.means, np.float64), np.asarray(rest.quats, np.float64)
    turn = np.repeat(matrix_to_quat(a[:3, :3])[None], len(means), 0)
    if axis is not None:
        turn[len(means) - len(axis):] = shortest_arc(axis, axis @ a[:3, :3].T)
    return rest.replace(means=(means @ a[:3, :3].T + a[:3, 3]).astype(np.float32),
                        quats=quat_multiply(turn, quats).astype(np.float32))


def _rest_person(avatar):
    """(the avatar at rest as one GaussianSet, as the bake's `BakeFrame.person` at the rest
    pose; the hair's rest long axes (H, 3) when its deformer carries principal axes, else None)."""
    from avatarkit.cage.points import principal_axis_index
    from avatarkit.gaussians.gaussian_set import GaussianSet
    from avatarkit.head.model import HeadParams
    from avatarkit.rig.binding_kernel import binding_to_world
    from avatarkit.rotations import quat_to_matrix

    params = HeadParams.from_clip(pose_clip(np.zeros((1, 3)), np.zeros(1)))
    params.shape = np.asarray(avatar.shape, np.float32).reshape(-1)
    v = avatar.head_model.forward(params)[0][0]
    means, quats, scales = binding_to_world(avatar.binding, np.ascontiguousarray(v, np.float32))
    parts = [avatar.bald.replace(means=means, quats=quats, scales=scales, extras={})]
    axis = None
    if avatar.has_hair:
        parts.append(avatar.hair.replace(extras={}))
        if avatar.rig.deformer.method == "principal_axis":
            k = principal_axis_index(avatar.hair.scales)
            axis = quat_to_matrix(np.asarray(avatar.hair.quats, np.float64))[np.arange(len(k)), :, k]
    return GaussianSet.concat(parts), axis


def border_colour(rgb: np.ndarray, share: float = 0.05) -> tuple[float, float, float]:
    """The background a video shows around a head, as a render's background colour in [0, 1]:
    the per-channel median of the top rows and, down to half the height, the outer columns
    (`share` of the size each; a portrait's torso fills the bottom). rgb: (H, W, 3) uint8."""
    a = np.asarray(rgb)
    h, w = a.shape[:2]
    bh, bw = max(1, int(share * h)), max(1, int(share * w))
    band = np.concatenate([a[:bh].reshape(-1, 3), a[:h // 2, :bw].reshape(-1, 3), a[:h // 2, -bw:].reshape(-1, 3)])
    return tuple(float(v) for v in np.median(band, axis=0) / 255.0)


def read_face_mesh(rgb: np.ndarray):
    """The face mesh as the tracker reads a frame in the middle of a video: detected, then
    re-run in the region made from that mesh (the tracker's region comes from the previous
    frame's mesh). None without a face."""
    from avatarkit.face import detect_faces, face_landmarks, roi_from_mesh

    faces = detect_faces(rgb)
    if not faces:
        return None
    mesh = face_landmarks(rgb, max(faces, key=lambda q: q.score), mirror=False)
    if mesh.presence < 0.5:
        return None
    again = face_landmarks(rgb, roi_from_mesh(mesh.points), mirror=False)
    return again if again.presence >= 0.5 else mesh


def render_samples(render: Renderer, model, shape: np.ndarray, embedding, camera: Camera,
                   rotation: np.ndarray, jaw: np.ndarray) -> dict:
    """Render the subject at each pose, read the face mesh, and record the truth: the data
    `view_correction.samples_from_renders` takes (mesh (N, 468, 3) px, truth_cam (N, K, 3)
    the embedding's points in the OpenCV camera frame, head_to_cam (N, 3, 3), jaw (N,), focal,
    size, principal (2,), found (N,))."""
    meshes = [read_face_mesh(rgb) for rgb in render(pose_clip(rotation, jaw), camera)]
    res = truth(model, shape, embedding, camera, rotation, jaw)
    res.update(found=np.array([m is not None for m in meshes]),
               mesh=np.stack([np.full((468, 3), np.nan) if m is None else np.asarray(m.points, np.float64)
                              for m in meshes]))
    return res


def truth(model, shape: np.ndarray, embedding, camera: Camera, rotation: np.ndarray, jaw: np.ndarray) -> dict:
    """Where the embedding's points are at each pose: truth_cam (N, K, 3) OpenCV camera frame,
    head_to_cam (N, 3, 3), jaw (N,), focal, size, principal (2,)."""
    from scipy.spatial.transform import Rotation

    from avatarkit.head.model import HeadParams

    params = HeadParams.from_clip(pose_clip(rotation, jaw))
    params.shape = np.asarray(shape, np.float32).reshape(-1)
    verts = model.forward(params)[0].astype(np.float64)                              # (N, V, 3) world
    return dict(truth_cam=np.stack([camera.to_camera(embedding.points(v, model.faces)) for v in verts]),
                head_to_cam=camera.rotation @ Rotation.from_rotvec(rotation).as_matrix(),
                jaw=np.asarray(jaw, np.float64), focal=np.float64(camera.fx), size=np.int64(camera.width),
                principal=np.array([camera.cx, camera.cy]))


@dataclass(eq=False)
class SubjectCalibration:
    """correction: the fitted `ViewCorrection` (None: too few renders had a face); renders,
    found: how many renders and how many had a face; seconds: rendering + face mesh, fit;
    report: `fit_correction`'s held-out figures; data: the renders' readings
    (`render_samples`)."""

    correction: object
    renders: int
    found: int
    seconds: tuple
    report: str
    data: dict | None = None    # `render_samples`' data, to fit another part without rendering again


#: what of the fitted correction is kept (`calibrate_subject(part=)`): "full", every landmark's
#: own offsets; "rigid", only a turn and shift of the whole face as a function of the view and
#: jaw (`view_correction.solve_rigid`: the part that moves the fitted pose); "nonrigid", the full
#: correction less that rigid part (the landmarks' places relative to each other, which leave
#: the pose as it is read)
PARTS = ("full", "rigid", "nonrigid")


def rest_landmarks(model, shape: np.ndarray, embedding) -> np.ndarray:
    """(K, 3) the embedding's points on the subject at rest (the frame the offsets live in)."""
    from avatarkit.head.model import HeadParams

    params = HeadParams.from_clip(pose_clip(np.zeros((1, 3)), np.zeros(1)))
    params.shape = np.asarray(shape, np.float32).reshape(-1)
    return embedding.points(model.forward(params)[0][0].astype(np.float64), model.faces)


def fit_subject(data: dict, model, shape: np.ndarray, embedding, part: str = "full",
                ridge: float | None = None, outline_weight: float = 0.3):
    """(ViewCorrection, report) from `render_samples`' data (`PARTS`). The rigid part: the turn
    and shift of the whole face, fitted to the residuals with the face outline's points
    weighted as the tracker weights them (`TrackOptions.outline_weight`: the pose the tracker
    reads leans on them that much), with `view_correction.RIGID_RIDGE`; `ridge` is the full
    correction's."""
    from avatarkit.face.correspondence import FACE_OVAL
    from avatarkit.face.view_correction import ViewCorrection, fit_correction, samples_from_renders

    if part not in PARTS:
        raise ValueError(f"subject calibration part: {part!r} (one of {', '.join(PARTS)})")
    samples = samples_from_renders(data, embedding)
    if part == "full":
        return fit_correction(samples, embedding.mesh_index, ridge)
    weight = np.where(np.isin(embedding.mesh_index, FACE_OVAL), outline_weight, 1.0)
    rigid, report = fit_correction(samples, embedding.mesh_index, rigid=rest_landmarks(model, shape, embedding),
                                   weight=weight)
    if part == "rigid":
        return rigid, report
    full, report = fit_correction(samples, embedding.mesh_index, ridge)
    return ViewCorrection(full.mesh_index, full.coef - rigid.coef, full.static - rigid.static), \
        f"the full correction less its rigid part; the full one's {report}"


def calibrate_subject(render: Renderer, model, shape: np.ndarray, embedding, focal: float,
                      distance: float = 0.55, grid: CalibrationGrid | None = None,
                      ridge: float | None = None, part: str = "full") -> SubjectCalibration:
    """Fit a `ViewCorrection` for this subject from renders at `grid`'s poses (module
    docstring); `part`: what of it is kept (`PARTS`). embedding: the tracker's landmark
    embedding WITHOUT its per-landmark calibration offsets (the correction is relative to the
    embedding's points)."""
    import time

    from avatarkit.face.view_correction import BASIS

    grid = grid or CalibrationGrid()
    rotation, jaw = grid.poses()
    camera = calibration_camera(focal, distance)
    t0 = time.perf_counter()
    data = render_samples(render, model, shape, embedding, camera, rotation, jaw)
    t1 = time.perf_counter()
    found = int(data["found"].sum())
    if found < 2 * len(BASIS):
        return SubjectCalibration(None, len(rotation), found, (t1 - t0, 0.0),
                                  f"{found} of {len(rotation)} renders had a face: too few to fit")
    corr, report = fit_subject(data, model, shape, embedding, part, ridge)
    return SubjectCalibration(corr, len(rotation), found, (t1 - t0, time.perf_counter() - t1), report, data)
