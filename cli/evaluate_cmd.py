"""`avatarkit evaluate`: self-reenactment quality of an avatar built from one frame of a video."""
from __future__ import annotations

import click

from avatarkit.cli.options import REFINE_NAMES, cli_warnings, quiet_option, refine_every_option


@click.command("evaluate")
@click.argument("video", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Report folder to write (metrics.json, frames.csv, side_by_side.mp4; the built "
              "avatar in avatar/). An earlier report there is replaced.")
@click.option("--avatar", type=click.Path(file_okay=False),
              help="Evaluate this avatar instead of building one from the video.")
@click.option("--build-frame", type=click.IntRange(min=0), help="Build from this one video frame "
              "(default: build from the whole video, as `avatarkit build VIDEO`). With --avatar: the "
              "frame it was built from, excluded with its neighbours.")
@click.option("--compare-single", is_flag=True, help="Also build from the video build's reference "
              "frame alone and report that single-frame build on the same held-out frames.")
@click.option("--exclude", type=click.IntRange(min=0), default=5, show_default=True,
              help="Frames either side of the build frame (and of every keyframe of a video "
              "build) left out of the summary.")
@click.option("--simulate-hair", is_flag=True, help="Simulate the hair in the bake (default: it "
              "rides the head rigidly).")
@click.option("--side-by-side/--no-side-by-side", default=True, show_default=True,
              help="Write side_by_side.mp4 (video | our render | error heat map).")
@click.option("--subject-calibration/--no-subject-calibration", default=False, show_default=True,
              help="Track with a view correction calibrated on renders of the avatar (docs/tracking.md).")
@click.option("--subject-part", type=click.Choice(["full", "rigid", "nonrigid"]), default="full",
              show_default=True, help="With --subject-calibration: what of the correction is used: all "
              "of it, only its turn and shift of the whole face (rigid), or the rest (docs/tracking.md).")
@click.option("--refine", type=click.Choice(("none", *REFINE_NAMES)), default="photometric-fast",
              show_default=True,
              help="Track with each frame's head pose and jaw opening refined against the frame by "
              "rendering the evaluated avatar (docs/tracking.md): photometric-fast, 2 cheaper passes on "
              "every 5th frame; photometric, 3 passes on every frame (~5x the time); photometric-pose, "
              "the head pose only; none, the landmark fit's pose. A video build's frame-colours stage "
              "registers its frames by it too (none: as `avatarkit build` does; docs/video-build.md).")
@refine_every_option
@click.option("--head-on", type=click.Choice(["neck", "global"]), default="neck", show_default=True,
              help="Where the tracked head motion goes: 'neck' turns the head on the neck joint, the "
              "body held at the build frame's pose; 'global' turns the whole model with the head.")
@quiet_option
def evaluate_cmd(video, output, avatar, build_frame, compare_single, exclude, simulate_hair, side_by_side,
                 subject_calibration, subject_part, refine, refine_every, head_on, quiet):
    """Self-reenactment: build an avatar from VIDEO (or one frame of it), drive it with the motion
    tracked from the whole video, render every frame from the tracked camera and compare with the video
    (PSNR and SSIM on the person region, face-mesh landmark error). See docs/evaluation.md.

    \b
    Examples:
      avatarkit evaluate talk.mp4 -o talk_eval
      avatarkit evaluate talk.mp4 -o talk_eval --avatar me/ --build-frame 40
      avatarkit evaluate turn.mp4 -o turn_eval --compare-single
    """
    from avatarkit.cli.track_cmd import _LazyBar
    from avatarkit.track.evaluate import EvalOptions, check_report_target, evaluate

    check_report_target(output)
    if compare_single and (avatar is not None or build_frame is not None):
        raise click.UsageError("--compare-single compares the video build with the single-frame build: "
                               "it does not go with --avatar or --build-frame")
    if subject_part != "full" and not subject_calibration:
        raise click.UsageError("--subject-part chooses what of --subject-calibration is used: it needs it")
    refine = None if refine == "none" else refine
    if refine_every is not None and refine is None:
        raise click.UsageError("--refine-every goes with a refinement, not --refine none")
    options = EvalOptions(build_frame=build_frame, exclude=exclude, simulate_hair=simulate_hair,
                          side_by_side=side_by_side, compare_single=compare_single,
                          subject_calibration=subject_calibration, subject_part=subject_part, head_on=head_on,
                          refine=refine, refine_every=refine_every)
    current: dict = {}           # the stage whose bar is shown (one bar per stage, in turn)

    def progress(stage, done, total):
        if current.get("stage") != stage:
            if "bar" in current:
                current.pop("bar").__exit__(None, None, None)
            current.update(stage=stage, bar=_LazyBar(stage, quiet))
        current["bar"].step(done, total)

    try:
        with cli_warnings(quiet):
            report = evaluate(video, output, avatar=avatar, options=options, progress=progress)
    finally:
        if "bar" in current:
            current.pop("bar").__exit__(None, None, None)
    if not quiet:
        s = report.summary

        def f(v, fmt):
            return "n/a" if v is None else format(v, fmt)

        click.echo(f"{s['frames_evaluated']} of {s['frames']} frames evaluated: PSNR {f(s['psnr'], '.2f')} dB, "
                   f"SSIM {f(s['ssim'], '.3f')} (person region); whole frame PSNR {f(s['psnr_full'], '.2f')}, "
                   f"SSIM {f(s['ssim_full'], '.3f')}; landmark error {f(s['landmark_error_px'], '.2f')} px "
                   "(median); LPIPS not reported", err=True)
        one = s.get("single_frame")
        if one:
            click.echo(f"single-frame build on the same frames: PSNR {f(one['psnr'], '.2f')} dB, SSIM "
                       f"{f(one['ssim'], '.3f')}; whole frame PSNR {f(one['psnr_full'], '.2f')}", err=True)
        click.echo(f"wrote {output}", err=True)
