"""Tracker benchmark: accuracy on rendered videos with known motion, landmark error and speed
on the real talking-head clips.

Run: `.venv/bin/python benchmarks/track.py [--frames 48] [--size 480] [--avatar DIR] [--quick]`

Prints
  - synthetic: the template head driven by a mixed clip (turn, nod, talk: the jaw opens)
    rendered at --size, each tracked as rendered and mirrored: median rotation error (degrees),
    jaw error (rad), landmark error (px); next to each, in the same process, the tracker with
    the template's view correction (`TrackOptions(view_correction=True)`, `face.view_correction`:
    calibrated on template renders of seeds disjoint from these; off by default), the tracker
    without its landmark calibration (`TrackOptions(calibration_frames=0)`), the tracker with a
    view correction calibrated on the subject itself (`track.subject_calibration`: the renderer
    that made the video - same head, skin sample and light, or the avatar - at the default
    grid's 45 poses, mirrored for the mirrored video; with and without the landmark
    calibration; what `track --avatar` does with `--subject-calibration`; and the rigid part
    alone of the jaw-closed grid's, `subject_calibration.fit_subject(part="rigid")`, with and
    without the landmark calibration), and the tracker on
    the plain face mesh (`TrackOptions(mirror_landmarks=False)`: not averaged with its mirror
    image, the default before session 9), and ratios.
    The target figure is on the template rendered person-like (`synthetic.shading`: Lambert shading
    from a light fixed to the camera, so it moves over the head with the pose, and a dark mouth
    interior as the jaw opens; the lead's decision of session 7); the flat-coloured renders of
    sessions 4-6 are tracked and printed beside it. With `--avatar DIR` also that avatar (e.g. one
    built by `avatarkit build samples/portrait.jpg -o DIR`: a real face's colours);
  - real videos (../shared/data/videos/*.mp4 beside the checkout, skipped when absent): frames
    tracked, frames with a face, median landmark reprojection error (px; also over the frames
    after the calibration frames alone, which the calibration did not see), the same without
    calibration, the same on the plain face mesh (and the time ratio), frames per second of
    tracking with preview off, and, as the baseline run in the same process, frames per second
    of decoding alone and of the face mesh alone.
Targets (issue 16): <= 2 deg and <= 0.05 rad median on the synthetic videos (the shaded ones);
<= 3 px median at 480x480 on the real videos; >= 15 frames/s on 2 cores.
"""
from __future__ import annotations

import argparse
import glob
import os
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
VIDEOS = os.path.join(HERE, "..", "..", "shared", "data", "videos")


from _timing import cpu_model  # noqa: E402  (run as benchmarks/NAME.py: its folder is on sys.path)
from avatarkit.track.tracker import REFINE_EVERY, REFINE_SETTINGS  # noqa: E402


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


def synthetic(frames: int, size: int, avatar_dir: str | None, flat: bool = True) -> None:
    """The template head (shaded with a mouth interior: the target; flat colours), and the
    avatar in `avatar_dir` if given, each tracked as rendered and mirrored left-right (the
    mirrored truth: rotation vector (x, -y, -z))."""
    from avatarkit.head.model import HeadModel
    from avatarkit.synthetic.head_video import HeadVideo, SyntheticFrame, avatar_video, head_video_camera
    from avatarkit.synthetic.shading import LIGHT
    from avatarkit.track import TrackOptions, track_frames
    from avatarkit.track import subject_calibration as sc
    from avatarkit.track.tracker import model_embedding
    from avatarkit.track.neck import head_rotation

    clip = mixed_clip(frames, 30.0)
    camera = head_video_camera(size, distance=0.55)
    subjects = ["shaded"] + (["flat"] if flat else []) + ([avatar_dir] if avatar_dir else [])
    table = []
    for subject in subjects:
        t0 = time.perf_counter()
        if subject not in ("shaded", "flat"):
            from avatarkit.avatar import load_avatar

            avatar = load_avatar(subject)
            model, shape = avatar.head_model, avatar.shape
            video = list(avatar_video(avatar, clip, camera))
            what = f"avatar {subject}"
        else:
            model = HeadModel.template()
            shape = np.zeros(model.num_shape)
            if subject == "shaded":
                video = list(HeadVideo(clip, camera, light=LIGHT, mouth=True).frames())
                what = "TARGET: template head, Lambert-shaded, dark mouth interior"
            else:
                video = list(HeadVideo(clip, camera).frames())
                what = "template head, flat colours (sessions 4-6)"
        t_render = time.perf_counter() - t0
        print(f"synthetic ({what}, mixed clip, {frames} frames at {size}x{size}; render {t_render:.1f} s):")
        mirrored = [SyntheticFrame(f.index, f.time, np.ascontiguousarray(f.rgb[:, ::-1])) for f in video]
        render = subject_renderer(subject, avatar if subject not in ("shaded", "flat") else None)
        # the head's rotation (global then neck) on both sides: the same whichever joint carries it
        true_head = head_rotation(clip.rotation, clip.neck)
        for view, frames_in, truth, draw in (("as rendered", video, true_head, render),
                                             ("mirrored", mirrored, true_head * np.array([1.0, -1.0, -1.0]),
                                              sc.mirrored(render))):
            # the subject's own calibration: its model (the renderer that made the video; for
            # the mirrored video, its mirror image) at the grid's poses, never the video's frames
            cal = sc.calibrate_subject(draw, model, shape, model_embedding(model), camera.fx, 0.55)
            closed = sc.calibrate_subject(draw, model, shape, model_embedding(model), camera.fx, 0.55,
                                          sc.AVATAR_GRID)
            # the rigid part alone (`subject_calibration.fit_subject(part="rigid")`), from the
            # jaw-closed grid's renders (a jaw opening is not a turn of the head)
            rigid, _ = sc.fit_subject(closed.data, model, shape, model_embedding(model), "rigid")
            for c, g in ((cal, "default grid"), (closed, "jaw-closed grid (track --avatar)")):
                print(f"  {view:11s} own calibration, {g}: {c.found}/{c.renders} renders with a face, render + "
                      f"face mesh {c.seconds[0]:.1f} s at {sc.calibration_camera(camera.fx, 0.55).width} px, fit "
                      f"{c.seconds[1]:.1f} s")
            figures = {}
            for label, options in (("tracker", TrackOptions()),
                                   ("with the view correction",
                                    TrackOptions(view_correction=True)),
                                   ("baseline, no landmark calibration", TrackOptions(calibration_frames=0)),
                                   ("baseline, plain face mesh", TrackOptions(mirror_landmarks=False)),
                                   ("with its own calibration", TrackOptions(view_correction=cal.correction)),
                                   ("own calibration, no landmark calibration",
                                    TrackOptions(view_correction=cal.correction, calibration_frames=0)),
                                   ("own calibration, jaw-closed grid", TrackOptions(view_correction=closed.correction)),
                                   ("own calibration's rigid part, jaw-closed grid", TrackOptions(view_correction=rigid)),
                                   ("own calibration's rigid part, no landmark calibration",
                                    TrackOptions(view_correction=rigid, calibration_frames=0))):
                t0 = time.perf_counter()
                r = track_frames(frames_in, model, shape, (size, size), 30.0, options)
                t_track = time.perf_counter() - t0
                rot = [angle_deg(a, b) for a, b in zip(head_rotation(r.clip.rotation, r.clip.neck), truth)]
                jaw = np.abs(r.clip.jaw[:, 0] - clip.jaw[:, 0])
                figures[label] = (np.median(rot), np.median(jaw), np.nanmedian(r.landmark_error))
                print(f"  {view:11s} {label}: rotation error median {np.median(rot):.2f} deg "
                      f"(p90 {np.percentile(rot, 90):.2f}), jaw error median {np.median(jaw):.3f} rad, "
                      f"landmark error median {np.nanmedian(r.landmark_error):.2f} px, faces found "
                      f"{int(r.found.sum())}/{frames}; track {t_track:.1f} s")
            a, b, c, d, e, g, h, k, m = figures.values()
            table.append((subject, view) + a + b + d + e + h + k + m)
            print(f"  {view:11s} ratios view-corrected/tracker: rotation {b[0] / a[0]:.2f}, jaw {b[1] / a[1]:.2f}, "
                  f"landmarks {b[2] / a[2]:.2f}; tracker/no calibration: rotation {a[0] / c[0]:.2f}, "
                  f"jaw {a[1] / c[1]:.2f}; tracker/plain face mesh: rotation {a[0] / d[0]:.2f}, jaw {a[1] / d[1]:.2f}; "
                  f"own calibration/tracker: rotation {e[0] / a[0]:.2f}, jaw {e[1] / a[1]:.2f}")
    print("synthetic, median over as rendered + mirrored (tracker; with the template's view correction in "
          "brackets; with the subject's own calibration; baseline on the plain face mesh):")
    for subject in subjects:
        t = np.array([row[2:] for row in table if row[0] == subject])
        name = {"shaded": "TARGET shaded + mouth", "flat": "flat colours"}.get(subject, subject)
        print(f"  {name:22s} rotation {np.median(t[:, 0]):.2f} deg ({np.median(t[:, 3]):.2f}), jaw "
              f"{np.median(t[:, 1]):.3f} rad ({np.median(t[:, 4]):.3f}); own calibration {np.median(t[:, 9]):.2f} deg, "
              f"{np.median(t[:, 10]):.3f} rad (jaw-closed grid {np.median(t[:, 12]):.2f} deg, {np.median(t[:, 13]):.3f} rad; "
              f"its rigid part {np.median(t[:, 15]):.2f} deg, {np.median(t[:, 16]):.3f} rad, without the landmark calibration "
              f"{np.median(t[:, 18]):.2f} deg, {np.median(t[:, 19]):.3f} rad); plain face mesh {np.median(t[:, 6]):.2f} deg, "
              f"{np.median(t[:, 7]):.3f} rad   targets <= 2 deg, <= 0.05 rad")


# `refine_columns`' runs: (label, refine every k-th frame (0: the tracker alone), photometric.
# Settings fields); with "jaw": `refine="photometric"`, without: "photometric-pose". Session 14 also ran: the pose alone
# (photometric-pose), the pose from the render's depth, the jaw in 3 or 4 passes from the mesh's points, the
# jaw from the render's depth in 4 passes; session 15: cold and warm starts, 1-3 passes, every 1-6th
# frame, size 160 (docs/tracking.md); session 16: the named speed setting `photometric-fast` (its
# own spacing, `REFINE_EVERY`), given by name as a 4th field
_JAW = REFINE_SETTINGS["photometric"]
REFINE_RUNS = (("tracker", 0, {}),
               ("refined every 1, photometric (the jaw, the render's depth, 3 passes)", 1, _JAW),
               ("refined every 3, photometric", 3, _JAW),
               ("refined every 3, photometric in 1 pass", 3, dict(_JAW, iterations=1)),
               ("refined every 4, photometric in 2 passes", 4, dict(_JAW, iterations=2)),
               ("refined every 6, photometric in 2 passes", 6, dict(_JAW, iterations=2)),
               (f"photometric-fast (every {REFINE_EVERY['photometric-fast']}, "
                f"{REFINE_SETTINGS['photometric-fast']['iterations']} pass(es))",
                REFINE_EVERY["photometric-fast"], REFINE_SETTINGS["photometric-fast"], "photometric-fast"))


def refine_columns(frames: int, size: int, avatar_dir: str, runs=None) -> None:
    """The tracker with and without the photometric pose refinement (`TrackOptions(refine=
    "photometric-pose")`, `track.photometric`), each of `runs` (`REFINE_RUNS`: with the jaw's opening
    (`refine="photometric"`), the points from the render's depth, fewer passes, every k-th
    frame; `photometric.SESSION13` as settings: session 13's first round, its speed baseline),
    in this process, on the avatar's mixed-clip video as rendered and mirrored. The mirrored
    video is
    refined against the avatar as it is (not mirrored): a face that is not quite the avatar's,
    as on a real clip. The template-head videos have no avatar to render: not refined."""
    runs = REFINE_RUNS if runs is None else runs
    from avatarkit.avatar import load_avatar
    from avatarkit.synthetic.head_video import SyntheticFrame, avatar_video, head_video_camera
    from avatarkit.track import TrackOptions, track_frames
    from avatarkit.track.neck import head_rotation
    from avatarkit.track.photometric import PoseRefiner, Settings

    clip = mixed_clip(frames, 30.0)
    camera = head_video_camera(size, distance=0.55)
    avatar = load_avatar(avatar_dir)
    model, shape = avatar.head_model, avatar.shape
    video = list(avatar_video(avatar, clip, camera))
    mirrored = [SyntheticFrame(f.index, f.time, np.ascontiguousarray(f.rgb[:, ::-1])) for f in video]
    true_head = head_rotation(clip.rotation, clip.neck)
    print(f"refinement (avatar {avatar_dir}, mixed clip, {frames} frames at {size}x{size}; load "
          f"{os.getloadavg()[0]:.1f}):")
    rows = {}
    for view, frames_in, truth in (("as rendered", video, true_head),
                                   ("mirrored", mirrored, true_head * np.array([1.0, -1.0, -1.0]))):
        meshes = None
        for label, k, settings, *named in runs:
            # a named setting brings its own spacing (`tracker.refine_spacing`): k is what it is
            refine = named[0] if named else ("photometric" if settings.get("jaw") else "photometric-pose")
            options = TrackOptions(refine=refine if k else None, refine_every=None if named else max(k, 1))
            refiner = PoseRefiner(avatar, camera.fx, (size, size), Settings(**settings)) if k else None
            t0 = time.perf_counter()
            r = track_frames(frames_in, model, shape, (size, size), 30.0, options, meshes=meshes, refiner=refiner)
            t_track = time.perf_counter() - t0
            if meshes is None:
                # the fits alone (the face mesh's points reused), so each refined run's speed can
                # be given with the face mesh's time added: a video tracked from scratch
                t0 = time.perf_counter()
                track_frames(frames_in, model, shape, (size, size), 30.0, TrackOptions(), meshes=r.meshes)
                fits = time.perf_counter() - t0
                mesh_seconds = max(t_track - fits - (r.refinement["seconds"] if r.refinement else 0.0), 0.0)
            meshes = r.meshes
            rot = [angle_deg(a, b) for a, b in zip(head_rotation(r.clip.rotation, r.clip.neck), truth)]
            jaw = np.abs(r.clip.jaw[:, 0] - clip.jaw[:, 0])
            raw = [angle_deg(a, b) for a, b in zip(r.raw["rotation"], truth)]    # before the smoother
            raw_jaw = np.abs(r.raw["jaw"][:, 0] - clip.jaw[:, 0])
            # translation: the clip's world is the view frame less the median head position, so
            # compare the frame-to-frame motion of the head's root (truth: still)
            tr = r.clip.translation - np.median(r.clip.translation, axis=0)
            trn = np.linalg.norm(tr, axis=1) * 1000.0
            rows.setdefault(label, []).append((np.median(rot), np.median(jaw), np.median(trn), t_track))
            extra = "" if r.refinement is None else (f"; refined {r.refinement['frames']} frames, "
                                                     f"{r.refinement['seconds']:.1f} s, residual "
                                                     f"{r.refinement['residual_before_px']:.2f} -> "
                                                     f"{r.refinement['residual_after_px']:.2f} px, "
                                                     f"{r.refinement['renders']:.2f} passes per frame")
            print(f"  {view:11s} {label}: rotation error median {np.median(rot):.2f} deg (p90 "
                  f"{np.percentile(rot, 90):.2f}; before the smoother {np.median(raw):.2f}), jaw {np.median(jaw):.3f} rad (p90 "
                  f"{np.percentile(jaw, 90):.3f}; before the smoother {np.median(raw_jaw):.3f}), root wander median "
                  f"{np.median(trn):.1f} mm, landmark error {np.nanmedian(r.landmark_error):.2f} px; track "
                  f"{t_track:.1f} s ({frames / t_track:.2f} frames/s{', face mesh included' if k == 0 else ''}; "
                  f"{frames / (t_track + (0.0 if k == 0 else mesh_seconds)):.2f} frames/s with the face mesh's "
                  f"{mesh_seconds:.1f} s){extra}",
                  flush=True)
    for label, v in rows.items():
        v = np.array(v)
        print(f"  median over both: {label}: rotation {np.median(v[:, 0]):.2f} deg, jaw {np.median(v[:, 1]):.3f} rad, "
              f"root wander {np.median(v[:, 2]):.1f} mm")


def subject_renderer(subject: str, avatar=None):
    """What rendered the video of `subject`, as a `subject_calibration` renderer: the same head
    renderer with the same skin sample (seed 0) and light, or the avatar's splat renderer."""
    from avatarkit.synthetic.head_video import HeadVideo
    from avatarkit.synthetic.shading import LIGHT
    from avatarkit.track import subject_calibration as sc

    if avatar is not None:
        return sc.rigid_avatar_renderer(avatar)     # the bake's renders; without it for rigid turns
    kw = dict(light=LIGHT, mouth=True) if subject == "shaded" else {}
    return lambda clip, camera: (f.rgb for f in HeadVideo(clip, camera, **kw).frames())


def real(limit: int | None, videos: str | None = None) -> None:
    videos = VIDEOS if videos is None else videos
    from avatarkit.face import face_landmarks
    from avatarkit.track.tracker import CALIBRATION_FRAMES, FrameTracker, TrackOptions
    from avatarkit.track.video import track_video
    from avatarkit.video import open_video

    paths = sorted(glob.glob(os.path.join(videos, "*.mp4")))
    if not paths:
        print(f"real videos: {videos} not found (--videos DIR): skipped")
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
        t0 = time.perf_counter()
        base = track_video(path, end=end, options=TrackOptions(calibration_frames=0))
        t_base = time.perf_counter() - t0
        t0 = time.perf_counter()
        prev = track_video(path, end=end, options=TrackOptions(view_correction=True))
        t_prev = time.perf_counter() - t0
        t0 = time.perf_counter()
        plain = track_video(path, end=end, options=TrackOptions(mirror_landmarks=False))
        t_plain = time.perf_counter() - t0
        held = r.landmark_error[np.cumsum(r.found) > CALIBRATION_FRAMES]
        print(f"{name}: {r.num_frames} frames, face in {int(r.found.sum())}; landmark error median "
              f"{np.nanmedian(r.landmark_error):.2f} px (p90 {np.nanpercentile(r.landmark_error, 90):.2f}; "
              f"frames after the {CALIBRATION_FRAMES} calibration frames {np.nanmedian(held):.2f})   target <= 3 px")
        print(f"  with the view correction: {np.nanmedian(prev.landmark_error):.2f} px "
              f"(ratio {np.nanmedian(prev.landmark_error) / np.nanmedian(r.landmark_error):.2f}), "
              f"{prev.num_frames / t_prev:.1f} frames/s (time ratio view-corrected/tracker {t_prev / t_track:.2f})")
        print(f"  baseline, plain face mesh: {np.nanmedian(plain.landmark_error):.2f} px "
              f"(ratio {np.nanmedian(r.landmark_error) / np.nanmedian(plain.landmark_error):.2f}), "
              f"{plain.num_frames / t_plain:.1f} frames/s (time ratio tracker/plain {t_track / t_plain:.2f})")
        print(f"  baseline, no landmark calibration: {np.nanmedian(base.landmark_error):.2f} px "
              f"(ratio {np.nanmedian(r.landmark_error) / np.nanmedian(base.landmark_error):.2f}), "
              f"{base.num_frames / t_base:.1f} frames/s (time ratio with/without {t_track / t_base:.2f})")
        print(f"  tracking {r.num_frames / t_track:.1f} frames/s (identity fit, decode, mesh, fit, smoothing); "
              f"baselines in this process: decode alone {n / t_decode:.0f} frames/s, face mesh alone "
              f"{n / t_mesh:.1f} frames/s -> tracking costs {t_track / t_mesh:.2f}x the face mesh alone")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", type=int, default=480)
    ap.add_argument("--avatar", help="an avatar folder to render instead of the template head")
    ap.add_argument("--videos", default=VIDEOS, help="folder of the real clips (default ../shared/data/videos "
                    "beside the checkout)")
    ap.add_argument("--real-only", action="store_true", help="only the real clips")
    ap.add_argument("--refine", action="store_true", help="with --avatar: only the tracker with and without "
                    "the photometric pose refinement (`refine_columns`)")
    ap.add_argument("--quick", action="store_true",
                    help="12 synthetic frames at 256 (the shaded video only), 30 real frames")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.size = 12, 256
    print(f"CPU: {cpu_model()}, {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f}")
    if args.refine:
        if not args.avatar:
            ap.error("--refine needs --avatar")
        refine_columns(args.frames, args.size, args.avatar)
        return
    if not args.real_only:
        synthetic(args.frames, args.size, args.avatar, flat=not args.quick)
    real(30 if args.quick else None, args.videos)


if __name__ == "__main__":
    main()
