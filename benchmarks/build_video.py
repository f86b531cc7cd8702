"""Video build benchmark: the whole-video build against the single-frame build (its baseline,
run in the same process).

Run: `.venv/bin/python benchmarks/build_video.py [--size 192] [--clip eased|whip] [--frames N] [--skip-real]
[--quick] [--style short|bob|...] [--subject both|avatar|mesh] [--seed N] [--wall white|dark|colour|clutter]
[--set MODULE.NAME=VALUE ...] [--no-multiview-hair] [--no-register] [--facing-refine]`; `AVATARKIT_HAIR_END=0|1` (the lifter's hair end from the turned keyframes,
`recon.hair_end`) and `AVATARKIT_GROW_BARE=0|1` (the hull's growth over bare scalp) switch the
two session-12 options, both off by default; `AVATARKIT_OPEN_MOUTH=0|1` the teeth and parted lips
(`recon.mouth`, session 14, off), `AVATARKIT_HAIR_OUTLINE=0|1` the hair's outline fitted to
the keyframes' silhouettes (`recon.hair_outline`, session 14, on) and
`AVATARKIT_OUTLINE_POSES=tracked|registered|registered-all` which stages use the turned keyframes'
poses registered against the draft build (`track.video_build.OUTLINE_POSES`);
`AVATARKIT_COLOUR_REFINE=none|photometric-fast|photometric` the refinement that registers the
frame-colours stage's frames in the timed build (`track.frame_colours.REFINE`, photometric-fast
since session 17; the real clips' `evaluate` hands its own, `EvalOptions.refine`)

Prints
  - synthetic: the sample avatar turning its head (`synthetic.turning_video`: `--clip eased`, the
    default, an eased turn to +-80 degrees and up in 96 frames, the video docs/video-build.md asks
    people to record; `--clip whip`, the 32-frame clip to +-46 degrees at ~275 degrees/s that
    sessions 5-8 measured on), built from the
    whole video and from the video build's reference frame alone; PSNR of each build's rest
    render against the known avatar's at front, three-quarter and profile views, and the
    video build's gain (target: profile >= +3 dB), both renders over white (the score) and,
    beside it, over black (session 27: each background hides a different error); how much hair shell the keyframes grew and how
    many strand directions they set (`--no-multiview-hair` turns both off). Each build runs in its
    own process (`_in_own_process`);
  - synthetic, mesh subject (`synthetic.mesh_head`: the template mesh with a procedural texture
    and a hair-cap mesh, drawn by a z-buffer rasteriser, not by our splatting): the same two
    builds of its turning video and the same views against its own rasterised rest renders
    (`--subject` picks one of the two synthetic subjects; default both);
  - real clips (../shared/data/videos/*.mp4 beside the checkout, skipped when absent):
    `evaluate --compare-single` (self-reenactment on the held-out frames: keyframes +-5
    excluded for both builds): PSNR / SSIM of the video build and the single-frame build and
    the gain (target >= +1 dB);
  - time: the video build of the largest real clip (250 frames 480x480: target <= 120 s on 2
    cores) wall and CPU seconds, per stage, and the single-frame build of one of its frames
    (the ratio is the video build's cost over it). The shared clips barely turn (one
    keyframe), so `--time-synthetic` times a 250-frame 480x480 synthetic turning video too,
    where every multi-view stage runs; `--time-phone` times the mesh subject's 250-frame
    480x480 turning video and the same frames at a phone's size (`synthetic.phone_video`:
    1080x1920 portrait at 30 fps, stored landscape with a display matrix, H.264 High) in the same
    process, the ratio of the two and the process's peak memory after each (session 28).
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import tempfile
import time

os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
VIDEOS = os.path.join(HERE, "..", "..", "shared", "data", "videos")


from _timing import cpu_model, peak_rss_mb  # noqa: E402  (run as benchmarks/NAME.py: its folder is on sys.path)


def _score(kind: str, path: str, png: str | None, counts: tuple[int, int], style: str, size: int,
           multiview_hair: bool, subject: str = "avatar", register: bool = True, seed: int = 0,
           switches: tuple[str, ...] = ()) -> tuple[dict, dict, float, dict]:
    """One build of the synthetic video (kind "video") or of its reference frame ("single") and
    its novel-view PSNR against the known avatar: (psnr by azimuth over white, provenance, wall s,
    psnr by azimuth over black). White is the benchmark's score since session 5; black (the web
    player's background) is printed beside it because a white score cannot see Gaussians in a
    white wall's colour (session 27: wall-coloured discs on the white mesh subject's cheek). Run in a
    fresh process: a build made after another one in the same process used to measure
    differently (GrabCut drew from OpenCV's global RNG; `recon.segment` now resets it), and a
    process of its own keeps any other state from leaking between the two builds."""
    from avatarkit.recon import pipeline
    from avatarkit.recon.pipeline import BuildOptions, build_avatar
    from avatarkit.synthetic.sample_avatar import make_sample_avatar
    from avatarkit.synthetic.turning_video import novel_view_psnr
    from avatarkit.track import video_build
    from avatarkit.track.video_build import build_video_avatar

    from _switches import apply_switches

    video_build.REGISTER_TURNED = register
    video_build.REGISTER_MODE = os.environ.get("AVATARKIT_REGISTER_MODE", video_build.REGISTER_MODE)
    # the facing-weighted refine over the keyframes (`recon.facing_refine`, off by default)
    if os.environ.get("AVATARKIT_FACING_REFINE") in ("0", "1"):
        pipeline.FACING_REFINE = os.environ["AVATARKIT_FACING_REFINE"] == "1"
    # the hull's growth over bare scalp (`recon.hair_hull.GROW_BARE`)
    if os.environ.get("AVATARKIT_GROW_BARE") in ("0", "1"):
        from avatarkit.recon import hair_hull

        hair_hull.GROW_BARE = os.environ["AVATARKIT_GROW_BARE"] == "1"
    # the lifter's hair end from the turned keyframes (`recon.hair_end`)
    if os.environ.get("AVATARKIT_HAIR_END") in ("0", "1"):
        pipeline.HAIR_END_FROM_VIEWS = os.environ["AVATARKIT_HAIR_END"] == "1"
    # teeth, cavity and parted lips (`recon.mouth`, off by default)
    if os.environ.get("AVATARKIT_OPEN_MOUTH") in ("0", "1"):
        pipeline.OPEN_MOUTH = os.environ["AVATARKIT_OPEN_MOUTH"] == "1"
    # the hair's outline fitted to the keyframes' silhouettes (`recon.hair_outline`, on by default)
    if os.environ.get("AVATARKIT_HAIR_OUTLINE") in ("0", "1"):
        pipeline.FIT_HAIR_OUTLINE = os.environ["AVATARKIT_HAIR_OUTLINE"] == "1"
    # the turned keyframes' registered poses: for the outline alone, or for every stage
    if os.environ.get("AVATARKIT_OUTLINE_POSES") in ("tracked", "registered", "registered-all"):
        video_build.OUTLINE_POSES = os.environ["AVATARKIT_OUTLINE_POSES"]
    pipeline.MULTIVIEW_HAIR_DIRECTIONS = pipeline.GROW_HAIR_HULL = multiview_hair
    apply_switches(switches)                 # last: `--set` wins over the environment's switches
    opts = BuildOptions(n_bald=counts[0], n_hair=counts[1], preview=False, hair_mode="rigid", seed=seed)
    t0 = time.perf_counter()
    avatar = build_video_avatar(path, opts) if kind == "video" else build_avatar(png, opts)
    wall = time.perf_counter() - t0
    if subject == "mesh":
        from avatarkit.synthetic.mesh_head import MeshHead, view_psnr

        subject = MeshHead.make()
        return (view_psnr(avatar, subject, size), avatar.provenance, wall,
                view_psnr(avatar, subject, size, background=(0.0, 0.0, 0.0)))
    truth = make_sample_avatar(n_hair=3000, n_bald=12000, style=style, cage_vertices=200)
    return (novel_view_psnr(avatar, truth, size), avatar.provenance, wall,
            novel_view_psnr(avatar, truth, size, background=(0.0, 0.0, 0.0)))


def _in_own_process(*args):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_score, *args).result()


def make_clip(kind: str, frames: int | None):
    """The synthetic turning clip: "eased" (default 96 frames) or "whip" (default 32 frames)."""
    from avatarkit.synthetic.turning_video import eased_turning_clip, turning_clip

    if kind == "whip":
        return turning_clip(frames or 32)
    return eased_turning_clip(frames or 96)


def synthetic(size: int, frames: int | None, counts: tuple[int, int], tmp: str, style: str = "short",
              multiview_hair: bool = True, subject: str = "avatar", clip_kind: str = "eased",
              register: bool = True, seed: int = 0, wall: str = "white", switches: tuple[str, ...] = ()) -> None:
    from avatarkit.export.images import write_png
    from avatarkit.video import read_frame

    path = os.path.join(tmp, f"turn_{subject}.mp4")
    clip = make_clip(clip_kind, frames)
    frames = clip.n_frames
    from avatarkit.synthetic.walls import wall_image

    # the wall behind the video only: both builds are scored over white, as always
    background = (1.0, 1.0, 1.0) if wall == "white" else wall_image(wall, size)
    if subject == "mesh":
        from avatarkit.synthetic.mesh_head import MeshHead, turning_video

        turning_video(MeshHead.make(), path, size=size, clip=clip, background=background)
        what = "the mesh subject (textured template mesh + hair cap, rasterised)"
    else:
        from avatarkit.synthetic.sample_avatar import make_sample_avatar
        from avatarkit.synthetic.turning_video import write_turning_video

        truth = make_sample_avatar(n_hair=3000, n_bald=12000, style=style, cage_vertices=200)
        write_turning_video(truth, path, size=size, clip=clip, background=background)
        what = f"sample avatar with {style} hair"
    what += f", {wall} wall" if wall != "white" else ""
    pv, prov, tv, pv_black = _in_own_process("video", path, None, counts, style, size, multiview_hair, subject, register, seed,
                                   tuple(switches))
    ref = prov["source_video"]["frame"]
    png = os.path.join(tmp, "ref.png")
    write_png(png, read_frame(path, ref).rgb)
    ps, _, ts, ps_black = _in_own_process("single", path, png, counts, style, size, multiview_hair, subject, True, seed,
                                tuple(switches))
    keys = [k["frame"] for k in prov["source_video"]["keyframes"]]
    print(f"synthetic turning video ({clip_kind} clip, {frames} frames {size}x{size}, {what}; keyframes "
          f"{keys}, reference {ref}); builds {counts[0]} bald + {counts[1]} hair (lifter seed {seed}), each in its own "
          "process")
    from avatarkit.track.keyframes import yaw_pitch
    from avatarkit.track.neck import head_rotation

    true = np.degrees(yaw_pitch(head_rotation(clip.rotation, clip.neck))[:, 0])
    print("  keyframes' yaw, tracked (true): " + ", ".join(
        f"{k['yaw_deg']:.0f} ({true[k['frame']]:.0f})" for k in prov["source_video"]["keyframes"]))
    edge = prov["source_video"].get("tracking_edge", [])
    if edge:
        print("  the tracking's edge (yaw likely under-read; keyframes.tracking_edge), true yaw: " + ", ".join(
            f"{f} ({true[f]:.0f})" for f in edge))
    # the turn-end frames' pose: `register_turned`'s against the first draft, then (REFINE_TURNED)
    # the refinement's (`refine_keyframes`, its last round), which every stage uses; the refined
    # yaw is reported from the reference keyframe's, so it is compared with the true yaw's change
    refined = {f["frame"]: f for f in prov["source_video"].get("refined", [])}
    for r in prov["source_video"].get("registered", []):
        f = r["frame"]
        line = (f"  turn end: frame {f} registered by the first build at yaw {r['yaw_deg']:.1f} (true "
                f"{true[f]:.1f}), {r['renders']} renders")
        if f in refined:
            x = refined[f]
            line += (f"; refined (the pose every stage uses) {x['registered_deg']:+.1f} from the reference (true "
                     f"{true[f] - true[ref]:+.1f}){', at the bound' if x['at_bound'] else ''}")
        print(line)
    b = prov["build"]
    hull, dirs = b.get("segment3d", {}).get("hull"), b.get("hair_directions")
    if hull is not None:
        print(f"  hair shell grown from the keyframes: {hull['grown']} Gaussians; uncovered hair pixels per "
              f"keyframe {hull['missing_px_before']} -> {hull['missing_px_after']}")
    if "hair_end_from_views" in b:
        end = b["hair_end_from_views"]
        print(f"  hair's end from the turned keyframes: {'none' if end is None else f'{end:.4f} m'}; the lifter's "
              f"hidden strands end at {b.get('lift', {}).get('hair_end_y')} m")
    if dirs is not None:
        print(f"  strand directions from >= 2 keyframes: {dirs['from_views']} of {dirs['of']} hair Gaussians "
              f"(median turn {dirs.get('median_turn_deg', 0.0)} degrees)")
    jaw = prov["source_video"].get("jaw_corrective")
    if jaw is not None:
        # the turning clips do not move the mouth: the corrective should come out ~0
        last = jaw["rounds"][-1] if jaw.get("rounds") else {}
        print(f"  jaw corrective: {jaw.get('vertices', 0)} vertices, at most {jaw.get('max_mm_at_0.3_rad', 0.0)} mm "
              f"at 0.3 rad; the fitted opening's 5-95th percentiles {last.get('opening_p5_p95')}")
    print(f"  {'':8s} {'over white (the score)':^30s}   {'over black':^30s}")
    print(f"  {'azimuth':>8s} {'single dB':>10s} {'video dB':>10s} {'gain':>7s}   {'single dB':>10s} {'video dB':>10s} "
          f"{'gain':>7s}")
    for az in pv:
        print(f"  {az:8.0f} {ps[az]:10.2f} {pv[az]:10.2f} {pv[az] - ps[az]:+7.2f}   {ps_black[az]:10.2f} "
              f"{pv_black[az]:10.2f} {pv_black[az] - ps_black[az]:+7.2f}")
    prof = np.mean([pv[a] - ps[a] for a in pv if abs(a) == 90])
    prof_black = np.mean([pv_black[a] - ps_black[a] for a in pv if abs(a) == 90])
    print(f"  profile gain (mean of +-90): {prof:+.2f} dB (target >= +3 dB; over black {prof_black:+.2f}); build "
          f"wall: video {tv:.1f} s, single {ts:.1f} s")


def real(videos: list[str], counts: tuple[int, int], tmp: str) -> None:
    from avatarkit.track.evaluate import EvalOptions, evaluate

    for v in videos:
        out = os.path.join(tmp, os.path.basename(v) + ".eval")
        t0 = time.perf_counter()
        c0 = time.process_time()
        report = evaluate(v, out, options=EvalOptions(compare_single=True, side_by_side=False,
                                                      n_bald=counts[0], n_hair=counts[1]))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        s, one = report.summary, report.summary["single_frame"]
        print(f"{os.path.basename(v)}: {s['frames_evaluated']} of {s['frames']} frames held out "
              f"(keyframes {report.settings['keyframes']} and the build's colour frames "
              f"{report.settings['colour_frames']} +-{report.settings['exclude']} excluded)")
        for name, m in (("video build", s), ("single-frame build", one)):
            print(f"  {name:<19s} PSNR {m['psnr']:.2f} dB  SSIM {m['ssim']:.3f}  whole-frame PSNR "
                  f"{m['psnr_full']:.2f}  landmark {m['landmark_error_px']:.2f} px")
        print(f"  gain: {s['psnr'] - one['psnr']:+.2f} dB person region, {s['psnr_full'] - one['psnr_full']:+.2f} "
              f"dB whole frame (target >= +1 dB); evaluate wall {wall:.0f} s, CPU {cpu:.0f} s")


def timing(video: str, counts: tuple[int, int], tmp: str) -> tuple[float, float]:
    from avatarkit.recon.pipeline import BuildOptions
    from avatarkit.track.build_frame import build_image
    from avatarkit.track.video_build import build_video_avatar
    from avatarkit.video import open_video, read_frame

    with open_video(video) as v:
        info, n = v.info, len(v)
    t0, c0 = time.perf_counter(), time.process_time()
    avatar = build_video_avatar(video, BuildOptions(n_bald=counts[0], n_hair=counts[1], preview=False))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    ref = avatar.provenance["source_video"]["frame"]
    t0, c0 = time.perf_counter(), time.process_time()
    build_image(read_frame(video, ref).rgb, os.path.join(tmp, "single"),
                BuildOptions(n_bald=counts[0], n_hair=counts[1], preview=False))
    swall, scpu = time.perf_counter() - t0, time.process_time() - c0
    stages = avatar.provenance["build"]["timings_s"]
    print(f"video build of {os.path.basename(video)} ({n} frames {info.width}x{info.height}, "
          f"{counts[0]} + {counts[1]} Gaussians): wall {wall:.1f} s, CPU {cpu:.1f} s "
          "(target <= 120 s on 2 cores)")
    print("  stages (wall s): " + ", ".join(f"{k} {s:.1f}" for k, s in stages.items()))
    fc = avatar.provenance["build"].get("frame_colours")
    if fc is not None:
        print(f"  the frame-colours stage: {len(fc['frames'])} frames, registered by {fc.get('refine')}, "
              f"{fc.get('iterations')} rounds")
    fr = avatar.provenance["build"].get("facing_refine")
    if fr is not None:
        print(f"  of the colours stage, the facing refine over {fr['views']} keyframes: {fr['seconds']:.1f} s")
    print(f"  baseline single-frame build of frame {ref}: wall {swall:.1f} s, CPU {scpu:.1f} s; "
          f"ratio video / single: wall {wall / swall:.2f}x, CPU {cpu / scpu:.2f}x")
    print(f"  peak memory of this process so far: {peak_rss_mb():.0f} MB")
    return wall, cpu


def time_phone(counts: tuple[int, int], tmp: str) -> None:
    """The mesh subject's 250-frame 480x480 eased turning video, then the same frames at a
    phone's size (1080x1920 portrait, 30 fps, `synthetic.phone_video`), built in this process
    one after the other: the phone clip's time as a ratio to the square one's."""
    from avatarkit.synthetic.mesh_head import MeshHead, turning_video
    from avatarkit.synthetic.phone_video import phone_video
    from avatarkit.synthetic.turning_video import eased_turning_clip

    square = os.path.join(tmp, "mesh_turn480.mp4")
    turning_video(MeshHead.make(), square, size=480, clip=eased_turning_clip(250))
    phone = os.path.join(tmp, "mesh_turn_phone.mp4")
    phone_video(square, phone)
    w0, c0 = timing(square, counts, tmp)
    w1, c1 = timing(phone, counts, tmp)
    print(f"phone clip / 480x480 clip: wall {w1 / w0:.2f}x, CPU {c1 / c0:.2f}x (load {os.getloadavg()[0]:.1f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=192)
    ap.add_argument("--frames", type=int, default=None, help="clip length (default: eased 96, whip 32)")
    ap.add_argument("--clip", default="eased", choices=("eased", "whip"),
                    help="synthetic turning clip: eased to +-80 degrees (default) or the older 46-degree whip")
    ap.add_argument("--no-register", action="store_true",
                    help="video builds without registering the frames the tracker lost (track.register)")
    ap.add_argument("--skip-real", action="store_true", help="only the synthetic video")
    ap.add_argument("--skip-synthetic", action="store_true")
    ap.add_argument("--quick", action="store_true", help="tiny sizes, synthetic only (CI)")
    ap.add_argument("--style", default="short", help="the synthetic subject's hair style (synthetic.HAIR_STYLES)")
    ap.add_argument("--set", dest="switches", action="append", default=[], metavar="MODULE.NAME=VALUE",
                    help="set a library switch for every build, e.g. recon.multiview.RELABEL_CONNECTED=None "
                         "(repeatable; benchmarks/_switches.py)")
    ap.add_argument("--seed", type=int, default=0, help="the builds' lifter seed (BuildOptions.seed)")
    ap.add_argument("--wall", default="white", choices=("white", "dark", "colour", "clutter"),
                    help="the wall behind the synthetic video (synthetic.walls; the renders are scored over white)")
    ap.add_argument("--subject", default="both", choices=("both", "avatar", "mesh"),
                    help="synthetic subject: the sample avatar (splatted), the mesh subject (rasterised), or both")
    ap.add_argument("--no-multiview-hair", action="store_true",
                    help="video builds without the multi-view hair directions and shell growth (the 'before' "
                         "figures)")
    ap.add_argument("--facing-refine", action="store_true",
                    help="video builds with the facing-weighted colour refine over the keyframes "
                         "(recon.facing_refine; AVATARKIT_FACING_REFINE=1 does the same)")
    ap.add_argument("--time-synthetic", action="store_true",
                    help="also time the build of a 250-frame 480x480 synthetic turning video")
    ap.add_argument("--time-phone", action="store_true",
                    help="also time the mesh subject's 250-frame 480x480 turning video and the same frames at a "
                         "phone's size (1080x1920 portrait, 30 fps) in the same process")
    a = ap.parse_args()
    print(f"CPU: {cpu_model()}; load {os.getloadavg()[0]:.1f}; python {sys.version.split()[0]}")
    from _switches import apply_switches

    try:
        for line in apply_switches(a.switches):      # here too: the timed builds run in this process
            print(f"switch: {line}")
    except ValueError as e:
        ap.error(str(e))
    if a.facing_refine:
        os.environ["AVATARKIT_FACING_REFINE"] = "1"      # read by each build's own process
    if os.environ.get("AVATARKIT_FACING_REFINE") == "1":
        from avatarkit.recon import pipeline

        pipeline.FACING_REFINE = True                     # the timed builds run in this process
        print("facing-weighted colour refine over the keyframes: on")
    if os.environ.get("AVATARKIT_HAIR_OUTLINE") in ("0", "1"):
        from avatarkit.recon import pipeline

        pipeline.FIT_HAIR_OUTLINE = os.environ["AVATARKIT_HAIR_OUTLINE"] == "1"   # the timed builds run here
        print(f"the hair's outline fitted to the keyframes' silhouettes: {'on' if pipeline.FIT_HAIR_OUTLINE else 'off'}")
    if a.no_multiview_hair:
        print("multi-view hair directions and shell growth: off")
    if os.environ.get("AVATARKIT_COLOUR_REFINE"):
        from avatarkit.track import frame_colours

        name = os.environ["AVATARKIT_COLOUR_REFINE"]
        frame_colours.REFINE = None if name == "none" else name       # the timed build runs here
        print(f"the frame-colours stage's frames registered by: {frame_colours.REFINE}")
    counts = (40_000, 40_000)
    with tempfile.TemporaryDirectory(prefix="bench-video-") as tmp:
        subjects = ("avatar", "mesh") if a.subject == "both" else (a.subject,)
        if a.quick:
            synthetic(128, 24, (3000, 1500), tmp, a.style, not a.no_multiview_hair, subjects[0], "whip")
            return
        if not a.skip_synthetic:
            for subject in subjects:
                synthetic(a.size, a.frames, (8000, 4000), tmp, a.style, not a.no_multiview_hair, subject, a.clip,
                          not a.no_register, a.seed, a.wall, a.switches)
        if a.time_synthetic:
            from avatarkit.synthetic.sample_avatar import make_sample_avatar
            from avatarkit.synthetic.turning_video import write_turning_video

            path = os.path.join(tmp, "turn250.mp4")
            write_turning_video(make_sample_avatar(n_hair=3000, n_bald=12000, style="short", cage_vertices=200),
                                path, size=480, frames=250)
            timing(path, counts, tmp)
        if a.time_phone:
            time_phone(counts, tmp)
        videos = sorted(glob.glob(os.path.join(VIDEOS, "*.mp4")))
        if a.skip_real or not videos:
            if not videos:
                print("real clips: ../shared/data/videos not beside the checkout: skipped")
            return
        timing(max(videos, key=os.path.getsize), counts, tmp)
        real(videos, counts, tmp)
    print(f"load at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
