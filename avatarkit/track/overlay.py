"""The tracker's preview: the video with the fitted head drawn on it.

Per frame: the fitted head's face-region mesh as a thin wireframe (what the clip will do to an
avatar), the detected face-mesh landmarks as small red dots and the fitted head's landmarks as
green dots (their distance is the landmark error), and the frame number with its confidence
(frames without a face say "interpolated"). The video is read a second time, frame by frame,
so memory stays flat.
"""
from __future__ import annotations

import os
from typing import Callable

import numpy as np

WIRE_ALPHA = 0.3


def _face_edges(model) -> np.ndarray:
    """(K, 2) unique vertex pairs of the triangles in the model's face region (all triangles
    when the model names no face region)."""
    faces = np.asarray(model.faces)
    if "face" in model.regions:
        faces = faces[model.region_faces("face", "majority")]
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def draw_frame(rgb: np.ndarray, vertices_px: np.ndarray | None, edges: np.ndarray,
               fitted_px: np.ndarray | None, detected_px: np.ndarray | None, label: str) -> np.ndarray:
    """Draw on a copy of rgb (H, W, 3) uint8: mesh edges (vertex pixels (V, 2)), fitted (K, 2)
    and detected (K, 2) landmarks, and a text label."""
    import cv2

    out = np.ascontiguousarray(rgb).copy()
    if vertices_px is not None:
        ok = np.isfinite(vertices_px[edges]).all(axis=(1, 2))
        segs = vertices_px[edges[ok]].astype(np.int32)      # (E, 2, 2)
        wire = out.copy()
        cv2.polylines(wire, list(segs), False, (255, 255, 255), 1, cv2.LINE_AA)
        # a see-through wireframe: the face under it stays readable
        out = cv2.addWeighted(wire, WIRE_ALPHA, out, 1.0 - WIRE_ALPHA, 0.0)
    for pts, colour in ((detected_px, (230, 40, 40)), (fitted_px, (40, 220, 60))):
        if pts is None:
            continue
        for x, y in np.asarray(pts)[np.isfinite(pts).all(axis=1)]:
            cv2.circle(out, (int(round(x)), int(round(y))), 1, colour, -1, cv2.LINE_AA)
    cv2.putText(out, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def posed_vertices(model, clip, t: int) -> np.ndarray:
    """(V, 3) world vertices of the head at clip frame t."""
    from avatarkit.head.model import HeadParams

    params = HeadParams.from_clip(clip, frames=[t])
    params.shape = np.asarray(clip.shape, np.float32)
    return model.forward(params)[0][0]


def write_overlay(video_path: str | os.PathLike, result, output: str | os.PathLike, model=None,
                  progress: Callable[[int, int], None] | None = None) -> None:
    """Write the preview of a `TrackResult` over the frames of `video_path` (MP4 or GIF)."""
    from avatarkit.export.video import VideoWriter
    from avatarkit.head.model import HeadModel
    from avatarkit.video import open_video

    if model is None:
        model = result.model if result.model is not None else HeadModel.template()
    edges = _face_edges(model)
    from avatarkit.track.tracker import model_embedding

    # the tracking's own embedding carries the per-video landmark calibration it was fitted with
    emb = result.embedding if model is result.model else None
    if emb is None:
        try:
            emb = model_embedding(model)
        except Exception:
            emb = None
    cam = result.camera
    p = os.fspath(video_path)
    T = result.num_frames
    with open_video(p, fps=30.0 if os.path.isdir(p) else None) as video, \
            VideoWriter(output, fps=result.clip.fps) as writer:
        first, last = int(result.frame_index.min()), int(result.frame_index.max()) + 1
        frames = {}
        t = 0
        for frame in video.frames(first, last):
            frames[frame.index] = frame.rgb
            while t < T and result.frame_index[t] in frames:
                rgb = frames[result.frame_index[t]]
                v = posed_vertices(model, result.clip, t)
                vpx, _ = cam.project(v)
                fitted = emb.points(v, model.faces) if emb is not None else None
                fitted_px = cam.project(fitted)[0] if fitted is not None else None
                detected = result.landmarks[t] if result.found[t] else None
                label = (f"frame {int(result.frame_index[t])}  confidence {result.confidence[t]:.2f}"
                         if result.found[t] else f"frame {int(result.frame_index[t])}  interpolated")
                writer.append(draw_frame(rgb, vpx, edges, fitted_px, detected, label))
                t += 1
                if progress is not None:
                    progress(t, T)
            # keep only the frame a resampled clip may show again
            for k in [k for k in frames if k < frame.index]:
                del frames[k]
