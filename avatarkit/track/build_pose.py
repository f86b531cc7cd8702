"""A tracked clip re-posed so that the avatar's build frame is seen exactly as the build saw it.

The portrait build fits the head to its image and projects the image onto the Gaussians from
that fit's pose (the avatar's provenance keeps it: `build.camera.world_to_camera`,
X_cam = C (R_f X + t_f), C = diag(1, -1, -1), X in the avatar's rest frame). The tracker fits
the same frame of the video on its own (other landmark weights, the per-landmark calibration,
a smoothed clip) and lands elsewhere: on talking_man_glasses.mp4's frame 26, 6.9 degrees and
34 mm away (mostly in depth). Driven by the tracked pose, the avatar never shows its own
build frame as the photo did, and every frame carries that offset.

`relative_to_build` keeps the tracked motion and removes the offset: with the tracked view
transform of the build frame (R_b, t_b), each frame's head transform X -> R_t X + t_t becomes
X -> R_t (D_R X + D_t) + t_t with D_R = R_b^T R_f and D_t = R_b^T (t_f - t_b), a fixed move of
the head in its own frame; at the build frame it gives the build's pose exactly, and the
motion between any two frames (R_s R_t^T in the head's frame) is unchanged.

`align_to_build` applies this and the eyes' counterpart (`gaze.relative_eyes`) to a tracked
result: `avatarkit evaluate` always, `avatarkit track --avatar` when the avatar's provenance says it
was built from the tracked video (`recorded_build_frame`).

Clip convention (`track.tracker`): the world is the view frame shifted by o (the tracked
camera: world_to_camera = [C | C o]) and the head turns about its root joint J0, so the
clip's translation is tau = t - o - J0 + R J0.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from avatarkit.rotations import axis_angle_to_matrix, matrix_to_axis_angle

_C = np.diag([1.0, -1.0, -1.0])


def relative_to_build(rotation: np.ndarray, translation: np.ndarray, row: int, camera_w2c: np.ndarray,
                      build_w2c: np.ndarray, joint0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotation (T, 3), translation (T, 3)) float64 of a tracked clip (axis-angle rotation
    (T, 3), translation (T, 3)) re-posed so that clip row `row` is seen by the tracked camera
    (camera_w2c (4, 4)) as the build's camera (build_w2c (4, 4)) saw the avatar's rest head
    (module docstring); joint0 (3,): the avatar's root joint at rest."""
    rot = np.asarray(rotation, np.float64).reshape(-1, 3)
    tau = np.asarray(translation, np.float64).reshape(-1, 3)
    J0 = np.asarray(joint0, np.float64).reshape(3)
    o = _C @ np.asarray(camera_w2c, np.float64)[:3, 3]
    wb = np.asarray(build_w2c, np.float64)
    Rf, tf = _C @ wb[:3, :3], _C @ wb[:3, 3]
    R = axis_angle_to_matrix(rot).astype(np.float64)                     # (T, 3, 3)
    tb = tau[row] + o + J0 - R[row] @ J0                                  # tracked view translation
    DR = R[row].T @ Rf
    Dt = R[row].T @ (tf - tb)
    new_rot = matrix_to_axis_angle(R @ DR).astype(np.float64)
    new_tau = tau + np.einsum("tij,j->ti", R, Dt + DR @ J0 - J0)
    return new_rot, new_tau


def view_transforms(rotation: np.ndarray, translation: np.ndarray, camera_w2c: np.ndarray,
                    joint0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R (T, 3, 3), t (T, 3)): X_view = R X + t of a clip's frames (for tests and checks)."""
    R = axis_angle_to_matrix(np.asarray(rotation, np.float64).reshape(-1, 3)).astype(np.float64)
    J0 = np.asarray(joint0, np.float64).reshape(3)
    o = _C @ np.asarray(camera_w2c, np.float64)[:3, 3]
    t = np.asarray(translation, np.float64).reshape(-1, 3) + o + J0 - R @ J0
    return R, t


def eyes_from_build_frame(result, frame: int | None) -> bool:
    """Make the tracked clip's eye rotations relative to the build frame's (`gaze.relative_eyes`:
    the avatar's eyeballs carry that frame's eyes). False (clip unchanged) when the build frame
    is unknown or not in the clip. The change of gaze is scaled by `gaze.RELATIVE_GAIN`."""
    from avatarkit.track import gaze

    rows = np.flatnonzero(np.asarray(result.frame_index) == frame) if frame is not None else []
    if len(rows) == 0:
        return False
    eyes = np.asarray(result.clip.eyes)
    result.clip.eyes = gaze.relative_eyes(eyes, eyes[int(rows[0])], gaze.RELATIVE_GAIN).astype(eyes.dtype)
    return True


def pose_from_build(result, avatar_dir: Path, frame: int | None) -> bool:
    """Re-pose the tracked clip so that the build frame is seen as the avatar's build saw it
    (`track.build_pose`: the tracked motion kept, the offset between the build's fit and the
    tracker's removed). False (clip unchanged) when the build frame is unknown or not in the
    clip, or the avatar's provenance has no build camera."""
    from avatarkit.avatar import load_avatar_head, read_manifest
    from avatarkit.head.model import HeadParams
    from avatarkit.track.build_pose import relative_to_build

    rows = np.flatnonzero(np.asarray(result.frame_index) == frame) if frame is not None else []
    camera = (read_manifest(avatar_dir).get("provenance", {}).get("build", {}).get("camera") or {})
    w2c = camera.get("world_to_camera")
    if len(rows) == 0 or w2c is None or camera.get("convention", "opencv") != "opencv":
        return False
    model, shape, _, _ = load_avatar_head(avatar_dir)
    params = HeadParams(shape=np.asarray(shape, np.float32), expr=np.zeros((1, model.num_expr), np.float32))
    joint0 = model.rest_joints(params)[0][0]
    clip = result.clip
    rot, tau = relative_to_build(clip.rotation, clip.translation, int(rows[0]), result.camera.world_to_camera,
                                 np.asarray(w2c, np.float64), joint0)
    clip.rotation = rot.astype(np.asarray(clip.rotation).dtype)
    clip.translation = tau.astype(np.asarray(clip.translation).dtype)
    return True


def recorded_build_frame(avatar_dir: Path, video: str) -> int | None:
    """The frame of `video` the avatar was built from, when its provenance says so
    (`build VIDEO --frame`), else None."""
    from avatarkit.avatar import read_manifest

    src = read_manifest(avatar_dir).get("provenance", {}).get("source_video") or {}
    same = src.get("video") and os.path.abspath(src["video"]) == os.path.abspath(video)
    return int(src["frame"]) if same and isinstance(src.get("frame"), int) else None


def align_to_build(result, avatar_dir: str | os.PathLike, frame: int | None) -> dict:
    """Make a clip tracked with an avatar's head model (`track_video(avatar=)`) drive that avatar
    as its build saw frame `frame` (None: not aligned): eyes relative to that frame's gaze
    (`eyes_from_build_frame`) and head pose relative to the build's fit (`pose_from_build`).
    Changes `result.clip` in place. Returns what was applied: {"frame", "eyes", "head_pose"}."""
    eyes = eyes_from_build_frame(result, frame)
    pose = pose_from_build(result, Path(avatar_dir), frame)
    return {"frame": frame if (eyes or pose) else None, "eyes": eyes, "head_pose": pose}
