"""Portrait analysis: find the one face, coarse landmarks, roll, frontality and a canonical crop.

Only detectors that ship inside our dependencies are used (no downloads):
OpenCV's Haar cascades (`frontalface_alt2`, then `frontalface_default`; `eye`,
`eye_tree_eyeglasses`, `smile`; `profileface` only to explain a failure) and scikit-image's
LBP frontal-face cascade as the last fallback. Landmarks a detector did not find are estimated
from average face proportions and flagged (`Landmark.detected == False`).

Coordinates are continuous image pixels of the array passed in: x right, y down, pixel (i, j)
covers [i, i+1) x [j, j+1) so its centre is (i + 0.5, j + 0.5), as in the renderer's cameras
(gsplat/COLMAP). Face boxes (x, y, w, h) cover [x, x+w) x [y, y+h). "Left"/"right" eye are the
*subject's*: the left eye appears on the image's right side (the FLAME/dlib convention).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import dataclass, field

import numpy as np

from avatarkit.errors import InputError

#: faces narrower than this (pixels, in the analysed image) are refused
MIN_FACE = 64
#: detections narrower than this fraction of the largest face are ignored as background faces
#: or false positives, so a photo with one clear subject never fails as "several faces"
MINOR_FACE_FRACTION = 0.4
#: below this frontality a warning is returned
FRONTALITY_WARN = 0.45
#: the canonical crop is the FFHQ alignment square (Karras et al. 2019) widened by this factor,
#: so voluminous hair and the top of the head stay inside
CROP_SCALE = 1.2
#: face detection runs on a copy whose longer side is at most this (speed; faces stay >> 24 px)
DETECT_SIDE = 1024

#: `analyze_portrait(detector=...)` choices
FACE_DETECTORS = ("auto", "mediapipe", "cascade")

LANDMARK_NAMES = ("right_eye", "left_eye", "nose_tip", "mouth_center", "mouth_right", "mouth_left")

#: average frontal-face proportions, measured on the alt2 Haar box: fractions of (w, h) from the
#: box's top-left corner. Used when a detector finds no eyes (the other detectors' boxes frame
#: the face within a few percent of alt2's).
BOX_RATIOS = {"right_eye": (0.27, 0.375), "left_eye": (0.73, 0.375)}

#: average proportions in the eye frame: origin at the eye midpoint, x along the eye axis toward
#: the subject's left eye, y perpendicular toward the chin, unit = inter-ocular distance (IOD).
#: Shared by segmentation and the bald filter.
FACE_PROPORTIONS = {
    "nose_tip": (0.0, 0.55),
    "mouth_center": (0.0, 0.95),
    "mouth_right": (-0.45, 0.95),
    "mouth_left": (0.45, 0.95),
    "brow_line": (0.0, -0.35),
    "chin": (0.0, 1.75),
    "skull_top": (0.0, -1.75),   # scalp top without hair, about the eye-to-chin distance up
    "head_half_width": (1.15, 0.0),
}

Box = tuple[int, int, int, int]  # x, y, w, h in pixels

# OpenCV's warps address pixels by index (pixel i's centre at i); our coordinates put pixel i's
# centre at i + 0.5 (the renderer's convention). These convert between the two.
_FROM_INDEX = np.array([[1.0, 0, 0.5], [0, 1.0, 0.5], [0, 0, 1.0]])
_TO_INDEX = np.array([[1.0, 0, -0.5], [0, 1.0, -0.5], [0, 0, 1.0]])


@dataclass(frozen=True)
class Landmark:
    """A 2D point in image pixels and where it came from."""

    x: float
    y: float
    detected: bool  # True: the centre of a detector's hit; False: estimated from proportions
    source: str     # haar_eye | haar_eyeglasses | haar_smile | smile_box | mirrored | eye_ratio | box_ratio

    def __post_init__(self):
        object.__setattr__(self, "x", float(self.x))
        object.__setattr__(self, "y", float(self.y))

    @property
    def xy(self) -> np.ndarray:  # (2,) float64
        return np.array([self.x, self.y])


@dataclass(eq=False)
class PortraitAnalysis:
    """Everything later stages need to know about the face in one portrait."""

    image_size: tuple[int, int]          # (width, height) of the analysed image
    face_box: Box                        # the chosen face
    detector: str                        # haar_alt2 | haar_default | lbp_skimage | given
    face_index: int                      # index of the chosen face in `faces`
    faces: tuple[Box, ...]               # every face found, sorted left to right
    landmarks: dict[str, Landmark]       # keys: LANDMARK_NAMES
    roll_deg: float                      # in-plane tilt: + when the subject's left eye (image right) is lower
    frontality: float                    # 1 = frontal, 0 = strongly turned; nan when not measured
    symmetry: float                      # mirror correlation of the eye-aligned face patch (-1..1)
    eye_offset: float                    # eye midpoint minus face-box centre along the eye axis, in IOD
    crop_center: tuple[float, float]     # centre of the canonical square crop (pixels)
    crop_side: float                     # its side (pixels)
    warnings: list[str] = field(default_factory=list)
    mesh: object = None                  # avatarkit.face.FaceMesh of the chosen face (MediaPipe detector), or None

    # -- the eye frame -------------------------------------------------------------------
    @property
    def eye_mid(self) -> np.ndarray:  # (2,)
        return 0.5 * (self.landmarks["right_eye"].xy + self.landmarks["left_eye"].xy)

    @property
    def eye_distance(self) -> float:
        """Inter-ocular distance (IOD) in pixels: the unit of `FACE_PROPORTIONS`."""
        return float(np.linalg.norm(self.landmarks["left_eye"].xy - self.landmarks["right_eye"].xy))

    def face_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (2,), (2,): along the eye axis toward the subject's left eye, and toward the chin."""
        ex = self.landmarks["left_eye"].xy - self.landmarks["right_eye"].xy
        ex = ex / max(np.linalg.norm(ex), 1e-9)
        return ex, np.array([-ex[1], ex[0]])

    def to_face(self, xy: np.ndarray) -> np.ndarray:
        """Image pixels (..., 2) -> eye-frame coordinates (..., 2) in IOD units (see FACE_PROPORTIONS)."""
        ex, ey = self.face_axes()
        d = (np.asarray(xy, dtype=np.float64) - self.eye_mid) / self.eye_distance
        return np.stack([d @ ex, d @ ey], axis=-1)

    def from_face(self, uv: np.ndarray) -> np.ndarray:
        """Eye-frame coordinates (..., 2) in IOD units -> image pixels (..., 2)."""
        ex, ey = self.face_axes()
        uv = np.asarray(uv, dtype=np.float64)
        return self.eye_mid + self.eye_distance * (uv[..., :1] * ex + uv[..., 1:2] * ey)

    def face_grid(self, shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Eye-frame coordinates (u, v) of every pixel centre: two (H, W) float32 arrays."""
        h, w = shape if shape is not None else (self.image_size[1], self.image_size[0])
        ex, ey = self.face_axes()
        xs = (np.arange(w, dtype=np.float32) + 0.5 - self.eye_mid[0]) / self.eye_distance
        ys = (np.arange(h, dtype=np.float32) + 0.5 - self.eye_mid[1]) / self.eye_distance
        u = xs[None, :] * np.float32(ex[0]) + ys[:, None] * np.float32(ex[1])
        v = xs[None, :] * np.float32(ey[0]) + ys[:, None] * np.float32(ey[1])
        return u, v

    def point(self, name: str) -> np.ndarray:
        """(2,) pixel position of a landmark."""
        return self.landmarks[name].xy

    def points(self, names=None) -> np.ndarray:
        """(K, 2) pixel positions of the named landmarks."""
        names = LANDMARK_NAMES if names is None else names
        return np.stack([self.landmarks[n].xy for n in names])

    # -- the canonical crop --------------------------------------------------------------
    @property
    def crop_box(self) -> tuple[float, float, float, float]:
        """(x, y, w, h) of the crop square in image pixels, before the roll is undone."""
        cx, cy = self.crop_center
        s = self.crop_side
        return (cx - s / 2, cy - s / 2, s, s)

    def crop_matrix(self, size: int = 512, upright: bool = True) -> np.ndarray:
        """(3, 3) affine taking original pixel coordinates to crop pixel coordinates.

        `upright` rotates the crop so the eyes are level (undoes `roll_deg`).
        """
        theta = math.radians(self.roll_deg) if upright else 0.0
        c, s = math.cos(theta), math.sin(theta)
        k = size / self.crop_side
        rot = np.array([[c, s], [-s, c]]) * k  # maps the eye axis (cos, sin) to +x
        m = np.eye(3)
        m[:2, :2] = rot
        m[:2, 2] = np.array([size / 2, size / 2]) - rot @ np.asarray(self.crop_center)
        return m

    def crop(self, image: np.ndarray, size: int = 512, upright: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The canonical square crop (size, size, C) and the (2, 3) affine original -> crop pixels.

        Outside the image the border pixels are repeated (cv2.BORDER_REPLICATE).
        """
        import cv2

        image = np.asarray(image)
        m = self.crop_matrix(size, upright)
        src, pre = image, np.eye(3)  # pre: original -> src pixel coordinates
        k = size / self.crop_side
        if k < 0.5:
            # warpAffine samples bilinearly: shrink with area averaging first to avoid aliasing.
            f = min(1.0, 2.0 * k)
            h, w = image.shape[:2]
            dsize = (max(1, round(w * f)), max(1, round(h * f)))
            src = cv2.resize(image, dsize, interpolation=cv2.INTER_AREA)
            pre = np.diag([dsize[0] / w, dsize[1] / h, 1.0])
        warp = _TO_INDEX @ m @ np.linalg.inv(pre) @ _FROM_INDEX
        out = cv2.warpAffine(src, warp[:2], (size, size), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
        return out, m[:2].copy()

    def scaled(self, k: float) -> "PortraitAnalysis":
        """The same analysis for the image resized by factor `k` (pixel quantities times k)."""
        def box(b):
            return tuple(int(round(v * k)) for v in b)

        lms = {n: dataclasses.replace(l, x=l.x * k, y=l.y * k) for n, l in self.landmarks.items()}
        cx, cy = self.crop_center
        return dataclasses.replace(
            self,
            image_size=(max(1, round(self.image_size[0] * k)), max(1, round(self.image_size[1] * k))),
            face_box=box(self.face_box), faces=tuple(box(b) for b in self.faces), landmarks=lms,
            crop_center=(cx * k, cy * k), crop_side=self.crop_side * k,
            warnings=list(self.warnings), mesh=None if self.mesh is None else self.mesh.scaled(k))


# ---------------------------------------------------------------------------------------
# detectors

@functools.lru_cache(maxsize=None)
def _haar(name: str):
    import cv2

    clf = cv2.CascadeClassifier(os.path.join(cv2.data.haarcascades, name))
    if clf.empty():  # pragma: no cover - a broken OpenCV install
        raise RuntimeError(f"OpenCV cascade {name} failed to load")
    return clf


@functools.lru_cache(maxsize=None)
def _lbp():
    from skimage.data import lbp_frontal_face_cascade_filename
    from skimage.feature import Cascade

    return Cascade(lbp_frontal_face_cascade_filename())


def _grey(image: np.ndarray) -> np.ndarray:
    import cv2

    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    return cv2.equalizeHist(grey)


def detect_faces(image: np.ndarray, min_size: int = 32) -> tuple[list[Box], str]:
    """All frontal faces at least `min_size` px wide in an (H, W, 3) uint8 RGB image, sorted left
    to right, and the detector that found them. Tries Haar alt2, then Haar default, then
    scikit-image's LBP cascade; the first that finds anything wins (alt2 has the fewest false
    positives). Detection runs on a copy shrunk so `min_size` becomes the cascades' 20 px
    window: small scales dominate the cost of a cascade, and we never need faces below that."""
    import cv2

    grey = _grey(image)
    h, w = grey.shape
    f = min(1.0, DETECT_SIDE / max(h, w), 20.0 / max(min_size, 1))
    small = cv2.resize(grey, (round(w * f), round(h * f)), interpolation=cv2.INTER_AREA) if f < 1 else grey
    ms = max(20, int(min_size * f))
    boxes: list = []
    detector = "none"
    for name, cascade, neighbours in (("haar_alt2", "haarcascade_frontalface_alt2.xml", 5),
                                      ("haar_default", "haarcascade_frontalface_default.xml", 6)):
        found = _haar(cascade).detectMultiScale(small, scaleFactor=1.1, minNeighbors=neighbours, minSize=(ms, ms))
        if len(found):
            boxes, detector = [tuple(int(v) for v in b) for b in found], name
            break
    if not boxes:
        found = _lbp().detect_multi_scale(img=small, scale_factor=1.2, step_ratio=1,
                                          min_size=(ms, ms), max_size=small.shape[::-1])
        if found:
            boxes = [(d["c"], d["r"], d["width"], d["height"]) for d in found]
            detector = "lbp_skimage"
    boxes = [tuple(int(round(v / f)) for v in b) for b in _merge_overlaps(boxes)]
    boxes.sort(key=lambda b: (b[0] + b[2] / 2, b[1]))
    return boxes, detector


def _merge_overlaps(boxes: list) -> list:
    """One box per face: detections whose centre lies inside another's box are averaged
    (OpenCV groups its own hits, scikit-image's cascade returns neighbours separately)."""
    groups: list[list] = []
    for b in sorted(boxes, key=lambda b: -b[2] * b[3]):
        cx, cy = b[0] + b[2] / 2, b[1] + b[3] / 2
        for g in groups:
            x, y, w, h = g[0]
            if x <= cx <= x + w and y <= cy <= y + h:
                g.append(b)
                break
        else:
            groups.append([b])
    return [tuple(np.mean(np.array(g, dtype=np.float64), axis=0)) for g in groups]


def _profile_faces(image: np.ndarray, min_size: int = 32) -> int:
    """How many profile faces (either direction) the Haar profile cascade sees: explains failures."""
    import cv2

    grey = _grey(image)
    h, w = grey.shape
    f = min(1.0, DETECT_SIDE / max(h, w), 20.0 / max(min_size, 1))
    if f < 1:
        grey = cv2.resize(grey, (round(w * f), round(h * f)), interpolation=cv2.INTER_AREA)
    clf = _haar("haarcascade_profileface.xml")
    n = len(clf.detectMultiScale(grey, 1.1, 5, minSize=(20, 20)))
    return n + len(clf.detectMultiScale(np.ascontiguousarray(grey[:, ::-1]), 1.1, 5, minSize=(20, 20)))


def _detect_in(grey: np.ndarray, region: Box, cascade: str, neighbours: int,
               min_size: tuple[int, int], max_size: tuple[int, int], norm_w: float) -> list[tuple[float, float, float, float]]:
    """Cascade hits (cx, cy, w, h) in image pixels inside `region`, run at a normalised scale."""
    import cv2

    x, y, w, h = region
    H, W = grey.shape
    x0, y0, x1, y1 = max(0, x), max(0, y), min(W, x + w), min(H, y + h)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return []
    roi = grey[y0:y1, x0:x1]
    f = norm_w / max(w, 1)
    roi = cv2.resize(roi, (max(1, round(roi.shape[1] * f)), max(1, round(roi.shape[0] * f))),
                     interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
    mins = tuple(max(4, int(v * f)) for v in min_size)
    maxs = tuple(max(m + 1, int(v * f)) for v, m in zip(max_size, mins))
    hits = _haar(cascade).detectMultiScale(roi, scaleFactor=1.05, minNeighbors=neighbours, minSize=mins, maxSize=maxs)
    return [(x0 + (hx + hw / 2) / f, y0 + (hy + hh / 2) / f, hw / f, hh / f) for hx, hy, hw, hh in hits]


def _find_eyes(grey: np.ndarray, box: Box) -> dict[str, Landmark]:
    """Eye centres inside the upper part of the face box; estimated where the cascades miss."""
    x, y, w, h = box
    region = (x, y + int(0.15 * h), w, int(0.45 * h))
    exp = {n: np.array([x + r[0] * w, y + r[1] * h]) for n, r in BOX_RATIOS.items()}
    for cascade, source in (("haarcascade_eye.xml", "haar_eye"), ("haarcascade_eye_tree_eyeglasses.xml", "haar_eyeglasses")):
        hits = _detect_in(grey, region, cascade, 3, (0.12 * w, 0.12 * w), (0.4 * w, 0.4 * w), 160.0)
        cx = x + w / 2
        rights = [c for c in hits if c[0] < cx]   # subject's right eye: image left
        lefts = [c for c in hits if c[0] >= cx]
        best, best_score = None, math.inf
        for r in rights:
            for l in lefts:
                sep, dy = (l[0] - r[0]) / w, abs(l[1] - r[1]) / w
                ratio = abs(math.log(l[2] / r[2]))
                if not (0.3 <= sep <= 0.7 and dy <= 0.15 and ratio <= 0.5):
                    continue
                score = (dy + abs(sep - 0.46) + abs((l[0] + r[0]) / 2 - cx) / w + 0.3 * ratio
                         + abs((l[1] + r[1]) / 2 - exp["left_eye"][1]) / h)
                if score < best_score:
                    best, best_score = (r, l), score
        if best is not None:
            r, l = best
            return {"right_eye": Landmark(r[0], r[1], True, source), "left_eye": Landmark(l[0], l[1], True, source)}
        # One eye only: accept it if it sits where an eye should, mirror it for the other.
        singles = [(n, c) for n, group in (("right_eye", rights), ("left_eye", lefts)) for c in group
                   if abs(c[0] - exp[n][0]) < 0.15 * w and abs(c[1] - exp[n][1]) < 0.12 * h]
        if singles:
            n, c = min(singles, key=lambda nc: np.hypot(*(np.array(nc[1][:2]) - exp[nc[0]])))
            other = "left_eye" if n == "right_eye" else "right_eye"
            return {n: Landmark(c[0], c[1], True, source),
                    other: Landmark(2 * cx - c[0], c[1], False, "mirrored")}
    return {n: Landmark(float(p[0]), float(p[1]), False, "box_ratio") for n, p in exp.items()}


def _place(eye_mid, iod, ex, ey, name):
    u, v = FACE_PROPORTIONS[name]
    return eye_mid + iod * (u * ex + v * ey)


def _find_mouth(grey: np.ndarray, box: Box, eyes: dict[str, Landmark]) -> dict[str, Landmark]:
    """Mouth centre (smile cascade, else proportions) and corners (from the smile box or proportions)."""
    x, y, w, h = box
    r, l = eyes["right_eye"].xy, eyes["left_eye"].xy
    mid, iod = (r + l) / 2, float(np.linalg.norm(l - r))
    ex = (l - r) / max(iod, 1e-9)
    ey = np.array([-ex[1], ex[0]])
    guess = _place(mid, iod, ex, ey, "mouth_center")
    derived = "eye_ratio" if eyes["right_eye"].detected or eyes["left_eye"].detected else "box_ratio"
    region = (x + int(0.1 * w), y + int(0.55 * h), int(0.8 * w), int(0.55 * h))
    hits = _detect_in(grey, region, "haarcascade_smile.xml", 15, (0.25 * w, 0.1 * w), (0.7 * w, 0.35 * w), 160.0)
    hits = [c for c in hits if np.hypot(c[0] - guess[0], c[1] - guess[1]) < 0.4 * iod]
    if hits:
        c = min(hits, key=lambda c: np.hypot(c[0] - guess[0], c[1] - guess[1]))
        centre = np.array(c[:2])
        half = 0.36 * c[2]  # the smile box includes some cheek on either side of the corners
        return {"mouth_center": Landmark(c[0], c[1], True, "haar_smile"),
                "mouth_right": Landmark(*(centre - half * ex), False, "smile_box"),
                "mouth_left": Landmark(*(centre + half * ex), False, "smile_box")}
    return {n: Landmark(*_place(mid, iod, ex, ey, n), False, derived)
            for n in ("mouth_center", "mouth_right", "mouth_left")}


def _symmetry(grey: np.ndarray, eye_mid: np.ndarray, iod: float, roll_deg: float) -> float:
    """Mirror correlation of the eye-aligned, high-passed face patch: ~0.5+ for frontal faces."""
    import cv2

    size = 64
    t = math.radians(roll_deg)
    c, s = math.cos(t), math.sin(t)
    k = size / (2.2 * iod)  # patch spans u in [-1.1, 1.1], v in [-0.7, 1.5] (IOD units)
    centre = eye_mid + iod * 0.4 * np.array([-s, c])
    # Blur a region around the patch first: warpAffine samples bilinearly and would alias.
    r = int(1.6 * iod) + 2
    H, W = grey.shape
    x0, y0 = max(0, int(centre[0]) - r), max(0, int(centre[1]) - r)
    roi = grey[y0:min(H, int(centre[1]) + r), x0:min(W, int(centre[0]) + r)].astype(np.float32)
    if roi.size == 0:
        return 0.0
    if k < 0.7:
        roi = cv2.GaussianBlur(roi, (0, 0), 0.5 / k)
    rot = np.array([[c, s], [-s, c]]) * k
    m = np.eye(3)
    m[:2, :2] = rot
    m[:2, 2] = np.array([size / 2, size / 2]) - rot @ (centre - np.array([x0, y0]))
    patch = cv2.warpAffine(roi, (_TO_INDEX @ m @ _FROM_INDEX)[:2], (size, size), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
    patch = patch - cv2.GaussianBlur(patch, (0, 0), 6)
    a = patch - patch.mean()
    b = a[:, ::-1]
    den = float((a * a).sum())
    return float((a * b).sum() / den) if den > 0 else 0.0


def _describe(boxes) -> str:
    return "; ".join(f"[{i}] box x={b[0]} y={b[1]} ({b[2]}x{b[3]} px)" for i, b in enumerate(boxes))


def _as_image(image, path):
    from avatarkit.recon.image_io import read_image

    if isinstance(image, (str, os.PathLike)):
        return read_image(image), (path if path is not None else image)
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"image must be (H, W, 3) uint8 RGB, got {arr.dtype} {arr.shape}", path)
    return arr, path


def analyze_portrait(image, face_index: int | None = None, *, path: str | os.PathLike | None = None,
                     min_face: int | None = None, detector: str = "auto") -> PortraitAnalysis:
    """Find exactly one face in a portrait and describe it.

    image: (H, W, 3) uint8 RGB, or an image file path (read with `read_image`).
    face_index: which face to use when there are several (faces are indexed left to right).
    path: the file name to put in error messages when `image` is an array.

    detector: "auto" (the default, as `BuildOptions.face_detector`'s: MediaPipe when installed,
    else the cascades with a warning; the cascades also when MediaPipe finds no face),
    "mediapipe" (BlazeFace + the 468-point face mesh and iris, `avatarkit.face`; raises
    `ModelsMissing` when they are not installed) or "cascade" (OpenCV Haar / scikit-image LBP).

    Raises InputError: no face; several faces and no `face_index` (the message lists them);
    `face_index` out of range; face narrower than `min_face` pixels. A strongly non-frontal
    face, or one whose eyes were not found, is reported in `warnings`, not raised.
    """
    min_face = MIN_FACE if min_face is None else min_face
    if detector not in FACE_DETECTORS:
        raise InputError(f"face detector must be one of {', '.join(FACE_DETECTORS)}, got {detector!r}")
    image, path = _as_image(image, path)
    if detector in ("auto", "mediapipe"):
        from avatarkit.face.models import ModelsMissing

        try:
            found = _analyze_mediapipe(image, face_index, path, min_face)
        except ModelsMissing as e:
            if detector == "mediapipe":
                raise
            found = None
            missing = f"{e.message}; using the cascade face detector"
        else:
            missing = None
        if found is not None:
            return found
        result = _analyze_cascade(image, face_index, path, min_face)
        result.warnings.insert(0, missing or "MediaPipe found no face; the cascade face detector did")
        return result
    return _analyze_cascade(image, face_index, path, min_face)


def _choose(boxes: list, face_index, min_face: int, path, warnings: list) -> tuple[int, list]:
    """The index of the face to use among boxes (x, y, w, h) sorted left to right, after dropping
    much smaller detections (with a warning); raises InputError as `analyze_portrait` says."""
    largest = max(b[2] for b in boxes)
    keep = [i for i, b in enumerate(boxes) if b[2] >= MINOR_FACE_FRACTION * largest]
    minor = [boxes[i] for i in range(len(boxes)) if i not in keep]
    if minor:
        warnings.append(f"ignored {len(minor)} much smaller face-like detection(s): {_describe(minor)}")
    kept = [boxes[i] for i in keep]
    if face_index is None:
        if len(kept) > 1:
            raise InputError(f"found {len(kept)} faces: {_describe(kept)}; "
                             f"pass --face-index N (face_index=N) to choose one", path)
        face_index = 0
    elif not 0 <= face_index < len(kept):
        raise InputError(f"face index {face_index} is out of range: found {len(kept)} "
                         f"face{'s' if len(kept) > 1 else ''}: {_describe(kept)}", path)
    box = kept[face_index]
    if box[2] < min_face:
        raise InputError(f"face is too small: {box[2]}x{box[3]} px, at least {min_face} px wide is needed "
                         f"(use a larger or closer photo)", path)
    return keep[face_index], keep


def _analyze_mediapipe(image, face_index, path, min_face) -> PortraitAnalysis | None:
    """`analyze_portrait` with MediaPipe's models; None when they find no face."""
    from avatarkit.face import detect_faces, face_landmarks

    faces = detect_faces(image)
    meshes = [face_landmarks(image, f) for f in faces]
    # the face mesh's presence score rejects the detector's false positives
    faces, meshes = [f for f, m in zip(faces, meshes) if m.presence >= 0.5], \
        [m for m in meshes if m.presence >= 0.5]
    if not faces:
        return None
    warnings: list[str] = []
    boxes = [f.xywh() for f in faces]
    index, keep = _choose(boxes, face_index, min_face, path, warnings)
    mesh = meshes[index]
    p = mesh.points.astype(np.float64)
    iris = mesh.iris_centers.astype(np.float64)
    src = "mediapipe"
    landmarks = {"right_eye": Landmark(*iris[0], True, src), "left_eye": Landmark(*iris[1], True, src),
                 "nose_tip": Landmark(*p[1, :2], True, src),
                 "mouth_center": Landmark(*(0.5 * (p[13, :2] + p[14, :2])), True, src),
                 "mouth_right": Landmark(*p[61, :2], True, src), "mouth_left": Landmark(*p[291, :2], True, src)}
    return _describe_face(image, boxes[index], "mediapipe", keep.index(index), [boxes[i] for i in keep],
                          landmarks, warnings, mesh)


def _analyze_cascade(image, face_index, path, min_face) -> PortraitAnalysis:
    warnings: list[str] = []
    # Look for faces down to half the accepted size, so a too-small face is reported as such.
    boxes, detector = detect_faces(image, min_size=max(24, min_face // 2))
    if not boxes:
        hint = ("a face was found only in profile: avatarkit needs a roughly frontal portrait"
                if _profile_faces(image, max(24, min_face // 2)) else
                f"use a well-lit, roughly frontal portrait with the face at least {min_face} px wide")
        raise InputError(f"no face found (OpenCV Haar and scikit-image LBP face detectors); {hint}", path)
    index, keep = _choose(boxes, face_index, min_face, path, warnings)
    box = boxes[index]
    boxes = [boxes[i] for i in keep]
    face_index = keep.index(index)

    grey = _grey(image)
    eyes = _find_eyes(grey, box)
    landmarks = dict(eyes)
    landmarks.update(_find_mouth(grey, box, eyes))
    r, l = eyes["right_eye"].xy, eyes["left_eye"].xy
    iod = float(np.linalg.norm(l - r))
    ex = (l - r) / iod
    ey = np.array([-ex[1], ex[0]])
    mid = (r + l) / 2
    nose_src = "eye_ratio" if (eyes["right_eye"].detected or eyes["left_eye"].detected) else "box_ratio"
    landmarks["nose_tip"] = Landmark(*_place(mid, iod, ex, ey, "nose_tip"), False, nose_src)
    landmarks = {n: landmarks[n] for n in LANDMARK_NAMES}
    if not (eyes["right_eye"].detected and eyes["left_eye"].detected):
        missing = [n for n in ("right_eye", "left_eye") if not eyes[n].detected]
        warnings.append(f"{' and '.join(m.replace('_', ' ') for m in missing)} not found; estimated from "
                        f"face proportions, so roll and frontality are less reliable")
    return _describe_face(image, box, detector, face_index, boxes, landmarks, warnings)


def _describe_face(image, box, detector, face_index, boxes, landmarks, warnings, mesh=None) -> PortraitAnalysis:
    """Roll, frontality and the canonical crop of the chosen face, from its landmarks."""
    h, w = image.shape[:2]
    grey = _grey(image)
    r, l = landmarks["right_eye"].xy, landmarks["left_eye"].xy
    iod = float(np.linalg.norm(l - r))
    both = landmarks["right_eye"].detected and landmarks["left_eye"].detected
    roll = math.degrees(math.atan2(l[1] - r[1], l[0] - r[0]))
    ex = (l - r) / iod
    mid = (r + l) / 2
    # Frontality: a turned head moves the eyes off the face box's centre line and breaks the
    # face's mirror symmetry; either alone fools easily (lighting, hair), so take the weaker.
    box_centre = np.array([box[0] + box[2] / 2, box[1] + box[3] / 2])
    eye_offset = float((mid - box_centre) @ ex / iod)
    symmetry = _symmetry(grey, mid, iod, roll)
    by_offset = float(np.clip(1.0 - abs(eye_offset) / 0.25, 0.0, 1.0)) if both else 1.0
    by_symmetry = float(np.clip((symmetry - 0.1) / 0.4, 0.0, 1.0))
    frontality = min(by_offset, by_symmetry)
    if frontality < FRONTALITY_WARN:
        warnings.append(f"the face looks strongly non-frontal (frontality {frontality:.2f}); "
                        f"the built-in reconstruction assumes a roughly frontal portrait")

    # Canonical crop: FFHQ's rule (side = 2 max(2 IOD, 1.8 eye-to-mouth), centred a tenth of the
    # way from the eyes to the mouth), widened by CROP_SCALE.
    e2m = landmarks["mouth_center"].xy - mid
    side = CROP_SCALE * 2.0 * max(2.0 * iod, 1.8 * float(np.linalg.norm(e2m)))
    centre = mid + 0.1 * e2m
    return PortraitAnalysis(
        image_size=(w, h), face_box=tuple(int(v) for v in box), detector=detector, face_index=face_index,
        faces=tuple(tuple(int(v) for v in b) for b in boxes),
        landmarks=landmarks, roll_deg=roll, frontality=frontality, symmetry=symmetry,
        eye_offset=eye_offset, crop_center=(float(centre[0]), float(centre[1])), crop_side=side,
        warnings=warnings, mesh=mesh)


def analysis_from_box(image_size: tuple[int, int], face_box: Box) -> PortraitAnalysis:
    """A PortraitAnalysis for a face box known by other means (a tracker, a synthetic image):
    every landmark estimated from average proportions, roll 0, frontality not measured (nan).

    image_size: (width, height).
    """
    x, y, w, h = (int(v) for v in face_box)
    if w <= 0 or h <= 0:
        raise InputError(f"face box must have positive size, got {face_box}")
    eyes = {n: Landmark(x + r[0] * w, y + r[1] * h, False, "box_ratio") for n, r in BOX_RATIOS.items()}
    r, l = eyes["right_eye"].xy, eyes["left_eye"].xy
    mid, iod = (r + l) / 2, float(np.linalg.norm(l - r))
    ex, ey = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    lms = dict(eyes)
    for n in ("nose_tip", "mouth_center", "mouth_right", "mouth_left"):
        lms[n] = Landmark(*_place(mid, iod, ex, ey, n), False, "box_ratio")
    e2m = lms["mouth_center"].xy - mid
    side = CROP_SCALE * 2.0 * max(2.0 * iod, 1.8 * float(np.linalg.norm(e2m)))
    centre = mid + 0.1 * e2m
    return PortraitAnalysis(
        image_size=(int(image_size[0]), int(image_size[1])), face_box=(x, y, w, h), detector="given",
        face_index=0, faces=((x, y, w, h),), landmarks={n: lms[n] for n in LANDMARK_NAMES}, roll_deg=0.0,
        frontality=float("nan"), symmetry=float("nan"), eye_offset=0.0,
        crop_center=(float(centre[0]), float(centre[1])), crop_side=side)
