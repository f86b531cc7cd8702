"""Tracker benchmark: accuracy on rendered videos with known motion, landmark error and speed
on the real talking-head clips.

Run: `.venv/bin/python benchmarks/track.py [--frames 48] [--size 480] [--avatar DIR] [--quick]`

Prints
  - synthetic: the template head (or `--avatar DIR`, e.g. one built from samples/portrait.jpg,
    whose face looks like a face to the face mesh) driven by a mixed clip (turn, nod, talk: the
    jaw opens) rendered at --size: median rotation error (degrees), jaw error (rad), eye-midpoint
    position error (mm);
  - real videos (../shared/data/videos/*.mp4 beside the checkout, skipped when absent): frames
    tracked, frames with a face, median landmark reprojection error (px), frames per second of
    tracking with preview off, and, as the baseline run in the same process, frames per second
    of decoding alone and of the face mesh alone (landmarks without the fit).
Targets (issue 16): <= 2 deg and <= 0.05 rad median on the synthetic videos; <= 3 px median at
480x480 on the real videos; >= 15 frames/s on 2 cores.
"""
from __future__ import annotations

import argparse
import glob
import os
import platform
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
VIDEOS = os.path.join(HERE, "..", "..", "shared", "data", "videos")


def cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def mixed_clip(T: int, fps: float):
    from avatarkit.motion.clip import MotionClip

    t = np.linspace(0, 1, T)
    rot = np.stack([0.15 * np.sin(2 * np.pi * t), 0.35 * np.sin(np.pi * t * 2 + 0.3),
                    0.05 * np.sin(np.pi * t)], axis=1)
    jaw = np.stack([0.22 * np.sin(3 * np.pi * t) ** 2, np.zeros(T), np.zeros(T)], axis=1)
    return MotionClip(fps=fps, rotation=rot, translation=np.zeros((T, 3)), neck=np.zeros((T, 3)),
                      jaw=jaw, eyes=np.zeros((T, 6)), expr=np.zeros((T, 9)))


def angle_deg(a, b) -> float:
    from avatarkit.rotations import axis_angle_to_matrix

    R = axis_angle_to_matrix(a).T @ axis_angle_to_matrix(b)
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def synthetic(frames: int, size: int, avatar_dir: str | None) -> None:
    from avatarkit.head.model import HeadModel
    from avatarkit.synthetic.head_video import HeadVideo, avatar_video, head_video_camera
    from avatarkit.track import TrackOptions, track_frames

    clip = mixed_clip(frames, 30.0)
    camera = head_video_camera(size, distance=0.55)
    t0 = time.perf_counter()
    if avatar_dir:
        from avatarkit.avatar import load_avatar

        avatar = load_avatar(avatar_dir)
        model, shape = avatar.head_model, avatar.shape
        video = list(avatar_video(avatar, clip, camera))
        what = f"avatar {avatar_dir}"
    else:
        model = HeadModel.template()
        shape = np.zeros(model.num_shape)
        video = list(HeadVideo(clip, camera).frames())
        what = "template head"
    t_render = time.perf_counter() - t0
    print(f"synthetic ({what}, mixed clip, {frames} frames at {size}x{size}; render {t_render:.1f} s):")
    figures = {}
    for label, options in (("tracker", TrackOptions()),
                           ("baseline: no landmark calibration", TrackOptions(calibration_frames=0))):
        t0 = time.perf_counter()
        r = track_frames(video, model, shape, (size, size), 30.0, options)
        t_track = time.perf_counter() - t0
        rot = [angle_deg(a, b) for a, b in zip(r.clip.rotation, clip.rotation)]
        jaw = np.abs(r.clip.jaw[:, 0] - clip.jaw[:, 0])
        figures[label] = (np.median(rot), np.median(jaw), np.nanmedian(r.landmark_error))
        print(f"  {label}: rotation error median {np.median(rot):.2f} deg (p90 {np.percentile(rot, 90):.2f}), "
              f"jaw error median {np.median(jaw):.3f} rad, landmark error median "
              f"{np.nanmedian(r.landmark_error):.2f} px, faces found {int(r.found.sum())}/{frames}; "
              f"track {t_track:.1f} s")
    a, b = figures.values()
    print(f"  ratios tracker/baseline: rotation {a[0] / b[0]:.2f}, jaw {a[1] / b[1]:.2f}, landmarks {a[2] / b[2]:.2f}")


def real(limit: int | None) -> None:
    from avatarkit.face import face_landmarks
    from avatarkit.track.tracker import FrameTracker, TrackOptions
    from avatarkit.track.video import track_video
    from avatarkit.video import open_video

    paths = sorted(glob.glob(os.path.join(VIDEOS, "*.mp4")))
    if not paths:
        print("real videos: ../shared/data/videos not found beside the checkout: skipped")
        return
    for path in paths:
        name = os.path.basename(path)
        end = None
        with open_video(path) as v:
            n = v.info.frame_count if limit is None else min(limit, v.info.frame_count)
            end = n
            t0 = time.perf_counter()
            decoded = [f for f in v.frames(0, n)]
            t_decode = time.perf_counter() - t0
            from avatarkit.head.model import HeadModel

            m = HeadModel.template()
            ft = FrameTracker(m, np.zeros(m.num_shape), (v.info.width, v.info.height), TrackOptions())
            t0 = time.perf_counter()
            for f in decoded:
                ft.landmarks(f.rgb)
            t_mesh = time.perf_counter() - t0
        del decoded
        t0 = time.perf_counter()
        r = track_video(path, end=end)
        t_track = time.perf_counter() - t0
        print(f"{name}: {r.num_frames} frames, face in {int(r.found.sum())}; landmark error median "
              f"{np.nanmedian(r.landmark_error):.2f} px (p90 {np.nanpercentile(r.landmark_error, 90):.2f})")
        print(f"  tracking {r.num_frames / t_track:.1f} frames/s (identity fit, decode, mesh, fit, smoothing); "
              f"baselines in this process: decode alone {n / t_decode:.0f} frames/s, face mesh alone "
              f"{n / t_mesh:.1f} frames/s -> tracking costs {t_track / t_mesh:.2f}x the face mesh alone")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", type=int, default=480)
    ap.add_argument("--avatar", help="an avatar folder to render instead of the template head")
    ap.add_argument("--quick", action="store_true", help="12 synthetic frames at 256, 30 real frames")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.size = 12, 256
    print(f"CPU: {cpu_model()}, {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f}")
    synthetic(args.frames, args.size, args.avatar)
    real(30 if args.quick else None)


if __name__ == "__main__":
    main()
