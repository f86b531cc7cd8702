"""`avatarkit convert`: splats between 3DGS PLY, OpenUSD and SPZ; PLY sequences to one USD stage."""
from __future__ import annotations

import click

from avatarkit.cli.options import FINITE, FiniteFloatRange, advance, output_option, progress, quiet_option

_PLY_FRAMES = ("yup", "ydown")  # gaussians.ply.PLY_FRAMES (literal so --help imports no numpy)


def _size(n: int) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n} B"


@click.command("convert")
@click.argument("inputs", nargs=-1, required=True, type=click.Path(dir_okay=True))
@output_option("Output file: .ply, .usd/.usda/.usdc/.usdz or .spz (a sequence needs USD).")
@click.option("--up-axis", type=click.Choice(["Y", "Z"], case_sensitive=False), default="Y",
              show_default=True, help="USD stage up axis; Z turns the splats +90 degrees about X.")
@click.option("--prim-path", default=None,
              help="Splat prim to read from USD input / to write in USD output [default: the only one / /Splats].")
@click.option("--half", is_flag=True, help="Write USD half-precision attributes (positionsh, scalesh, ...).")
@click.option("--sh-degree", type=click.IntRange(0, 3), default=None,
              help="Keep SH bands up to this degree (drop higher ones).")
@click.option("--fps", type=FiniteFloatRange(min=0, min_open=True), default=24.0, show_default=True,
              help="Frames per second of a sequence stage.")
@click.option("--time", "time_code", type=FINITE, default=None,
              help="Time code to read a USD input at [default: its earliest sample].")
@click.option("--spz-version", type=click.Choice(["2", "3", "4"]), default="3", show_default=True,
              help="SPZ version to write. 3 is the newest that NVIDIA's converter and @spz-loader/core "
                   "read; 4 (zstd, needs the zstandard package) only for readers that know it.")
@click.option("--ply-frame", type=click.Choice(_PLY_FRAMES), default="yup", show_default=True,
              help="Axes of the PLY files written (and read): yup (ours, +Y up) or ydown (the 3DGS/COLMAP "
                   "frame trainers write and splat viewers assume: y and z negated).")
@click.option("--input-ply-frame", type=click.Choice(_PLY_FRAMES), default=None,
              help="Axes of PLY input when they differ from --ply-frame's [default: --ply-frame].")
@quiet_option
def convert_cmd(inputs, output, up_axis, prim_path, half, sh_degree, fps, time_code, spz_version, ply_frame,
                input_ply_frame, quiet):
    """Convert Gaussian splats between 3DGS PLY, OpenUSD and SPZ, chosen by file extension.

    INPUTS is one splat file, a folder of PLY files (natural order) or several files; more than
    one frame becomes one time-sampled USD stage (frame i at time code i).

    \b
    Examples:
      avatarkit convert scene.ply -o scene.usdc
      avatarkit convert scene.usdz --prim-path /World/Splats -o scene.ply
      avatarkit convert scene.ply -o scene.spz --sh-degree 1
      avatarkit convert frames/ -o anim.usdc --fps 30 --up-axis Z
      avatarkit convert avatar.ply -o viewer.ply --ply-frame ydown --input-ply-frame yup
      avatarkit convert trained.ply -o trained.spz --ply-frame ydown
    """
    from avatarkit.convert import ConvertOptions, convert, resolve_inputs

    options = ConvertOptions(up_axis=up_axis.upper(), prim_path=prim_path, half=half, sh_degree=sh_degree,
                             fps=fps, time=time_code, spz_version=int(spz_version), ply_frame=ply_frame,
                             input_ply_frame=input_ply_frame)
    target = inputs[0] if len(inputs) == 1 else list(inputs)
    frames = len(resolve_inputs(target))
    if frames > 1:
        with progress(range(frames), length=frames, label="converting", quiet=quiet) as bar:
            step = advance(bar)
            result = convert(target, output, options, progress=step)
    else:
        result = convert(target, output, options)
    if not quiet:
        frames_txt = f", {result.frames} frames" if result.frames > 1 else ""
        click.echo(f"wrote {result.output}: {result.count:,} Gaussians{frames_txt}, SH degree "
                   f"{result.sh_degree}, {_size(result.bytes)} in {result.seconds:.2f} s")
