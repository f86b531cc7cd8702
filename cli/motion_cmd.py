"""`avatarkit motion`: make, inspect, convert and resample motion clips (FLAME parameter sequences)."""
from __future__ import annotations

import click

from avatarkit.cli.options import FiniteFloatRange, output_option, quiet_option

_KINDS = ("nod", "shake", "tilt", "turn", "talk", "idle", "whip")  # avatarkit.motion.KINDS, kept
# literal so `--help` does not import numpy/scipy; a test checks they agree
_CLIP_PATH = click.Path(exists=False, dir_okay=True)
_fps_in = click.option("--fps", type=FiniteFloatRange(min=0, min_open=True), default=None,
                       help="Frame rate of the input [default: the file's own, else 25 (VHAP)].")


def _report(quiet: bool, output: str, clip) -> None:
    if not quiet:
        click.echo(f"wrote {output}: {clip.n_frames} frames at {clip.fps:g} fps ({clip.duration:.2f} s)")


@click.group("motion")
def motion():
    """Make, inspect and convert motion clips (FLAME parameter sequences).

    Clips are .npz files in the GaussianAvatars/VHAP layout (rotation, translation, neck_pose,
    jaw_pose, eyes_pose, expr, shape; + fps), folders of per-frame VHAP flame_param/*.npz
    files (read only), or avatarkit's .json format.
    """


@motion.command("make")
@click.argument("kind", type=click.Choice(_KINDS))
@output_option("Output clip: .npz or .json.")
@click.option("--frames", type=click.IntRange(min=2), default=None,
              help="Number of frames [default: 2 s for nod/shake/tilt, 3 s turn/whip, 4 s talk, 6 s idle].")
@click.option("--fps", type=FiniteFloatRange(min=0, min_open=True), default=25.0, show_default=True,
              help="Frames per second.")
@click.option("--amplitude", type=FiniteFloatRange(0, 180), default=None,
              help="Peak angle in degrees [default: nod 15, shake 25, tilt 15, turn 40, talk 12 (jaw), "
                   "idle 3, whip 60].")
@click.option("--expr-dims", type=click.IntRange(min=0), default=100, show_default=True,
              help="Expression coefficients per frame (FLAME trackers use 100).")
@click.option("--seed", type=int, default=0, show_default=True, help="Varies talk and idle.")
@quiet_option
def make(kind, output, frames, fps, amplitude, expr_dims, seed, quiet):
    """Write a procedural clip of KIND.

    Every clip starts and ends at rest; the head turns through the global `rotation`
    (neck stays 0), as FLAME trackers do. `whip` makes fast large turns with sudden stops to
    stress hair simulation.

    \b
    Examples:
      avatarkit motion make nod -o nod.npz
      avatarkit motion make shake --amplitude 35 --fps 30 -o shake.json
      avatarkit motion make whip --frames 120 -o whip.npz
    """
    from avatarkit.motion import make_clip, save_clip

    clip = make_clip(kind, frames=frames, fps=fps, amplitude=amplitude, expr_dims=expr_dims, seed=seed)
    save_clip(output, clip)
    _report(quiet, output, clip)


@motion.command("inspect")
@click.argument("clip_path", metavar="CLIP", type=_CLIP_PATH)
@_fps_in
def inspect_clip_cmd(clip_path, fps):
    """Summarise a clip: frames, fps, duration, and the range of every channel.

    Rotations are shown in degrees per axis-angle component, translation in millimetres.
    """
    from avatarkit.motion import format_summary, load_clip

    clip = load_clip(clip_path, fps=fps)
    click.echo(format_summary(clip, title=clip_path))


@motion.command("convert")
@click.argument("input_path", metavar="IN", type=_CLIP_PATH)
@output_option("Output clip: .npz or .json.")
@_fps_in
@click.option("--start", type=int, default=None, help="First frame to keep (0-based).")
@click.option("--end", type=int, default=None, help="Frame to stop before (exclusive; negative counts from the end).")
@quiet_option
def convert(input_path, output, fps, start, end, quiet):
    """Convert a clip between .npz, .json and per-frame folders (folder -> .npz/.json).

    \b
    Examples:
      avatarkit motion convert tracked/flame_param -o clip.npz --fps 30
      avatarkit motion convert clip.npz -o clip.json --start 10 --end 110
    """
    from avatarkit.motion import load_clip, save_clip

    clip = load_clip(input_path, fps=fps)
    if start is not None or end is not None:
        clip = clip.slice(start or 0, end)
    save_clip(output, clip)
    _report(quiet, output, clip)


@motion.command("resample")
@click.argument("input_path", metavar="IN", type=_CLIP_PATH)
@output_option("Output clip: .npz or .json.")
@click.option("--to-fps", "to_fps", type=FiniteFloatRange(min=0, min_open=True), required=True,
              help="New frame rate.")
@_fps_in
@quiet_option
def resample(input_path, output, to_fps, fps, quiet):
    """Resample a clip to another frame rate (rotations by slerp, the rest linearly).

    \b
    Example:
      avatarkit motion resample clip.npz --to-fps 30 -o clip30.npz
    """
    from avatarkit.motion import load_clip, save_clip

    clip = load_clip(input_path, fps=fps).resample(to_fps)
    save_clip(output, clip)
    _report(quiet, output, clip)
