"""`avatarkit track`: FLAME-style motion from a monocular video."""
from __future__ import annotations

import click

from avatarkit.cli.options import (REFINE_NAMES, FiniteFloatRange, _is_terminal, cli_warnings, quiet_option,
                                   refine_every_option)

_FILE = click.Path(dir_okay=False)


@click.command("track")
@click.argument("video", type=click.Path())
@click.option("-o", "--output", required=True, type=_FILE,
              help="Tracked clip to write (.npz: the motion bake reads, plus the camera and confidence).")
@click.option("--avatar", type=click.Path(file_okay=False),
              help="Drive this avatar: use its head model and identity shape.")
@click.option("--head-model", type=_FILE, help="A head model (FLAME .pkl / avatarkit .npz) whose "
              "identity is fitted over the first frames (default: the built-in template).")
@click.option("--landmark-embedding", type=_FILE, help="FLAME's mediapipe_landmark_embedding.npz "
              "(needed with a FLAME head model).")
@click.option("--start", type=click.IntRange(min=0), default=0, show_default=True,
              help="First frame to track (0-based).")
@click.option("--end", type=click.IntRange(min=1), help="Frame after the last one to track "
              "(default: the video's end).")
@click.option("--face-index", type=click.IntRange(min=0), default=0, show_default=True,
              help="Which face, numbered left to right from 0, when the first frame has several.")
@click.option("--smoothing", type=FiniteFloatRange(min=0), default=4.0, show_default=True,
              help="Temporal smoothing (frames^4; 0 = none). It does not lag: see docs/tracking.md.")
@click.option("--focal-mm", type=click.FloatRange(min=0, min_open=True), help="The camera's lens, "
              "35 mm-equivalent across the frame's longer side (a phone's main camera ~26). Default: an "
              "assumed 50 mm portrait lens; give the one the avatar was built with (docs/video-build.md).")
@click.option("--preview", type=_FILE, help="Also write the video with the fitted head's landmarks "
              "and mesh drawn on it (.mp4 or .gif).")
@click.option("--align-to-build/--no-align-to-build", default=True, show_default=True,
              help="With --avatar built from this same video: drive its eyes relative to the build "
              "frame's gaze and pose the head so the build frame is seen as the build saw it "
              "(docs/tracking.md).")
@click.option("--subject-calibration/--no-subject-calibration", default=False, show_default=True,
              help="With --avatar: calibrate the face mesh's reading on renders of the avatar at known "
              "poses first (~10 s) and track with that correction (docs/tracking.md).")
@click.option("--subject-part", type=click.Choice(["full", "rigid", "nonrigid"]), default="full",
              show_default=True, help="With --subject-calibration: what of the correction is used: all "
              "of it, only its turn and shift of the whole face (rigid), or the rest (docs/tracking.md).")
@click.option("--refine", type=click.Choice(REFINE_NAMES), default=None,
              help="With --avatar: refine each frame's head pose and jaw opening against the frame "
              "by rendering the avatar (render-and-compare; ~0.3-1 s a frame; docs/tracking.md); "
              "photometric-pose: the head pose only; photometric-fast: 2 cheaper passes on every 5th frame "
              "(~17 frames/s from scratch on 2 cores in session 16; less accurate).")
@refine_every_option
@click.option("--head-on", type=click.Choice(["neck", "global"]), default="neck", show_default=True,
              help="Where the head's motion goes: 'neck' turns the head on the neck joint and keeps "
              "the body (the neck's base, the collar) at one pose: the avatar's build frame's with "
              "--avatar built from this video, else the clip's median; 'global' turns the whole "
              "model, neck and shoulders with the head (docs/tracking.md).")
@quiet_option
def track_cmd(video, output, avatar, head_model, landmark_embedding, start, end, face_index,
              smoothing, focal_mm, preview, align_to_build, subject_calibration, subject_part, refine, refine_every, head_on,
              quiet):
    """Track the face in VIDEO (MP4, MOV, MKV, AVI, ... or a folder of images at 30 fps) and
    write its motion as a clip that `avatarkit bake` takes.

    \b
    Examples:
      avatarkit track talk.mp4 -o talk.npz
      avatarkit track talk.mp4 -o talk.npz --avatar me/ --preview talk_overlay.mp4
      avatarkit bake me/ talk.npz -o talk.usdc --preview talk_avatar.mp4
    """
    from pathlib import Path

    from avatarkit.fileio import check_output_folder
    from avatarkit.track import TrackOptions, save_tracking
    from avatarkit.track.video import track_video

    from avatarkit.errors import OutputError

    if Path(output).suffix.lower() != ".npz":
        raise OutputError("a tracked clip is written as .npz", output)
    check_output_folder(Path(output).parent)
    if preview is not None:
        from avatarkit.export.video import video_format

        video_format(preview)
        check_output_folder(Path(preview).parent)
    if subject_calibration and avatar is None:
        raise click.UsageError("--subject-calibration renders the avatar: it needs --avatar")
    if subject_part != "full" and not subject_calibration:
        raise click.UsageError("--subject-part chooses what of --subject-calibration is used: it needs it")
    if refine is not None and avatar is None:
        raise click.UsageError(f"--refine {refine} renders the avatar: it needs --avatar")
    if refine_every is not None and refine is None:
        raise click.UsageError("--refine-every goes with --refine")
    options = TrackOptions(face_index=face_index, smoothing=smoothing, subject_calibration=subject_calibration,
                           subject_part=subject_part, refine=refine, refine_every=refine_every, focal_mm=focal_mm)
    with cli_warnings(quiet), _LazyBar("tracking", quiet) as bar:
        result = track_video(video, avatar=avatar, head_model=head_model,
                             landmark_embedding=landmark_embedding, start=start, end=end,
                             options=options, progress=bar.step)
    import dataclasses

    # the overlay keeps drawing the fit to the video; the file gets the aligned clip
    aligned, saved = None, dataclasses.replace(result, clip=result.clip.replace())
    if avatar is not None and align_to_build:
        from avatarkit.track.build_pose import align_to_build as align, recorded_build_frame

        frame = recorded_build_frame(avatar, video)
        if frame is not None:
            aligned = align(saved, avatar, frame)
            if aligned["frame"] is None and not quiet:
                click.echo(f"warning: {avatar} was built from frame {frame} of this video, outside the "
                           "tracked frames: the clip is not aligned to it", err=True)
    carried = None
    if head_on == "neck":
        from avatarkit.track.neck import place_head

        # the body keeps the build frame's pose only when the clip was aligned to that frame
        frame = aligned["frame"] if aligned is not None else None
        carried = place_head(saved, frame, "neck")
    with cli_warnings(quiet):
        save_tracking(output, saved)
        if preview is not None:
            from avatarkit.track.overlay import write_overlay

            with _LazyBar("preview", quiet) as bar:
                write_overlay(video, result, preview, progress=bar.step)
    if not quiet:
        found = int(result.found.sum())
        import numpy as np

        err = np.nanmedian(result.landmark_error)
        # the refined pose follows the frames' pixels, not the face mesh's landmarks (which read
        # a turned face with a bias): the error against them rises while the pose improves
        why = " (against the face mesh's landmarks, which the refined pose no longer follows)" if refine else ""
        click.echo(f"tracked {result.num_frames} frames at {result.clip.fps:g} fps: face in {found}, "
                   f"interpolated {result.num_frames - found}; median landmark error {err:.2f} px{why}", err=True)
        if aligned is not None and aligned["frame"] is not None:
            parts = [n for n, k in (("eyes", "eyes"), ("head pose", "head_pose")) if aligned[k]]
            click.echo(f"aligned to the avatar's build frame {aligned['frame']} ({' and '.join(parts)})", err=True)
        if carried is not None:
            from avatarkit.track.neck import describe

            click.echo(f"head on the {describe(carried)}", err=True)
        click.echo(f"wrote {output}" + (f" and {preview}" if preview else ""), err=True)


class _LazyBar:
    """A progress bar made on the first `step(done, total)`, when the total is known; like
    `options.progress`, none with -q or when stderr is not a terminal."""

    def __init__(self, label: str, quiet: bool):
        self.label, self.quiet, self.bar, self.done = label, quiet, None, 0

    def step(self, done: int, total: int) -> None:
        import sys

        if self.quiet or not _is_terminal(sys.stderr):
            return
        if self.bar is None:
            self.bar = click.progressbar(length=total, label=self.label, file=sys.stderr,
                                         show_eta=True, show_pos=True)
            self.bar.__enter__()
        self.bar.update(done - self.done)
        self.done = done

    def __enter__(self) -> "_LazyBar":
        return self

    def __exit__(self, *exc) -> bool:
        if self.bar is not None:
            self.bar.__exit__(*exc)
        return False
