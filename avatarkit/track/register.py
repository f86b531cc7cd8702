"""Register a video frame the face mesh no longer follows, by analysis by synthesis.

Past ~50-60 degrees of turn the face-mesh landmarks degrade and then vanish (measured on the
synthetic eased turn to 80 degrees at 192 px: the tracker loses the face from ~55-65 degrees
on, docs/video-build.md), so a video build's keyframes never see the back half of the head.
Such a frame is registered against an avatar built from the frames that are well tracked: the
avatar is rendered (our CPU splat renderer) at a candidate head pose over the frame's
background colour, and the pose that best reproduces the frame (mean squared colour error
over the whole image: the silhouette and the colours both count) is kept.

Poses are the tracker's (`track.tracker`, X_view = R X + t, Y-X-Z Euler yaw/pitch/roll as
`track.keyframes.yaw_pitch`), relative to the video build's reference keyframe: a pose P gives
the avatar's rest-frame camera C P M_r^-1 C W_ref, where W_ref is the reference keyframe's
camera (the build's, `provenance.build.camera`), M_r the reference keyframe's pose and C the
OpenCV flip, as `recon.multiview.keyframe_cameras` composes it.

`register_frame` (the fast path): the frame and the camera scaled to `SIZE` pixels, a coarse
search over yaw in a given range (the rest of the pose from the guess), then a pattern search
over yaw, pitch, roll and translation with halving steps. `register_frame_exhaustive` (the slow
obvious reference): every pose of a grid over yaw and pitch at the frame's full size.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from avatarkit.render.camera import Camera

#: the longer side (pixels) the fast path renders and compares at
SIZE = 96
#: coarse yaw step (radians)
COARSE_STEP = math.radians(4.0)
#: the pattern search's first steps: yaw, pitch, roll (radians), translation x, y, z (metres)
REFINE_STEPS = (math.radians(2.0), math.radians(2.0), math.radians(2.0), 0.004, 0.004, 0.01)
#: halvings of the pattern search's steps
REFINE_ROUNDS = 3

_C = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class Registration:
    """pose (4, 4) the head pose found (the tracker's convention, X_view = R X + t); error: the
    mean squared colour error (images in [0, 1]) there; evaluations: renders made; coarse:
    (K, 2) yaw (radians) and error of the coarse search."""

    pose: np.ndarray
    error: float
    evaluations: int
    coarse: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def yaw_pitch_roll(self) -> np.ndarray:
        return params_from_pose(self.pose)[:3]


def pose_from_params(params) -> np.ndarray:
    """(6,) yaw, pitch, roll (radians, Y-X-Z Euler), tx, ty, tz (metres) -> (4, 4) pose."""
    from scipy.spatial.transform import Rotation

    p = np.asarray(params, np.float64)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("YXZ", p[:3]).as_matrix()
    m[:3, 3] = p[3:6]
    return m


def params_from_pose(pose) -> np.ndarray:
    """(4, 4) pose -> (6,) yaw, pitch, roll, tx, ty, tz (the inverse of `pose_from_params`)."""
    from scipy.spatial.transform import Rotation

    m = np.asarray(pose, np.float64)
    return np.concatenate([Rotation.from_matrix(m[:3, :3]).as_euler("YXZ"), m[:3, 3]])


def pose_camera(reference_camera: Camera, reference_pose, pose) -> Camera:
    """The rest avatar's camera for a frame with head pose `pose` (4, 4): C P M_r^-1 C W_ref
    (module docstring)."""
    w2c = _C @ np.asarray(pose, np.float64) @ np.linalg.inv(np.asarray(reference_pose, np.float64)) @ _C \
        @ np.asarray(reference_camera.world_to_camera, np.float64)
    c = reference_camera
    return Camera(c.fx, c.fy, c.cx, c.cy, c.width, c.height, w2c)


def background_colour(image: np.ndarray) -> np.ndarray:
    """(3,) in [0, 1]: the median of the image's border pixels (the wall behind the person).
    image: (H, W, 3) uint8 or float in [0, 1]."""
    im = np.asarray(image)
    im = im.astype(np.float64) / 255.0 if im.dtype == np.uint8 else im.astype(np.float64)
    border = np.concatenate([im[0], im[-1], im[:, 0], im[:, -1]])
    return np.median(border, axis=0)


def photometric_error(gaussians, camera: Camera, target: np.ndarray, background, above: float = 1.0) -> float:
    """Mean squared difference between the render of `gaussians` by `camera` over `background`
    and target (H, W, 3) float in [0, 1] (the camera's size), over the image rows above
    `above` (share of the height from the top: the head without the neck, `register_frame`)."""
    from avatarkit.render import render

    r = render(gaussians, camera, background=tuple(float(x) for x in background))
    rows = max(1, int(round(above * camera.height)))
    return float(np.mean((np.clip(r.rgb[:rows], 0.0, 1.0) - target[:rows]) ** 2))


def _target(image: np.ndarray, size: int | None) -> np.ndarray:
    import cv2

    im = np.asarray(image)
    h, w = im.shape[:2]
    if size is not None and max(h, w) > size:
        k = size / max(h, w)
        im = cv2.resize(im, (max(1, int(round(w * k))), max(1, int(round(h * k)))), interpolation=cv2.INTER_AREA)
    return im.astype(np.float64) / 255.0 if im.dtype == np.uint8 else im.astype(np.float64)


def head_rows(vertices: np.ndarray, neck: np.ndarray | None, camera: Camera) -> float:
    """The share of the image height above the lowest projected head vertex that is not the
    neck's: vertices (V, 3) rest head; neck (V,) bool (None: no neck region); camera: the
    guess's. The neck is left out of the comparison: a person's neck does not turn with the
    head, and a build's neck is the single photo's guess (on the mesh subject the wider built
    neck pulled the registered yaw of an 80-degree frame to 60)."""
    v = np.asarray(vertices, np.float64)
    if neck is not None:
        v = v[~np.asarray(neck, bool)]
    cam = camera.world_to_camera
    x = v @ cam[:3, :3].T + cam[:3, 3]
    front = x[:, 2] > 1e-6
    if not front.any():
        return 1.0
    y = camera.fy * x[front, 1] / x[front, 2] + camera.cy
    return float(np.clip(y.max() / camera.height, 0.0, 1.0))


def register_frame(gaussians, image: np.ndarray, reference_camera: Camera, reference_pose, guess,
                   yaw_range: tuple[float, float], size: int = SIZE, coarse_step: float = COARSE_STEP,
                   steps=REFINE_STEPS, rounds: int = REFINE_ROUNDS, above: float = 1.0) -> Registration:
    """The head pose at which `gaussians` (the avatar at rest) best reproduce `image` (H, W, 3)
    uint8 (module docstring). guess (4, 4): the starting pose (its pitch, roll and translation
    start the search); yaw_range: (lo, hi) radians, the absolute yaws searched (the coarse grid
    and the refinement's bounds);
    above: only the image rows above this share of the height count (`head_rows`)."""
    target = _target(image, size)
    bg = background_colour(target)
    cam0 = reference_camera.with_size(target.shape[1], target.shape[0])
    n = [0]

    def cost(p) -> float:
        n[0] += 1
        return photometric_error(gaussians, pose_camera(cam0, reference_pose, pose_from_params(p)), target, bg,
                                 above)

    start = params_from_pose(guess)
    lo, hi = sorted(yaw_range)
    yaws = np.arange(lo, hi + 1e-9, coarse_step)
    coarse = np.array([[y, cost(np.concatenate([[y], start[1:]]))] for y in yaws])
    best = np.concatenate([[coarse[int(np.argmin(coarse[:, 1])), 0]], start[1:]])
    err = float(coarse[:, 1].min())
    step = np.asarray(steps, np.float64).copy()
    for _ in range(rounds + 1):
        improved = True
        while improved:
            improved = False
            for i in range(6):
                for s in (+step[i], -step[i]):
                    p = best.copy()
                    p[i] += s
                    if i == 0 and not lo <= p[0] <= hi:
                        continue                  # the yaw stays within the range it was given
                    e = cost(p)
                    if e < err - 1e-12:
                        best, err, improved = p, e, True
                        break
        step /= 2.0
    return Registration(pose_from_params(best), err, n[0], coarse)


def register_frame_exhaustive(gaussians, image: np.ndarray, reference_camera: Camera, reference_pose, guess,
                              yaw_range: tuple[float, float], yaw_step: float = math.radians(1.0),
                              pitch_range: float = math.radians(6.0),
                              pitch_step: float = math.radians(2.0), above: float = 1.0) -> Registration:
    """The slow obvious reference of `register_frame`: every (yaw, pitch) of a grid (yaw over
    `yaw_range`, pitch within +-`pitch_range` of the guess's), roll and translation the guess's,
    rendered at the image's own size; the best of them."""
    target = _target(image, None)
    bg = background_colour(target)
    start = params_from_pose(guess)
    lo, hi = sorted(yaw_range)
    best, err, n = start, math.inf, 0
    for y in np.arange(lo, hi + 1e-9, yaw_step):
        for dp in np.arange(-pitch_range, pitch_range + 1e-9, pitch_step):
            p = np.concatenate([[y, start[1] + dp], start[2:]])
            e = photometric_error(gaussians, pose_camera(reference_camera, reference_pose, pose_from_params(p)),
                                  target, bg, above)
            n += 1
            if e < err:
                best, err = p, e
    return Registration(pose_from_params(best), float(err), n)


__all__ = ["COARSE_STEP", "REFINE_ROUNDS", "REFINE_STEPS", "SIZE", "Registration", "background_colour", "head_rows",
           "params_from_pose", "photometric_error", "pose_camera", "pose_from_params", "register_frame",
           "register_frame_exhaustive"]
