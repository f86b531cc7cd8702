"""Face detection with MediaPipe's BlazeFace models (short and full range) on LiteRT.

What MediaPipe's face_detection_{short,full}_range graphs do, written out in numpy:

1. the image is letterboxed (aspect kept, zero padding) into the model's square input and
   scaled to [-1, 1];
2. the model returns, per SSD anchor, 16 regressors (box centre, size, six keypoints: x then
   y, in input pixels relative to the anchor centre) and one raw score;
3. anchors come from MediaPipe's SsdAnchorsCalculator (`ssd_anchors`) with the graphs'
   options (`SHORT_RANGE`, `FULL_RANGE`: fixed unit-size anchors, so only centres matter);
4. scores are sigmoid(clip(raw, -100, 100)); boxes under the model's threshold are dropped;
5. weighted non-maximum suppression (NonMaxSuppressionCalculator, algorithm WEIGHTED, IoU
   threshold 0.3): the best box absorbs every box overlapping it by more than the threshold,
   its coordinates becoming their score-weighted mean.

Both models run on every image: the short-range one (128 px input) is trained for faces
within ~2 m that fill a good part of the frame, the full-range one (192 px, one dense
stride-4 layer) for small, distant faces. Their detections are pooled before the
suppression. Keypoints are the subject's: right eye (image left on a frontal face), left
eye, nose tip, mouth centre, right ear tragion, left ear tragion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avatarkit.face.models import get_model
from avatarkit.face.roi import Roi, crop

KEYPOINT_NAMES = ("right_eye", "left_eye", "nose_tip", "mouth_center", "right_ear", "left_ear")


@dataclass(frozen=True)
class AnchorOptions:
    """MediaPipe's SsdAnchorsCalculatorOptions (the fields these models use)."""

    input_size: int
    strides: tuple[int, ...]
    num_layers: int
    min_scale: float = 0.1484375
    max_scale: float = 0.75
    anchor_offset: float = 0.5
    interpolated_scale_aspect_ratio: float = 1.0
    aspect_ratios: tuple[float, ...] = (1.0,)


@dataclass(frozen=True)
class DetectorConfig:
    model: str
    anchors: AnchorOptions
    min_score: float


# mediapipe/modules/face_detection/face_detection_short_range.pbtxt and
# face_detection_full_range.pbtxt (SsdAnchorsCalculator, TensorsToDetectionsCalculator options)
SHORT_RANGE = DetectorConfig("detect_short", AnchorOptions(128, (8, 16, 16, 16), 4), 0.5)
FULL_RANGE = DetectorConfig("detect_full", AnchorOptions(192, (4,), 1, interpolated_scale_aspect_ratio=0.0), 0.6)
#: NonMaxSuppressionCalculator: min_suppression_threshold (IoU)
NMS_IOU = 0.3
#: MediaPipe clips raw scores at this before the sigmoid
SCORE_CLIP = 100.0


@dataclass(frozen=True, eq=False)
class Face:
    """One detected face, in image pixels (x right, y down, pixel centres at i + 0.5).

    box: (4,) float32 x0, y0, x1, y1; keypoints: (6, 2) float32 in KEYPOINT_NAMES order;
    score: 0..1; detector: "short" or "full" (the model of the best box in its group).
    """

    box: np.ndarray
    keypoints: np.ndarray
    score: float
    detector: str

    @property
    def width(self) -> float:
        return float(self.box[2] - self.box[0])

    @property
    def height(self) -> float:
        return float(self.box[3] - self.box[1])

    @property
    def center(self) -> np.ndarray:  # (2,)
        return np.array([(self.box[0] + self.box[2]) / 2, (self.box[1] + self.box[3]) / 2])

    def xywh(self) -> tuple[int, int, int, int]:
        """The box as integer (x, y, w, h), as the cascade detector's boxes."""
        x0, y0, x1, y1 = (float(v) for v in self.box)
        return (int(round(x0)), int(round(y0)), int(round(x1 - x0)), int(round(y1 - y0)))


def ssd_anchors(opt: AnchorOptions) -> np.ndarray:
    """(A, 2) anchor centres in [0, 1] (x, y), in the order of the model's outputs, as
    MediaPipe's SsdAnchorsCalculator makes them (fixed_anchor_size: the sizes are all 1, so only
    the count per location matters: one per aspect ratio, plus one interpolated scale when
    `interpolated_scale_aspect_ratio` > 0; consecutive layers with the same stride share a grid)."""
    out = []
    layer = 0
    while layer < opt.num_layers:
        per_location = 0
        last = layer
        while last < opt.num_layers and opt.strides[last] == opt.strides[layer]:
            per_location += len(opt.aspect_ratios) + (1 if opt.interpolated_scale_aspect_ratio > 0 else 0)
            last += 1
        stride = opt.strides[layer]
        n = int(math.ceil(opt.input_size / stride))
        y, x = np.meshgrid((np.arange(n) + opt.anchor_offset) / n, (np.arange(n) + opt.anchor_offset) / n,
                           indexing="ij")
        grid = np.stack([x.ravel(), y.ravel()], axis=1)
        out.append(np.repeat(grid, per_location, axis=0))
        layer = last
    return np.concatenate(out).astype(np.float32)


_ANCHORS: dict = {}


def _anchors(cfg: DetectorConfig) -> np.ndarray:
    if cfg.model not in _ANCHORS:
        _ANCHORS[cfg.model] = ssd_anchors(cfg.anchors)
    return _ANCHORS[cfg.model]


def decode(raw_boxes: np.ndarray, raw_scores: np.ndarray, anchors: np.ndarray, input_size: int,
           min_score: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw outputs (A, 16), (A,) -> boxes (K, 4) x0 y0 x1 y1, keypoints (K, 6, 2), scores (K,)
    for the anchors scoring at least `min_score`; coordinates normalised to the input square."""
    scores = 1.0 / (1.0 + np.exp(-np.clip(raw_scores.astype(np.float64), -SCORE_CLIP, SCORE_CLIP)))
    keep = scores >= min_score
    r = raw_boxes[keep].astype(np.float64) / input_size
    a = anchors[keep].astype(np.float64)
    cx, cy = r[:, 0] + a[:, 0], r[:, 1] + a[:, 1]
    w, h = r[:, 2], r[:, 3]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    kps = r[:, 4:16].reshape(-1, 6, 2) + a[:, None, :]
    return boxes, kps, scores[keep]


def iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(4,) against (K, 4) x0 y0 x1 y1 -> (K,) intersection over union."""
    ix = np.clip(np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0]), 0, None)
    iy = np.clip(np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1]), 0, None)
    inter = ix * iy
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    union = area + areas - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def weighted_nms(boxes: np.ndarray, keypoints: np.ndarray, scores: np.ndarray,
                 threshold: float | None = None) -> list[int | np.ndarray]:
    """MediaPipe's WEIGHTED non-maximum suppression. boxes (K, 4), keypoints (K, P, 2), scores
    (K,) -> a list of (box (4,), keypoints (P, 2), score, index of the group's best box),
    best first. Each group is the best remaining box and every remaining box whose IoU with it
    is above `threshold`; its box and keypoints are the score-weighted means over the group,
    its score the best box's."""
    threshold = NMS_IOU if threshold is None else threshold
    order = list(np.argsort(-scores, kind="stable"))
    out = []
    while order:
        best = order[0]
        rest = np.array(order)
        sim = iou(boxes[best], boxes[rest])
        group = rest[sim > threshold]
        group = group if best in group else np.concatenate([[best], group])
        wts = scores[group][:, None]
        box = (boxes[group] * wts).sum(0) / wts.sum()
        kp = (keypoints[group] * wts[:, :, None]).sum(0) / wts.sum()
        out.append((box, kp, float(scores[best]), int(best)))
        absorbed = set(group.tolist())
        order = [i for i in order if i not in absorbed]
    return out


def _run_detector(image: np.ndarray, cfg: DetectorConfig, min_score: float):
    """One model on the letterboxed image -> boxes, keypoints (image pixels), scores."""
    model = get_model(cfg.model)
    size = model.input_size[0]
    h, w = image.shape[:2]
    side = float(max(w, h))
    box = Roi((w / 2.0, h / 2.0), side, 0.0)
    # zero padding reads as black (-1), as MediaPipe's letterbox
    x = crop(image, box, size, border="constant") * (2.0 / 255.0) - 1.0
    outs = model.run(x[None])
    raw_boxes = next(o for o in outs if o.shape[-1] == 16).reshape(-1, 16)
    raw_scores = next(o for o in outs if o.shape[-1] == 1).reshape(-1)
    boxes, kps, scores = decode(raw_boxes, raw_scores, _anchors(cfg), size, min_score)
    # input-normalised -> image pixels (the letterbox square is centred on the image)
    off = np.array([w / 2.0 - side / 2, h / 2.0 - side / 2])
    boxes = boxes * side + np.tile(off, 2)
    kps = kps * side + off
    return boxes, kps, scores


def detect_faces(image: np.ndarray, min_score: float | None = None) -> list[Face]:
    """Every face in an (H, W, 3) uint8 RGB image (any size), ordered left to right by box
    centre. Both BlazeFace models run and their detections are merged by weighted NMS.
    min_score: overrides the models' own thresholds (0.5 short, 0.6 full range).
    Raises ModelsMissing when the models or LiteRT are not installed."""
    image = np.asarray(image)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    all_boxes, all_kps, all_scores, source = [], [], [], []
    for name, cfg in (("short", SHORT_RANGE), ("full", FULL_RANGE)):
        b, k, s = _run_detector(image[..., :3], cfg, cfg.min_score if min_score is None else min_score)
        all_boxes.append(b)
        all_kps.append(k)
        all_scores.append(s)
        source += [name] * len(s)
    boxes = np.concatenate(all_boxes)
    if len(boxes) == 0:
        return []
    groups = weighted_nms(boxes, np.concatenate(all_kps), np.concatenate(all_scores))
    faces = [Face(box.astype(np.float32), kp.astype(np.float32), score, source[i])
             for box, kp, score, i in groups]
    faces.sort(key=lambda f: (float(f.center[0]), float(f.center[1])))
    return faces
