"""`avatarkit build`: one portrait -> an avatar folder."""
from __future__ import annotations

import click

from avatarkit.cli.options import REFINE_NAMES, quiet_option

_FILE = click.Path(dir_okay=False)


@click.command("build")
@click.argument("portrait", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Avatar folder to write (an existing avatar folder is replaced).")
@click.option("--hair-mask", type=_FILE, help="PNG whose non-zero pixels are hair (e.g. from SAM); "
              "replaces the built-in hair segmentation.")
@click.option("--head-splats", type=_FILE, help="3DGS PLY of the portrait lifted to 3D with its hair "
              "(e.g. FaceLift); needs --bald-splats.")
@click.option("--bald-splats", type=_FILE, help="3DGS PLY of the bald image lifted to 3D, in the "
              "same frame as --head-splats.")
@click.option("--head-model", type=_FILE, help="Your FLAME model (generic_model.pkl / flame2023.pkl, "
              "or an avatarkit .npz) instead of the built-in template head.")
@click.option("--flame-params", type=_FILE, help="A FLAME tracker's fit (.npz with 'shape'): its "
              "identity shape is used instead of fitting one.")
@click.option("--face-index", type=click.IntRange(min=0), help="Which face to use when the photo has "
              "several (numbered left to right from 0).")
@click.option("--face-detector", type=click.Choice(["auto", "mediapipe", "cascade"]), default="auto",
              show_default=True, help="auto: MediaPipe's face detector, 468-point face mesh and iris "
              "(installed by `make install`), else OpenCV/scikit-image cascades with a warning.")
@click.option("--landmark-embedding", type=_FILE, help="FLAME's mediapipe_landmark_embedding.npz: where "
              "the face-mesh points lie on --head-model (the template's ships with avatarkit).")
@click.option("--hair-mode", type=click.Choice(["auto", "cage", "rigid"]), default="auto",
              show_default=True, help="auto: short hair rides the scalp rigidly, long hair is "
              "simulated in a cage.")
@click.option("--n-bald", type=click.IntRange(min=100), default=40_000, show_default=True,
              help="Bald head Gaussians (built-in lifter).")
@click.option("--n-hair", type=click.IntRange(min=100), default=40_000, show_default=True,
              help="Hair Gaussians, at most (built-in lifter).")
@click.option("--seed", type=int, default=0, show_default=True, help="Varies the sampling.")
@click.option("--frame", type=click.IntRange(min=0), help="PORTRAIT is a video: build from this one frame "
              "only (0-based). Default: build from the whole video (see --keyframes).")
@click.option("--keyframes", type=click.IntRange(min=1, max=24), default=6, show_default=True,
              help="PORTRAIT is a video: fuse at most this many keyframes chosen by head pose "
              "(1: the single most frontal neutral frame).")
@click.option("--register/--no-register", default=True, show_default=True,
              help="PORTRAIT is a video that turns past what the face tracker follows (~55-60 degrees): "
              "register those frames against a first build and fuse them as keyframes too (about doubles "
              "the build of such a video).")
@click.option("--jaw-corrective/--no-jaw-corrective", default=False, show_default=True,
              help="PORTRAIT is a video: learn from the tracked frames how the person's mouth opens "
              "beyond the head model's (a per-subject jaw corrective, saved with the avatar; off by "
              "default: on the shared clips' held-out frames it has not paid yet, docs/video-build.md).")
@click.option("--frame-colours/--no-frame-colours", default=None,
              help="PORTRAIT is a video whose head hardly turns (one keyframe, e.g. a talking head): "
              "colour the head from 24 of its frames, each registered by rendering the avatar "
              "(default on; about 50 s of a 216-250-frame clip's build; docs/video-build.md). "
              "--no-frame-colours: the keyframe's colours only.")
@click.option("--frame-refine", type=click.Choice(("none", *REFINE_NAMES)), default=None,
              help="How the frame-colours stage registers its frames: refined by rendering the avatar "
              "(default photometric-fast; the choices of `avatarkit evaluate --refine`), or none: the "
              "landmark fit's poses.")
@click.option("--frame-hull/--no-frame-hull", default=None,
              help="With the frame-colours stage: clear the hair Gaussians those frames show over the "
              "background and move the bald head's surface there inward (default on; docs/video-build.md).")
@click.option("--focal-mm", type=click.FloatRange(min=0, min_open=True), help="The camera's lens, "
              "35 mm-equivalent across the picture's longer side (a phone's main camera ~26, its "
              "selfie camera ~24). Default: an assumed 50 mm portrait lens (docs/video-build.md, "
              "\"The camera's lens\").")
@click.option("--preview/--no-preview", default=True, show_default=True,
              help="Render front, three-quarter and profile previews into the folder.")
@quiet_option
def build_cmd(portrait, output, hair_mask, head_splats, bald_splats, head_model, flame_params,
              face_index, face_detector, landmark_embedding, hair_mode, n_bald, n_hair, seed, frame,
              keyframes, register, jaw_corrective, frame_colours, frame_refine, frame_hull, focal_mm, preview, quiet):
    """Build an avatar from one roughly frontal PORTRAIT photo (JPEG, PNG, WebP, ...), or from
    a PORTRAIT video (MP4, MOV, MKV, AVI, WebM): by default from the whole video (tracked;
    keyframes covering the head's turns give the identity shape, colours and hair bounds;
    docs/video-build.md), with --frame N from that one frame.

    Writes the avatar folder (avatar.json, bald.ply, hair.ply, cage.ply, rig.npz, previews)
    atomically: on any error nothing is left under OUTPUT.

    \b
    Examples:
      avatarkit build samples/portrait.jpg -o portrait_avatar
      avatarkit build me.jpg -o me --hair-mask me_hair.png
      avatarkit build me.jpg -o me --head-splats head.ply --bald-splats bald.ply
      avatarkit build me.jpg -o me --head-model ~/flame/generic_model.pkl --flame-params track.npz
      avatarkit build turn.mp4 -o me
      avatarkit build talk.mp4 -o me --frame 40
    """
    import time

    from avatarkit.avatar import check_avatar_target
    from avatarkit.recon.pipeline import BuildOptions, build_avatar, save_avatar

    options = BuildOptions(hair_mask=hair_mask, head_splats=head_splats, bald_splats=bald_splats,
                           head_model=head_model, flame_params=flame_params, face_index=face_index,
                           face_detector=face_detector, landmark_embedding=landmark_embedding, hair_mode=hair_mode, n_bald=n_bald, n_hair=n_hair, seed=seed, preview=preview,
                           focal_mm=focal_mm)
    if frame_colours is False and (frame_refine is not None or frame_hull is not None):
        raise click.UsageError("--frame-refine and --frame-hull go with the frame-colours stage, "
                               "not --no-frame-colours")
    options.check()
    check_avatar_target(output)  # refuse a bad output before the work
    t0 = time.perf_counter()

    def progress(stage, index, total, seconds):
        if quiet:
            return
        if seconds is None:
            click.echo(f"[{index:2d}/{total}] {stage:<10s} ...", err=True, nl=False)
        else:
            click.echo(f" {seconds:6.1f} s", err=True)

    from avatarkit.track.build_frame import is_video

    source = None
    if frame is None and is_video(portrait):
        from avatarkit.track.video_build import build_video_avatar

        if not quiet:
            click.echo("tracking the video ...", err=True)
        try:
            avatar = build_video_avatar(portrait, options, keyframes=keyframes, progress=progress,
                                        register=register, jaw_corrective=jaw_corrective,
                                        frame_colours=frame_colours, colour_refine=frame_refine,
                                        frame_hull=frame_hull)
        except BaseException:
            if not quiet:
                click.echo(" failed", err=True)
            raise
        _finish(avatar, output, quiet, t0)
        return
    if frame is not None or is_video(portrait):
        # a video: the chosen frame goes through a temporary PNG into the same portrait build
        import tempfile
        from pathlib import Path

        from avatarkit.export.images import write_png
        from avatarkit.track.build_frame import portrait_frame

        if not quiet and frame is None:
            click.echo("choosing the build frame (tracking the video) ...", err=True)
        image, index = portrait_frame(portrait, frame)
        source = {"video": str(Path(portrait).resolve()), "frame": index}
        if not quiet:
            click.echo(f"building from frame {index} of {portrait}", err=True)
        tmp = tempfile.TemporaryDirectory(prefix="avatarkit-frame-")
        portrait = Path(tmp.name) / f"frame{index}.png"
        write_png(portrait, image)
    try:
        avatar = build_avatar(portrait, options, progress)
    except BaseException:
        if not quiet:
            click.echo(" failed", err=True)
        if source is not None:
            tmp.cleanup()
        raise
    if source is not None:
        tmp.cleanup()
        avatar.provenance["source_video"] = source
    _finish(avatar, output, quiet, t0)


def _finish(avatar, output, quiet, t0):
    import time

    from avatarkit.recon.pipeline import save_avatar

    path = save_avatar(avatar, output)
    if not quiet:
        video = avatar.provenance.get("source_video") or {}
        if video.get("keyframes"):
            frames = ", ".join(str(k["frame"]) for k in video["keyframes"])
            click.echo(f"keyframes: {frames} (reference {video['frame']}; {video.get('mode')})", err=True)
        if video.get("registered"):
            found = ", ".join(f"{r['frame']} at {r['yaw_deg']:+.0f} deg yaw" for r in video["registered"])
            click.echo(f"registered past the tracking: {found}", err=True)
        build = avatar.provenance.get("build", {})
        for w in build.get("warnings", []):
            click.echo(f"warning: {w}", err=True)
        c = avatar.counts()
        hair = (f"{c['hair']:,} hair Gaussians ({avatar.hair_mode} hair), {c['cage_vertices']} cage "
                "vertices" if avatar.has_hair else "no hair (a bald avatar)")
        click.echo(f"wrote {path}: {c['bald']:,} bald Gaussians + {hair}, "
                   f"{time.perf_counter() - t0:.1f} s", err=True)
