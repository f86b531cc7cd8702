"""MediaPipe's 468-point face mesh and iris models on LiteRT.

Face mesh (mediapipe/modules/face_landmark): the region is a square around the detection
box, turned so that the line from the right eye to the left eye keypoint is its x axis
(DetectionsToRects, target angle 0), 1.5 times the box's longer side (RectTransformation,
square_long). It is resampled to 192 x 192 in [0, 1]; the model returns 468 points (x, y in
input pixels, z in the same units, smaller = nearer the camera) and a face-presence logit
(sigmoid -> `presence`). Points are mapped back through the region (LandmarkProjection); z
is scaled like x, so all three are image pixels.

Iris (mediapipe/modules/iris_landmark): each eye's region is centred between its corners
(mesh points 33 and 133 for the subject's right eye, 362 and 263 for the left), turned along
the corner line, 2.3 times the corner distance, resampled to 64 x 64 in [0, 1]; the model is
trained on one eye side, so the subject's left eye is mirrored in and out. It returns 71 eye
contour points and 5 iris points (centre first, then four on the iris boundary).

For video (issue 16), `roi_from_mesh` makes the next frame's region from this frame's mesh as
MediaPipe's tracking does (rotation from points 33 -> 263, scale 1.5).

Mirror averaging (`face_landmarks(mirror=True)`): the mesh model also runs on the region's
mirror image, its answer is mirrored back and re-indexed left <-> right (`mirror_pairs`), and
the two answers are averaged. The model does not answer a mirrored face with the mirrored
points: on an exactly left-right symmetric render of the template head its points miss their
mirrored partners by 3 px median at 512 x 512 (0.03 eye distances), a left/right-asymmetric
reading that the average cancels. An averaged pass of a mirrored image in the mirrored region
is the mirrored pass (up to the resampling's rounding; `face_landmarks` averages only the pass
it keeps). The iris model needs no second run: the subject's left eye
is already fed to it mirrored, so on the mirror image each eye's input is the other eye's
input of the original; it follows the averaged mesh's eye corners and so is mirror-consistent.

Test-time augmentation (`face_landmarks(augment=True)`, session 11): the kept pass is read in
nine regions, the kept region scaled by `AUGMENT_SCALES` times turned by `AUGMENT_ANGLES_DEG`
about its centre, each reading mapped back to the image and the nine averaged (with `mirror`,
each region's reading is first mirror-averaged: 18 model runs). The mesh model's answer moves
with where the face sits in its input (a few pixels at 512 x 512 for an 8 degree turn of the
region); that part is noise to the landmark fit, and the average keeps what every region
agrees on. The set is symmetric under mirroring (a region turned by +a, mirrored, is the mirror
image's region turned by -a), so the mirror-averaged augmented mesh stays mirror-consistent.
Measured (benchmarks/face.py, 120 shaded template renders): the landmark fit's median rotation
error 2.19 -> 1.86 deg (docs/face.md, Session 11).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avatarkit.face.detect import Face
from avatarkit.face.models import get_model
from avatarkit.face.roi import Roi, crop, roi_from_points

N_LANDMARKS = 468
#: face_detection_front_detection_to_roi / face_landmark_landmarks_to_roi: RectTransformation scale
FACE_ROI_SCALE = 1.5
#: iris_landmark_landmarks_to_roi: RectTransformation scale
IRIS_ROI_SCALE = 2.3
#: mesh points of each eye's corners, (subject's right eye, left eye), outer/inner in the order
#: MediaPipe's iris graph takes them (rotation from the first to the second)
EYE_CORNERS = ((33, 133), (362, 263))
#: mesh points of the rotation vector when a region is made from a previous mesh
MESH_ROTATION_POINTS = (33, 263)
#: the face mesh's points on the face's midline (their own mirror partners). MediaPipe's
#: canonical face model (face_geometry/data/canonical_face_model.obj) has x = 0 at exactly these
#: 28 vertices; its other 440 come as the subject's right side (x < 0, the indices below 248
#: not listed here, in order) followed by their mirror images in the same order (248..467).
#: `scripts/check_mesh_mirror.py` re-derives the pairing from the model's own answer on a
#: left-right symmetric render (nearest mirrored point, one-to-one) and checks it is this one.
MESH_MIDLINE = (0, 1, 2, 4, 5, 6, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 94, 151, 152, 164,
                168, 175, 195, 197, 199, 200)
#: `face_landmarks`' default: the plain mesh. The averaged one (module docstring) is asked for
#: where it was measured to help: the landmark fit of `avatarkit face` (`face.overlay`; the
#: benchmark's 36 shaded template renders 2.25 -> 1.82 deg, 1.98 -> 1.86 px; 36 renders of
#: disjoint seeds 3.19 -> 2.63 deg; the avatar from samples/portrait.jpg 10.20 -> 10.12 deg).
#: Not the build's fit (front-view PSNR 28.30 -> 28.21 dB with it on the plain mesh's embedding,
#: 28.11 on the one made from the averaged mesh, session 10) nor the tracker
#: (`TrackOptions.mirror_landmarks`; docs/face.md). `avatarkit face` fits it on its own
#: embedding (`correspondence.template_embedding(mirror=True)`; 120 renders 2.37 -> 2.19 deg).
MIRROR_AVERAGE = False
#: test-time augmentation's regions (module docstring): the kept region scaled by each of these
#: and turned by each of these angles (degrees), 9 readings averaged. Chosen on the benchmark's
#: seeds 0-4 among shifts (+-4 % of the side), scales (+-8 %), turns (+-4, +-8, +-12 deg) and
#: their products: turns did the most, scales next, shifts least (docs/face.md, Session 11).
AUGMENT_SCALES = (0.92, 1.0, 1.08)
AUGMENT_ANGLES_DEG = (-8.0, 0.0, 8.0)


@dataclass(eq=False)
class FaceMesh:
    """The face mesh of one face, in image pixels (x right, y down, pixel centres at i + 0.5;
    z in the same pixel units, smaller = nearer the camera, 0 near the face's centre depth).

    points: (468, 3) float32 in MediaPipe's face-mesh order; presence: 0..1 (is a face there);
    iris: (2, 5, 3) float32, (subject's right eye, left eye) x (centre, 4 boundary points);
    eye_contours: (2, 71, 3) float32; roi: the region the mesh model saw;
    eye_rois: the two iris regions.
    """

    points: np.ndarray
    presence: float
    iris: np.ndarray
    eye_contours: np.ndarray
    roi: Roi
    eye_rois: tuple[Roi, Roi]

    def scaled(self, k: float) -> "FaceMesh":
        """The same mesh for the image resized by factor k (every coordinate times k)."""
        def roi(r: Roi) -> Roi:
            return Roi((r.center[0] * k, r.center[1] * k), r.side * k, r.angle)

        k32 = np.float32(k)
        return FaceMesh(self.points * k32, self.presence, self.iris * k32, self.eye_contours * k32,
                        roi(self.roi), (roi(self.eye_rois[0]), roi(self.eye_rois[1])))

    @property
    def iris_centers(self) -> np.ndarray:
        """(2, 2) pixels: the subject's right, left iris centre."""
        return self.iris[:, 0, :2]

    @property
    def iris_radii(self) -> np.ndarray:
        """(2,) pixels: mean distance of the boundary points from each iris centre."""
        return np.linalg.norm(self.iris[:, 1:, :2] - self.iris[:, :1, :2], axis=2).mean(axis=1)


def mirror_pairs() -> np.ndarray:
    """(468,) int64: the face-mesh point that point i becomes when the face is mirrored left-right
    (an involution; the midline points map to themselves; `MESH_MIDLINE`)."""
    mid = set(MESH_MIDLINE)
    right = [i for i in range(N_LANDMARKS - (N_LANDMARKS - len(mid)) // 2) if i not in mid]
    pairs = np.arange(N_LANDMARKS)
    left = np.arange(N_LANDMARKS - len(right), N_LANDMARKS)
    pairs[right], pairs[left] = left, right
    return pairs


def mirror_points(points: np.ndarray, width: float) -> np.ndarray:
    """Face-mesh points (468, 2+) of an image `width` pixels wide as the mesh of its mirror image
    should be: x -> width - x, re-indexed left <-> right (`mirror_pairs`); other columns kept."""
    out = np.array(points, copy=True)[mirror_pairs()]
    out[:, 0] = width - out[:, 0]
    return out


def roi_from_face(face: Face) -> Roi:
    """The face-mesh region of a detection (module docstring)."""
    kp = face.keypoints.astype(np.float64)
    box = face.box.astype(np.float64).reshape(2, 2)
    return roi_from_points(kp[0], kp[1], box, FACE_ROI_SCALE)


def roi_from_mesh(points: np.ndarray) -> Roi:
    """The face-mesh region from a previous mesh `points` (468, 2+) (tracking)."""
    p = np.asarray(points, np.float64)[:, :2]
    a, b = MESH_ROTATION_POINTS
    return roi_from_points(p[a], p[b], p, FACE_ROI_SCALE)


def _sigmoid(x: float) -> float:
    return float(1.0 / (1.0 + np.exp(-np.clip(x, -100.0, 100.0))))


#: run the two eyes' iris inputs, and a region's face-mesh input with its mirror image, as one
#: batch of two (the same answers, bit for bit, as one run each: `tests/test_face_batch.py`); False runs
#: them one by one (the reference)
BATCH = True


def _run_pair(name: str, x0: np.ndarray, x1: np.ndarray) -> list[tuple[np.ndarray, ...]]:
    """Model `name` on two (S, S, 3) inputs: per input, its outputs (each flattened)."""
    if BATCH:
        outs = get_model(name, 2).run(np.stack([x0, x1]))
        return [tuple(o.reshape(2, -1)[i] for o in outs) for i in range(2)]
    model = get_model(name)
    return [tuple(o.reshape(-1) for o in model.run(x[None])) for x in (x0, x1)]


def _iris(image: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[Roi, Roi]]:
    size = get_model("iris").input_size[0]
    contours, irises, rois, inputs = [], [], [], []
    for side, (a, b) in enumerate(EYE_CORNERS):
        p0, p1 = points[a, :2], points[b, :2]
        rois.append(roi_from_points(p0, p1, np.stack([p0, p1]), IRIS_ROI_SCALE))
        inputs.append(crop(image, rois[-1], size, flip=side == 1) / 255.0)
    for side, (outs, roi) in enumerate(zip(_run_pair("iris", *inputs), rois)):
        flip = side == 1
        contour = next(o for o in outs if o.size == 71 * 3).reshape(71, 3).astype(np.float64) / size
        iris = next(o for o in outs if o.size == 5 * 3).reshape(5, 3).astype(np.float64) / size
        for arr, out in ((contour, contours), (iris, irises)):
            uv = arr[:, :2].copy()
            if flip:
                uv[:, 0] = 1.0 - uv[:, 0]
            xy = roi.to_image(uv)
            out.append(np.concatenate([xy, arr[:, 2:] * roi.side], axis=1))
    return (np.stack(irises).astype(np.float32), np.stack(contours).astype(np.float32),
            (rois[0], rois[1]))


def _mesh_outputs(outs, size: int) -> tuple[np.ndarray, float]:
    raw = next(o for o in outs if o.size == N_LANDMARKS * 3).reshape(N_LANDMARKS, 3).astype(np.float64) / size
    flag = next(o for o in outs if o.size == 1)
    return raw, float(flag.reshape(-1)[0])


def _run_mesh(x: np.ndarray) -> tuple[np.ndarray, float]:
    """The mesh model on one (S, S, 3) input in [0, 1]: (468, 3) region-normalised points
    (u, v, z / side) and the presence logit."""
    model = get_model("landmarks")
    return _mesh_outputs(model.run(np.ascontiguousarray(x[None], np.float32)), model.input_size[0])


def _mesh(image: np.ndarray, roi: Roi, mirror: bool = False) -> tuple[np.ndarray, float]:
    """(468, 3) float32 image-pixel points of the mesh model in `roi` and its presence logit
    (mirror: averaged with the answer on the region's mirror image)."""
    size = get_model("landmarks").input_size[0]
    x = crop(image, roi, size) / 255.0
    if mirror:
        # the region's mirror image is the input column-reversed (pixel centres are symmetric
        # about u = 0.5); its answer mirrored back: u -> 1 - u, left <-> right re-indexed
        (raw, logit), (raw_m, logit_m) = (_mesh_outputs(o, size) for o in _run_pair("landmarks", x, x[:, ::-1]))
        raw_m = raw_m[mirror_pairs()]
        raw_m[:, 0] = 1.0 - raw_m[:, 0]
        raw, logit = 0.5 * (raw + raw_m), 0.5 * (logit + logit_m)
    else:
        raw, logit = _run_mesh(x)
    xy = roi.to_image(raw[:, :2])
    points = np.concatenate([xy, raw[:, 2:] * roi.side], axis=1).astype(np.float32)
    return points, logit


def augmented_rois(roi: Roi, scales=None, angles_deg=None) -> list[Roi]:
    """The regions test-time augmentation reads: `roi` scaled by each of `scales` and turned
    by each of `angles_deg` about its centre (len(scales) * len(angles_deg) regions)."""
    scales = AUGMENT_SCALES if scales is None else scales
    angles_deg = AUGMENT_ANGLES_DEG if angles_deg is None else angles_deg
    return [Roi(roi.center, roi.side * k, roi.angle + math.radians(a)) for k in scales for a in angles_deg]


def _mesh_augmented(image: np.ndarray, roi: Roi, mirror: bool, known: tuple[np.ndarray, float] | None = None
                    ) -> tuple[np.ndarray, float]:
    """The mean of `_mesh` over `augmented_rois(roi)`: (468, 3) image pixels and the mean
    presence logit (as the mirror average takes it). known: the reading (points, logit) of `roi`
    itself, already made (it is one of the regions: not run again)."""
    points = np.zeros((N_LANDMARKS, 3))
    logit = 0.0
    rois = augmented_rois(roi)
    for r in rois:
        p, lg = known if (known is not None and r == roi) else _mesh(image, r, mirror)
        points += p
        logit += lg
    return (points / len(rois)).astype(np.float32), logit / len(rois)


def face_landmarks(image: np.ndarray, face: Face | Roi, refine: bool = True,
                   mirror: bool | None = None, augment: bool = False) -> FaceMesh:
    """The face mesh and irises of one face in an (H, W, 3) uint8 RGB image of any size.
    face: a detection (`detect_faces`) or a region (`roi_from_mesh` of a previous frame).
    refine: run the mesh model a second time in the region made from its first answer
    (`roi_from_mesh`, as MediaPipe's tracking does from frame to frame). The detector's box and
    eye keypoints are coarse, worse under strong roll (a face turned 90 degrees in the picture
    gets a ~70 degree region); on the sample portrait turned by 30, -45 and 90 degrees the
    second pass brings the median error from up to 6% to at most 2.5% of the eye distance.
    mirror: average the kept mesh pass with its answer on the region's mirror image (module
    docstring; one more mesh-model run); None: `MIRROR_AVERAGE`. With `refine` the first pass,
    which only places the second pass's region, is not averaged, so the mesh of a mirrored
    image matches the mirrored mesh to what the second region's small shift moves (on the sample
    portrait 0.4% of the eye distance median, 1.3% at most, against 2.4% / 5% for the plain
    mesh), not to the resampling's rounding as with one pass.
    augment: read the kept pass in the nine regions of `augmented_rois` and average them
    (module docstring; 9 mesh-model runs in place of 1, 18 with `mirror`); the mesh's `roi`
    stays the kept region. `avatarkit face`'s fit reads it (`face.overlay`).
    Raises ModelsMissing when the models or LiteRT are not installed."""
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    image = image[..., :3]
    roi = face if isinstance(face, Roi) else roi_from_face(face)
    mirror = MIRROR_AVERAGE if mirror is None else bool(mirror)
    # with refine, the first pass only places the second's region: averaged only if it is kept
    points, logit = _mesh(image, roi, mirror and not refine)
    averaged = mirror and not refine
    if refine and _sigmoid(logit) > 0.5:
        # kept only if the model is at least as sure of a face there: on a face turned far
        # sideways the mesh's bounding box can frame it worse than the detector did
        again = roi_from_mesh(points)
        points2, logit2 = _mesh(image, again, mirror)
        if _sigmoid(logit2) >= min(_sigmoid(logit), 0.9):
            roi, points, logit, averaged = again, points2, logit2, mirror
    if augment:
        # the kept reading is the unturned, unscaled region's when it was read as asked
        points, logit = _mesh_augmented(image, roi, mirror, (points, logit) if averaged == mirror else None)
    elif mirror and not averaged:
        points, logit = _mesh(image, roi, True)
    presence = _sigmoid(logit)
    iris, contours, eye_rois = _iris(image, points)
    return FaceMesh(points, presence, iris, contours, roi, eye_rois)
