"""Keyframes of a tracked video: the few frames a video build fuses (`recon.multiview`).

Choice (`choose_keyframes`), on a tracking of the video (any head, usually the template):

1. Eligible frames: a face found and a confidence at least `MIN_CONFIDENCE_SHARE` of the best.
   Looser than the single-frame choice's 0.8: the tracker's confidence falls with the turn
   (measured on a synthetic turn at 192 px: 0.95 frontal, 0.65-0.78 at 20-26 degrees, below 0.4
   past 30 degrees where its landmark error passes 4% of the image), and the turned frames are
   the point; below ~0.6 the fit is too poor to register a view. The edge of the tracking
   (`tracking_edge`: the frames on the way to a turn the face mesh lost, whose yaw the fit
   under-reads with a confidence that does not show it) is eligible too, and reported
   (`source_video.tracking_edge`): leaving it out measured worse (docs/video-build.md).
2. The reference keyframe is the single-frame build's frame (`build_frame.frame_costs`: most
   frontal, neutral mouth): the portrait build runs on it, so a video whose head never turns
   builds exactly what `build VIDEO --frame N` builds.
3. The others are picked greedily, farthest point in head pose: each next frame maximises
       min over chosen frames of |(yaw, pitch) - (yaw', pitch')| (rad)
       - EXPRESSION_WEIGHT * (2 |jaw| + 0.1 |expression|) - BLUR_WEIGHT * (1 - sharpness)
   where sharpness in [0, 1] is the variance of the Laplacian of the face crop over the best
   frame's (`face_sharpness`); frames within `min_gap` frames of a chosen one are skipped
   (motion blur and tracking noise are shared by neighbours). The choice stops at `count`
   keyframes or when the best frame adds less than `min_spread` of pose: a head that never
   turns gives the reference alone.

Yaw and pitch are the head rotation's Y-X-Z Euler angles (turn left/right, nod up/down): roll
is a rotation of the image and shows nothing new.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from avatarkit.track.neck import clip_head_rotation

#: eligible frames have at least this share of the best confidence (module docstring)
MIN_CONFIDENCE_SHARE = 0.6
#: at most this many keyframes (the reference included)
KEYFRAMES = 6
#: a new keyframe must add at least this much head pose (radians of yaw/pitch, ~8 degrees)
MIN_SPREAD = math.radians(8.0)
#: a lost stretch beside a tracked frame turned at least this much (radians) is a turn past the
#: tracking (the tracker follows to ~40-50 degrees); `tracking_edge` and `video_build.turned_frames`
TURNED_EDGE = math.radians(25.0)
#: the edge of the tracking: frames whose tracked yaw is within this much (radians) of the most
#: turned one read on the way to the lost face (`tracking_edge`)
EDGE_MARGIN = math.radians(6.0)
#: frames this close to a chosen keyframe are not picked (they repeat it)
MIN_GAP = 3
#: radians of pose spread one unit of expression cost is worth (an open jaw of 0.2 rad costs
#: as much as 0.1 rad, ~6 degrees, of new pose)
EXPRESSION_WEIGHT = 0.25
#: radians of pose spread a fully blurred frame (sharpness 0) gives up (~6 degrees)
BLUR_WEIGHT = 0.1
#: the head pose the farthest-point choice measures (`keyframe_pose`): "clip", the tracked clip's
#: (temporally smoothed), or "raw", each frame's own landmark fit (`result.raw["rotation"]`, what
#: `tracking_edge` reads). The smoother rounds off a turn that reverses at full speed: on the
#: 32-frame whip clip (a turn to +-46 degrees at ~275 degrees/s) the mesh subject's -46 end
#: reads -34.8 smoothed and -44.4 raw, so the choice took the frame after it (-42.0, read -36.9)
#: and the ends' neighbours. "clip" (session 26, docs/video-build.md "The whip clip (session
#: 26)"): "raw" leaves the whip's profile gain where it was (the end it takes registers as short)
#: and changes the eased clips' choice, the held-out bob's -45 view -0.47 dB, the mesh subject's
#: front -0.13
KEYFRAME_POSE = "clip"


@dataclass
class Keyframes:
    """clip_index (K,) int: rows of the tracking; frame_index (K,) int: video frame numbers;
    reference: position (in these arrays) of the reference keyframe (always 0); yaw_pitch (K, 2)
    radians; sharpness (K,) in [0, 1]."""

    clip_index: np.ndarray
    frame_index: np.ndarray
    yaw_pitch: np.ndarray
    sharpness: np.ndarray
    reference: int = 0

    def __len__(self) -> int:
        return len(self.clip_index)

    def summary(self) -> list[dict]:
        return [{"frame": int(f), "yaw_deg": round(math.degrees(float(yp[0])), 2),
                 "pitch_deg": round(math.degrees(float(yp[1])), 2), "sharpness": round(float(s), 3)}
                for f, yp, s in zip(self.frame_index, self.yaw_pitch, self.sharpness)]


def yaw_pitch(rotation: np.ndarray) -> np.ndarray:
    """rotation (T, 3) axis-angle -> (T, 2) radians: yaw (about +Y) and pitch (about +X)."""
    from scipy.spatial.transform import Rotation

    r = np.asarray(rotation, np.float64).reshape(-1, 3)
    euler = Rotation.from_rotvec(r).as_euler("YXZ")          # (T, 3): yaw, pitch, roll
    return euler[:, :2]


def expression_cost(result) -> np.ndarray:
    """(T,) 2 |jaw| + 0.1 |expression coefficients| (the single-frame choice's mouth terms)."""
    clip = result.clip
    return 2.0 * np.linalg.norm(clip.jaw, axis=1) + 0.1 * np.linalg.norm(clip.expr, axis=1)


def face_sharpness(rgb: np.ndarray, landmarks: np.ndarray | None) -> float:
    """Variance of the Laplacian of the grey face crop (the landmarks' bounding box, at most
    128 px across so the figure does not grow with the resolution); 0 without landmarks."""
    import cv2

    if landmarks is None or not np.isfinite(landmarks).all():
        return 0.0
    h, w = rgb.shape[:2]
    x0, y0 = np.floor(landmarks.min(axis=0)).astype(int)
    x1, y1 = np.ceil(landmarks.max(axis=0)).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return 0.0
    crop = cv2.cvtColor(np.ascontiguousarray(rgb[y0:y1, x0:x1]), cv2.COLOR_RGB2GRAY)
    k = min(1.0, 128.0 / max(crop.shape))
    if k < 1:
        crop = cv2.resize(crop, None, fx=k, fy=k, interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(crop.astype(np.float32), cv2.CV_32F).var())


def eligible_frames(result) -> np.ndarray:
    """(T,) bool: a face found and a confidence at least `MIN_CONFIDENCE_SHARE` of the best."""
    conf = np.where(result.found, np.asarray(result.confidence, np.float64), 0.0)
    return conf >= MIN_CONFIDENCE_SHARE * conf.max() if conf.max() > 0 else np.zeros(len(conf), bool)


def ineligible_stretches(ok: np.ndarray) -> list[tuple[int, int]]:
    """The maximal runs of False in ok (T,) bool, as half-open (start, stop) frame ranges."""
    ok = np.asarray(ok, bool)
    d = np.diff(np.r_[0, (~ok).astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def tracking_edge(result) -> np.ndarray:
    """(T,) bool: the eligible frames at the edge of a turn the face mesh lost, whose tracked
    yaw is not to be trusted although their confidence is.

    Approaching a turn past the face mesh's reach (~55-65 degrees), the landmark fit's yaw
    saturates: it reads a plateau a few degrees wide while the head turns on, and the fit's
    residual and the mesh's presence barely move, so the confidence stays 0.6-0.8 of the best
    (the mesh subject's eased turn at 192 px: true 53 / 60 / 61 / 55 degrees read 48 / 48 / 48 /
    47 at 0.80 / 0.74 / 0.61 / 0.80; the sample avatar with bob hair: true 60 read 31 at 0.60;
    measured per frame, neither the face outline's residual nor the inner points' separates
    these from well-read frames at 40 degrees). What shows it is where they are: next to
    frames without a face. So, beside every stretch of frames that are not eligible
    (`eligible_frames`) and hold a frame without a face, walk away over the eligible frames on
    the turned side (the first one turned at least `TURNED_EDGE`) while their tracked yaw
    (the per-frame fit's, `raw`) stays within `EDGE_MARGIN` of the most turned one read so
    far in the walk; those frames are the edge. A video that never loses the face (the real
    clips, the 46-degree whip clip) has no edge. The video build reports it
    (`source_video.tracking_edge`) and still takes such frames as keyframes (`choose_keyframes`)."""
    ok = eligible_frames(result)
    found = np.asarray(result.found, bool)
    yaw = yaw_pitch(np.asarray(result.raw["rotation"]))[:, 0]
    T = len(ok)
    edge = np.zeros(T, bool)
    for a, t in ineligible_stretches(ok):
        if found[a:t].all():
            continue                    # a confidence dip, not a face the mesh lost
        for i, step in ((a - 1, -1), (t, 1)):
            if not (0 <= i < T and ok[i]) or abs(yaw[i]) < TURNED_EDGE:
                continue
            side, peak = np.sign(yaw[i]), 0.0
            while 0 <= i < T and ok[i] and np.sign(yaw[i]) == side:
                peak = max(peak, abs(yaw[i]))
                if abs(yaw[i]) < peak - EDGE_MARGIN:
                    break
                edge[i] = True
                i += step
    return edge


def keyframe_pose(result) -> np.ndarray:
    """(T, 2) radians: the yaw and pitch the keyframe choice measures (`KEYFRAME_POSE`, read at
    call time); "raw" falls back to the clip's where a frame's own fit is missing or not finite."""
    pose = yaw_pitch(clip_head_rotation(result.clip))
    if KEYFRAME_POSE == "raw" and getattr(result, "raw", None) is not None and "rotation" in result.raw:
        raw = yaw_pitch(np.asarray(result.raw["rotation"], np.float64))
        ok = np.isfinite(raw).all(axis=1) & np.asarray(result.found, bool)
        pose = np.where(ok[:, None], raw, pose)
    elif KEYFRAME_POSE not in ("clip", "raw"):
        raise ValueError(f"keyframes.KEYFRAME_POSE must be 'clip' or 'raw', got {KEYFRAME_POSE!r}")
    return pose


def choose_keyframes(result, sharpness: np.ndarray | None = None, count: int | None = None,
                     min_spread: float | None = None, min_gap: int | None = None) -> Keyframes:
    """Keyframes of a `TrackResult` (module docstring). sharpness: (T,) raw face sharpness per
    clip frame (`face_sharpness`; None: all equal)."""
    count = KEYFRAMES if count is None else count
    min_spread = MIN_SPREAD if min_spread is None else min_spread
    min_gap = MIN_GAP if min_gap is None else min_gap
    from avatarkit.track.build_frame import frame_costs

    T = result.num_frames
    base = frame_costs(result)                       # inf where the single-frame choice would not take it
    # the edge of the tracking (`tracking_edge`) stays eligible: left out, its frames took the
    # side views from the first build the frames past the tracking register against (session
    # 10: the held-out bob's profile gain +1.68 -> +1.26 dB), docs/video-build.md
    eligible = eligible_frames(result)
    pose = keyframe_pose(result)
    s = np.ones(T) if sharpness is None else np.asarray(sharpness, np.float64).reshape(T)
    top = s[eligible].max() if eligible.any() else 0.0
    sharp = np.clip(s / top, 0.0, 1.0) if top > 0 else np.ones(T)
    # the reference: the single-frame build's frame (ties to the sharper one)
    ref = int(np.argmin(np.where(np.isfinite(base), base - 1e-6 * sharp, np.inf)))
    penalty = EXPRESSION_WEIGHT * expression_cost(result) + BLUR_WEIGHT * (1.0 - sharp)
    chosen = [ref]
    frames = np.arange(T)
    while len(chosen) < count:
        d = np.min(np.linalg.norm(pose[:, None] - pose[chosen][None], axis=2), axis=1)      # (T,)
        near = np.min(np.abs(frames[:, None] - np.asarray(chosen)[None]), axis=1) < min_gap
        score = np.where(eligible & ~near, d - penalty, -np.inf)
        best = int(np.argmax(score))
        if not np.isfinite(score[best]) or d[best] < min_spread or score[best] <= 0:
            break
        chosen.append(best)
    idx = np.asarray(chosen, np.int64)
    return Keyframes(idx, np.asarray(result.frame_index, np.int64)[idx], pose[idx], sharp[idx], 0)


def video_sharpness(video, result) -> np.ndarray:
    """(T,) `face_sharpness` of every tracked frame, in one pass over the video (frames are
    matched by `result.frame_index`)."""
    from avatarkit.video import open_video

    index = np.asarray(result.frame_index, np.int64)
    where = {}
    for t, f in enumerate(index):
        where.setdefault(int(f), []).append(t)
    out = np.zeros(len(index))
    with open_video(video) as v:
        for frame in v.frames(int(index.min()), int(index.max()) + 1):
            for t in where.get(int(frame.index), ()):
                if result.found[t]:
                    out[t] = face_sharpness(frame.rgb, result.landmarks[t])
    return out


def read_frames(video, frame_index) -> dict[int, np.ndarray]:
    """Video frame number -> (H, W, 3) uint8 for the given frames, in one pass."""
    from avatarkit.video import open_video

    want = sorted({int(f) for f in frame_index})
    out: dict[int, np.ndarray] = {}
    with open_video(video) as v:
        for frame in v.frames(want[0], want[-1] + 1):
            if int(frame.index) in want:
                out[int(frame.index)] = frame.rgb
    return out


__all__ = ["EDGE_MARGIN", "KEYFRAME_POSE", "KEYFRAMES", "TURNED_EDGE", "Keyframes", "choose_keyframes", "eligible_frames",
           "face_sharpness", "ineligible_stretches", "keyframe_pose", "read_frames", "tracking_edge", "video_sharpness", "yaw_pitch"]
