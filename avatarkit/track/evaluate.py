"""Self-reenactment evaluation (`avatarkit evaluate`): build an avatar from one frame of a video,
drive it with the motion tracked from the whole video, render every frame from the tracked
camera and compare with the video.

Steps (`evaluate`):
1. The avatar: given (`avatar=`), built from frame `build_frame` of the video by the portrait
   build (`recon.pipeline.build_avatar`), or (neither given) built from the whole video
   (`track.video_build`, as `avatarkit build VIDEO` does), saved under REPORT_DIR/avatar. With
   `compare_single` the single-frame build of the video build's reference frame is made too
   (REPORT_DIR/avatar_single_frame) and evaluated on the same frames: the summary's
   `single_frame` entry.
2. Track the whole video with that avatar's head model and identity (`track_video(avatar=)`):
   the clip's world is the avatar's world, and the tracked camera sees it as the video did.
   Step 1's tracking with the template head (which chose the build frame, or the video build's
   keyframes) lends its face meshes (`meshes=`: the same result, only the fits run again).
   The clip is aligned to the build frame (`track.build_pose.align_to_build`, as `avatarkit
   track --avatar` does when the avatar was built from this video): eye rotations relative to
   the build frame's (the avatar's eyeballs carry that frame's eyes), head pose relative to the
   build's fit (the build frame is then seen exactly as the build saw it, and the tracked
   motion from there drives the avatar).
3. Bake the clip on the avatar (hair static unless `simulate_hair`), render every frame with the
   tracked camera at the video's resolution on the constant background.
4. Per frame: PSNR and SSIM on the person region (`metrics` module docstring: the render's alpha
   mask, background set to one colour in both), the same on the whole composited frame (both
   computed on the mask's bounding box, `metrics.region_metrics`: the same numbers), and the
   landmark error: the face mesh detected on our render against the one detected on the video
   (median pixels over the 468 points, and that divided by the video face's eye distance).
   Frames within `exclude` frames of the build frame, or of any frame a video build saw (its
   keyframes and the frames its frame_colours stage coloured from, which `evaluate` takes from
   the first `colour_share` of the clip only), are reported but left out of the summary (the
   avatar saw them); the same frames for both builds. LPIPS is not computed: it needs network weights we cannot ship.
5. Outputs in REPORT_DIR: metrics.json (summary + settings), frames.csv (one row per frame),
   side_by_side.mp4 (video | our render | error heat map), written into a temporary folder and
   renamed into place at the end (nothing half-written on failure or Ctrl-C).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from avatarkit.errors import OutputError
from avatarkit.track import metrics
from avatarkit.track.build_pose import align_to_build, recorded_build_frame
from avatarkit.track import neck as _neck
from avatarkit.track.neck import describe, place_head

REPORT_FILES = ("metrics.json", "frames.csv", "side_by_side.mp4")
#: the paper's self-reenactment table (their protocol, see docs/evaluation.md)
PAPER = {"psnr": 20.79, "ssim": 0.864, "lpips": 0.124}
LPIPS_NOTE = "LPIPS is not reported: it needs network weights (AlexNet/VGG) we cannot ship."

Progress = Callable[[str, int, int], None]


@dataclass
class EvalOptions:
    """build_frame: the video frame the avatar is built from (None: chosen from a tracking, or
    unknown with a given avatar); exclude: frames either side of it left out of the summary;
    background: the constant colour (linear RGB in [0, 1]) outside the person mask in both
    images; alpha_threshold: render alpha above which a pixel is the person; simulate_hair: run
    the hair simulation in the bake (default: hair rides the head rigidly); side_by_side: write
    side_by_side.mp4; n_bald, n_hair: Gaussians of the build; subject_calibration: track with a
    view correction calibrated on renders of the avatar (`track.subject_calibration`), of which
    subject_part is used (`TrackOptions.subject_part`); head_on:
    where the tracked head motion goes (`track.neck.place_head`: "neck", the body held at the
    build frame's pose, or "global"); refine: track with the pose refined against each frame by
    rendering the avatar evaluated (`TrackOptions.refine`; None: the landmark fit's pose),
    every `refine_every`-th frame (None: the setting's own,
    `tracker.refine_spacing`)."""

    build_frame: int | None = None
    exclude: int = 5
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    alpha_threshold: float = field(default_factory=lambda: metrics.ALPHA_THRESHOLD)
    simulate_hair: bool = False
    side_by_side: bool = True
    n_bald: int = 40_000
    n_hair: int = 40_000
    compare_single: bool = False
    colour_share: float = 0.5
    subject_calibration: bool = False
    subject_part: str = "full"
    head_on: str = field(default_factory=lambda: _neck.DEFAULT_HEAD_ON)
    # the default drives the avatars with each frame's head pose and jaw refined by rendering the
    # avatar, 2 cheaper passes on every 5th frame: the landmark fit's pose alone (`--refine none`)
    # is ~4 degrees off on the synthetic videos (docs/tracking.md, session 16), so it scored the
    # tracker's bias as much as the avatar; ~15 s more per tracked avatar on a 250-frame clip, and
    # the video build's frame-colours stage registers its frames the same way
    # (`frame_colours.REFINE`; docs/evaluation.md, session 17). cli/evaluate_cmd.py repeats it
    refine: str | None = "photometric-fast"
    refine_every: int | None = None


@dataclass
class FrameMetrics:
    clip_frame: int
    video_frame: int
    excluded: bool
    found: bool               # the tracker found a face in the video frame
    confidence: float
    mask_fraction: float      # share of the frame in the person mask
    psnr: float
    ssim: float
    psnr_full: float
    ssim_full: float
    landmark_error_px: float
    landmark_error_iod: float


@dataclass
class EvalReport:
    frames: list[FrameMetrics]
    summary: dict
    settings: dict
    timings: dict = field(default_factory=dict)


def _median(values) -> float | None:
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], np.float64)
    return float(np.median(a)) if len(a) else None


def _mean(values) -> float | None:
    a = np.asarray([v for v in values if v is not None and math.isfinite(v)], np.float64)
    return float(np.mean(a)) if len(a) else None


def summarise(frames: list[FrameMetrics]) -> dict:
    """Means (and medians) over the frames not excluded; landmark errors as medians."""
    kept = [f for f in frames if not f.excluded]
    out = {"frames": len(frames), "frames_evaluated": len(kept),
           "frames_with_render_face": int(sum(math.isfinite(f.landmark_error_px) for f in kept))}
    for k in ("psnr", "ssim", "psnr_full", "ssim_full"):
        vals = [getattr(f, k) for f in kept]
        out[k] = _mean(vals)
        out[k + "_median"] = _median(vals)
    out["landmark_error_px"] = _median(f.landmark_error_px for f in kept)
    out["landmark_error_iod"] = _median(f.landmark_error_iod for f in kept)
    out["mask_fraction"] = _mean(f.mask_fraction for f in kept)
    out["lpips"] = None
    return out


class MeshFollower:
    """Face meshes of consecutive images: the detector on the first image or after a miss, then
    the region of the previous mesh (as the tracker does)."""

    def __init__(self, min_presence: float = 0.5):
        self.prev = None
        self.min_presence = min_presence

    def __call__(self, rgb: np.ndarray) -> np.ndarray | None:
        from avatarkit.face import detect_faces, face_landmarks, roi_from_mesh

        mesh = None
        if self.prev is not None:
            mesh = face_landmarks(rgb, roi_from_mesh(self.prev))
            if mesh.presence < self.min_presence:
                mesh = None
        if mesh is None:
            faces = detect_faces(rgb)
            if faces:
                faces.sort(key=lambda f: -float(getattr(f, "score", 0.0)))
                mesh = face_landmarks(rgb, faces[0])
                if mesh.presence < self.min_presence:
                    mesh = None
        self.prev = None if mesh is None else np.asarray(mesh.points[:, :2], np.float64)
        return self.prev


def check_report_target(folder: str | os.PathLike) -> Path:
    """The report folder may be new, empty, or an earlier report (then it is replaced)."""
    from avatarkit.fileio import check_output_folder

    p = Path(folder)
    check_output_folder(p.parent if str(p.parent) else Path("."))
    if p.exists():
        if not p.is_dir():
            raise OutputError("report folder is a file", p)
        if any(p.iterdir()) and not (p / "metrics.json").is_file():
            raise OutputError("report folder is not empty and not an earlier report: refusing to replace it", p)
    return p


def compare_frame(video_rgb: np.ndarray, render_rgb: np.ndarray, alpha: np.ndarray,
                  options: EvalOptions) -> tuple[dict, np.ndarray]:
    """Image metrics of one frame (video and render (H, W, 3), render alpha (H, W)) ->
    (values, person mask (H, W)). Both images are composited onto the background outside the
    mask; only inside the mask's bounding box, where anything differs (`metrics.region_metrics`:
    the whole-frame numbers at a fraction of the cost)."""
    mask = metrics.person_mask(alpha, options.alpha_threshold)
    vals = {"mask_fraction": float(mask.mean()),
            **metrics.region_metrics(render_rgb, video_rgb, mask, options.background)}
    return vals, mask


def _build_video(video: str, report: Path, options: EvalOptions,
                 progress: Progress | None, timings: dict) -> tuple[Path, int, list[int], list[int], object]:
    """The whole-video build into report/avatar -> (folder, reference frame, keyframes, the
    frames its frame_colours stage coloured from, the template tracking it chose the keyframes
    from: its face meshes are reused by the second tracking). The frame_colours stage may
    use the first `options.colour_share` of the tracked frames only."""
    from avatarkit.recon.pipeline import BuildOptions, save_avatar
    from avatarkit.track.video_build import build_tracking, build_video_avatar

    build_options = BuildOptions(preview=False, n_bald=options.n_bald, n_hair=options.n_hair)
    t0 = time.perf_counter()
    tracking = build_tracking(video, build_options, (lambda d, t: progress("tracking for the build", d, t))
                              if progress else None)
    timings["choose_frame"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    target = report / "avatar"
    index = np.asarray(tracking.frame_index, np.int64)
    span = (int(index[0]), int(index[min(len(index) - 1, int(math.ceil(options.colour_share * len(index))))]))
    # with the refinement evaluated, the build's frame_colours stage registers its frames by it
    # too (an avatar whose colours were fused on the landmark fit's poses lost its lead over the
    # single-frame build when scored with refined poses: docs/video-build.md, session 13)
    avatar = build_video_avatar(video, build_options, tracking=tracking, colour_span=span,
                                colour_refine=options.refine)
    save_avatar(avatar, target)
    timings["build"] = time.perf_counter() - t0
    src = avatar.provenance["source_video"]
    return (target, int(src["frame"]), [int(k["frame"]) for k in src["keyframes"]],
            [int(f) for f in src.get("colour_frames", [])], tracking)


def _build(video: str, report: Path, frame: int | None, options: EvalOptions,
           progress: Progress | None, timings: dict, name: str = "avatar") -> tuple[Path, int, object]:
    """Build the avatar from one frame into report/name -> (folder, build frame, the template
    tracking that chose the frame or None). The tracking's face meshes are reused by the second
    tracking."""
    from avatarkit.track.build_frame import build_from_video, choose_build_frame
    from avatarkit.track.video import track_video

    t0 = time.perf_counter()
    tracking = None
    if frame is None:
        step = (lambda d, t: progress("choosing the build frame", d, t)) if progress else None
        tracking = track_video(video, progress=step)
        frame = choose_build_frame(tracking)
    timings["choose_frame"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    target = report / name
    index = build_from_video(video, target, frame, n_bald=options.n_bald, n_hair=options.n_hair)
    timings["build"] = time.perf_counter() - t0
    return target, index, tracking


def evaluate(video: str | os.PathLike, report_dir: str | os.PathLike, *,
             avatar: str | os.PathLike | None = None, options: EvalOptions | None = None,
             progress: Progress | None = None) -> EvalReport:
    """Run the evaluation (module docstring) and write its files into `report_dir`.
    progress(stage, done, total) after each unit of work. AvatarKitError on bad input."""
    from avatarkit.fileio import atomic_folder
    from avatarkit.video import open_video

    options = options or EvalOptions()
    video = os.fspath(video)
    target = check_report_target(report_dir)
    with open_video(video) as v:           # a bad video fails here, before any work
        info = v.info
    timings: dict[str, float] = {}
    with atomic_folder(target) as staged:   # tag "partial": swept if a run dies
        build_frame = options.build_frame
        tracking = None
        keyframes: list[int] = []
        colour_frames: list[int] = []
        if avatar is None and build_frame is None:
            avatar_dir, build_frame, keyframes, colour_frames, tracking = _build_video(video, staged, options,
                                                                                       progress, timings)
            built = True
        elif avatar is None:
            avatar_dir, build_frame, tracking = _build(video, staged, build_frame, options, progress, timings)
            built = True
        else:
            avatar_dir, built = Path(avatar), False
            if build_frame is None:
                build_frame = recorded_build_frame(avatar_dir, video)
        t0 = time.perf_counter()
        from avatarkit.track.video import track_video

        step = (lambda d, t: progress("tracking", d, t)) if progress else None
        from avatarkit.track.tracker import TrackOptions, refine_spacing

        track_options = TrackOptions(subject_calibration=options.subject_calibration,
                                     subject_part=options.subject_part, refine=options.refine,
                                     refine_every=options.refine_every)
        result = track_video(video, avatar=avatar_dir, progress=step, options=track_options,
                             meshes=tracking.meshes if tracking is not None else None)
        aligned = align_to_build(result, avatar_dir, build_frame)
        relative, posed = aligned["eyes"], aligned["head_pose"]
        carried = place_head(result, build_frame, options.head_on)
        timings["track"] = time.perf_counter() - t0
        centres = sorted(set(keyframes) | set(colour_frames) | ({build_frame} if build_frame is not None else set()))
        frames, rest = render_and_compare(video, avatar_dir, result, centres or None, options, staged, progress)
        timings.update(rest)
        summary = summarise(frames)
        if options.compare_single:
            if not keyframes:
                from avatarkit.errors import InputError

                raise InputError("comparing with the single-frame build needs the video build "
                                 "(no --avatar, no --build-frame)")
            t0 = time.perf_counter()
            single_dir, _, _ = _build(video, staged, build_frame, options, None, {}, "avatar_single_frame")
            single_result = track_video(video, avatar=single_dir,
                                        progress=(lambda d, t: progress("tracking (single-frame build)", d, t))
                                        if progress else None, meshes=tracking.meshes, options=track_options)
            align_to_build(single_result, single_dir, build_frame)
            place_head(single_result, build_frame, options.head_on)
            single_opts = EvalOptions(**{**asdict(options), "side_by_side": False})
            single_frames, _ = render_and_compare(video, single_dir, single_result, centres, single_opts,
                                                  staged, progress)
            summary["single_frame"] = {k: _json_value(v) for k, v in summarise(single_frames).items()}
            timings["single_frame"] = time.perf_counter() - t0
        settings = {
            "video": os.path.abspath(video), "width": info.width, "height": info.height,
            "fps": result.clip.fps, "avatar": "built (REPORT_DIR/avatar)" if built else os.path.abspath(avatar_dir),
            "build_frame": build_frame, "keyframes": keyframes, "colour_frames": colour_frames,
            "build": ("video (keyframes fused)" if keyframes else "single frame" if built else "given"),
            "exclude": options.exclude,
            "subject_calibration": (None if result.subject_calibration is None else
                                    f"{options.subject_part}, "
                                    f"{result.subject_calibration.found}/{result.subject_calibration.renders} renders, "
                                    f"{sum(result.subject_calibration.seconds):.1f} s"),
            "mask": f"render alpha > {options.alpha_threshold} (same mask for both images)",
            "background": list(options.background),
            "ssim": {k: v for k, v in metrics.SSIM_SETTINGS.items()},
            "hair": "simulated" if options.simulate_hair else "static (rides the head)",
            "eyes": ("tracked gaze relative to the build frame's" if relative else "tracked gaze as it is"),
            "head_pose": ("tracked motion, the build frame posed as the build's fit" if posed
                          else "tracked pose as it is"),
            "head_on": describe(carried),
            "refine": options.refine and f"{options.refine}, every {refine_spacing(track_options)} frame(s)",
            "refinement": result.refinement,
            "lpips": LPIPS_NOTE, "paper": PAPER,
            "tracked_landmark_error_px": _median(result.landmark_error),
        }
        report = EvalReport(frames, summary, settings, timings)
        write_report(staged, report)
    return report


def render_and_compare(video, avatar_dir, result, build_frame, options: EvalOptions,
                       staged: Path, progress: Progress | None = None) -> tuple[list[FrameMetrics], dict]:
    """Bake `result.clip` (a TrackResult) on the avatar, render each frame with `result.camera`,
    compare with the video's frame `result.frame_index[i]`; side_by_side.mp4 into `staged`.
    build_frame: a frame number or a list of them (keyframes) whose neighbours are excluded.
    -> (per-frame metrics, seconds per stage)."""
    from avatarkit.avatar import load_avatar
    from avatarkit.bake import BakeConfig, bake
    from avatarkit.export.images import to_uint8
    from avatarkit.export.video import VideoWriter
    from avatarkit.render import render
    from avatarkit.sim.config import SimConfig
    from avatarkit.video import open_video

    t = {"bake": 0.0, "render": 0.0, "metrics": 0.0, "landmarks": 0.0, "write": 0.0}
    avatar = load_avatar(avatar_dir)
    static, baked = bake(avatar, result.clip, BakeConfig(sim=SimConfig(static=not options.simulate_hair)))
    T = result.num_frames
    index = np.asarray(result.frame_index, np.int64)
    follower = MeshFollower()
    centres = np.asarray([] if build_frame is None else np.atleast_1d(build_frame), np.int64)
    rows: list[FrameMetrics] = []
    writer = VideoWriter(staged / "side_by_side.mp4", fps=result.clip.fps) if options.side_by_side else None
    try:
        with open_video(video) as v:
            source = iter(v.frames(int(index[0]), int(index[-1]) + 1))
            current = next(source)
            it = iter(baked)
            for i in range(T):
                t0 = time.perf_counter()
                frame = next(it)
                g = frame.person(static, avatar.has_hair)
                t1 = time.perf_counter()
                r = render(g, result.camera, options.background)
                t2 = time.perf_counter()
                while current.index < index[i]:
                    current = next(source)
                ours = to_uint8(np.clip(r.rgb, 0, 1))
                vals, mask = compare_frame(current.rgb, ours, r.alpha, options)
                t3 = time.perf_counter()
                mesh = follower(ours)
                video_mesh = result.landmarks[i] if result.found[i] else None
                err = metrics.landmark_error(mesh, video_mesh)
                iod = metrics.interocular(video_mesh) if video_mesh is not None else float("nan")
                t4 = time.perf_counter()
                excluded = bool(len(centres)) and int(np.abs(centres - int(index[i])).min()) <= options.exclude
                rows.append(FrameMetrics(i, int(index[i]), bool(excluded), bool(result.found[i]),
                                         float(result.confidence[i]), vals["mask_fraction"], vals["psnr"],
                                         vals["ssim"], vals["psnr_full"], vals["ssim_full"], err,
                                         err / iod if iod > 0 else float("nan")))
                if writer is not None:
                    # inside the mask the composited video is the video itself
                    heat = metrics.error_heat_map(ours, current.rgb, mask, margin=0)
                    writer.append(np.concatenate([current.rgb, ours, heat], axis=1))
                t5 = time.perf_counter()
                t["bake"] += t1 - t0
                t["render"] += t2 - t1
                t["metrics"] += t3 - t2
                t["landmarks"] += t4 - t3
                t["write"] += t5 - t4
                if progress is not None:
                    progress("rendering and comparing", i + 1, T)
        if writer is not None:
            writer.close()
    except BaseException as e:
        if writer is not None:
            writer.__exit__(type(e), e, e.__traceback__)   # removes the partial file
        raise
    return rows, t


def _json_value(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_report(folder: Path, report: EvalReport) -> None:
    """metrics.json and frames.csv into `folder` (side_by_side.mp4 is written while rendering)."""
    doc = {"summary": {k: _json_value(v) for k, v in report.summary.items()},
           "settings": report.settings, "timings_s": {k: round(v, 3) for k, v in report.timings.items()},
           "lpips": LPIPS_NOTE}
    (folder / "metrics.json").write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")
    buf = io.StringIO()
    names = list(FrameMetrics.__dataclass_fields__)
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(names)
    for f in report.frames:
        row = asdict(f)
        w.writerow([_csv(row[n]) for n in names])
    (folder / "frames.csv").write_text(buf.getvalue())


def _csv(v) -> str:
    if isinstance(v, bool):
        return str(int(v))
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return str(v)
