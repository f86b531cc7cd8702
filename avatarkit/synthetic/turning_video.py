"""A known avatar turning its head, as a video: ground truth for the video build (`track.video_build`).

`eased_turning_clip`: the head turns left to near-profile, right to near-profile, back and up,
easing in and out of each turn and pausing at its ends, the way docs/video-build.md asks people
to record (a slow turn, a neutral face): the video the benchmark builds. `turning_clip`: the
older, faster clip (a linear whip to +-46 degrees and straight back, ~275 degrees/s at 32
frames), kept for comparison with earlier figures. `novel_view_psnr` compares renders of a built avatar with
renders of the known one at rest from fixed cameras around the head (front, three-quarter,
profile): both avatars live in the template head's rest frame, so the same camera sees both.
"""
from __future__ import annotations

import math

import numpy as np

#: azimuths (degrees) of the comparison views: front, three-quarter, profile, both sides
VIEW_AZIMUTHS = (0.0, 45.0, -45.0, 90.0, -90.0)


def turning_clip(frames: int = 32, yaw: float = 0.8, pitch: float = 0.3, fps: float = 24.0):
    """A MotionClip: front -> `yaw` rad left -> `yaw` right -> front -> `pitch` up, jaw closed."""
    from avatarkit.motion.clip import MotionClip

    n = frames
    a, b = n * 3 // 8, n * 3 // 4
    y = np.concatenate([np.linspace(0, yaw, n // 8 + 1)[:-1], np.linspace(yaw, -yaw, a - n // 8 + 1)[:-1],
                        np.linspace(-yaw, 0, b - a + 1)[:-1], np.zeros(n - b)])
    p = np.concatenate([np.zeros(b), np.linspace(0, pitch, n - b)])
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("YXZ", np.stack([y, -p, np.zeros(n)], axis=1)).as_rotvec()
    z = np.zeros((n, 3))
    return MotionClip(fps=fps, rotation=rot, translation=z.copy(), neck=z.copy(), jaw=z.copy(),
                      eyes=np.zeros((n, 6)), expr=np.zeros((n, 10)), name="turn")


def eased_turning_clip(frames: int = 96, yaw: float = math.radians(80.0), pitch: float = 0.3,
                       fps: float = 24.0, hold: float = 0.06):
    """A MotionClip: front -> `yaw` rad left -> `yaw` right -> front -> `pitch` up, jaw closed.
    Each move eases in and out (half a cosine), and the head pauses `hold` of the clip at each
    turn's end, as a person turns (a whip that reverses at full speed is what a smoother rounds
    off). Share of the frames: to the left 0.18, pause, across 0.30, pause, back 0.18, up 0.22."""
    from avatarkit.motion.clip import MotionClip

    n = int(frames)
    # (start, end) of each move in yaw, pitch; widths are shares of the clip
    moves = [(0.18, (0.0, yaw), (0.0, 0.0)), (hold, (yaw, yaw), (0.0, 0.0)),
             (0.30, (yaw, -yaw), (0.0, 0.0)), (hold, (-yaw, -yaw), (0.0, 0.0)),
             (0.18, (-yaw, 0.0), (0.0, 0.0)), (None, (0.0, 0.0), (0.0, pitch))]
    t = (np.arange(n) + 0.5) / n                                  # (n,) clip time in (0, 1)
    y, p = np.zeros(n), np.zeros(n)
    start = 0.0
    for width, (y0, y1), (p0, p1) in moves:
        end = 1.0 if width is None else start + width
        span = max(end - start, 1e-9) if width is not None else 0.22
        u = np.clip((t - start) / span, 0.0, 1.0)
        ease = 0.5 - 0.5 * np.cos(np.pi * u)                     # 0 -> 1, zero speed at both ends
        inside = (t >= start) & (t < end)
        y[inside] = (y0 + (y1 - y0) * ease)[inside]
        p[inside] = (p0 + (p1 - p0) * ease)[inside]
        start = end
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_euler("YXZ", np.stack([y, -p, np.zeros(n)], axis=1)).as_rotvec()
    z = np.zeros((n, 3))
    return MotionClip(fps=fps, rotation=rot, translation=z.copy(), neck=z.copy(), jaw=z.copy(),
                      eyes=np.zeros((n, 6)), expr=np.zeros((n, 10)), name="eased turn")


def write_turning_video(avatar, path, size: int = 192, frames: int = 32, distance: float = 0.5,
                        clip=None, background=(1.0, 1.0, 1.0)):
    """Render `avatar` driven by `turning_clip` (or `clip`) to an H.264 video at `path`, over
    `background` (an (r, g, b) colour or a (size, size, 3) image, `synthetic.walls`); returns
    the clip."""
    from avatarkit.export.video import write_video
    from avatarkit.synthetic.head_video import avatar_video, head_video_camera

    clip = clip or turning_clip(frames)
    camera = head_video_camera(size, distance=distance)
    write_video(path, [f.rgb for f in avatar_video(avatar, clip, camera, background)], fps=clip.fps, crf=12)
    return clip


def novel_view_psnr(built, truth, size: int = 192, azimuths=None,
                    background=(1.0, 1.0, 1.0)) -> dict[float, float]:
    """Azimuth (degrees) -> PSNR (dB) of `built` rendered at rest against `truth`, over the
    pixels either render covers (alpha > 0.5 in either), both on `background`. The cameras
    frame the truth's head (its bald Gaussians' bounds) from 0.6 m."""
    azimuths = VIEW_AZIMUTHS if azimuths is None else azimuths
    from avatarkit.recon.assemble import psnr
    from avatarkit.render import render
    from avatarkit.render.views import frame_camera, scene_bounds

    gt = truth.rest_gaussians()
    ours = built.rest_gaussians()
    bounds = scene_bounds(truth.bald)
    out = {}
    for az in azimuths:
        cam = frame_camera(bounds, az, 0.0, width=size, height=size)
        a = render(gt, cam, background)
        b = render(ours, cam, background)
        mask = (a.alpha > 0.5) | (b.alpha > 0.5)
        out[float(az)] = float(psnr(b.rgb, a.rgb, mask))
    return out
