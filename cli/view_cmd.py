"""`avatarkit view`: a bake as one self-contained HTML page that plays it in a browser."""
from __future__ import annotations

import click

from avatarkit.cli.options import advance, output_option, progress, quiet_option


def _size(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.1f} KB"


@click.command("view")
@click.argument("bake", type=click.Path())
@output_option("Output page (.html).")
@click.option("--max-size", default=None, metavar="SIZE",
              help="Cap the page's size (e.g. 50MB, 800KB, 20MiB, or bytes): splats are subsampled to fit.")
@click.option("--background", default="0,0,0", show_default=True, metavar="COLOR",
              help="r,g,b in [0, 1], #rrggbb, black, white or gray (as `avatarkit render`).")
@click.option("--fps", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Playback rate [default: the bake's; a plain PLY folder: 24].")
@click.option("--title", default=None, help="Page title [default: the input's name].")
@quiet_option
def view_cmd(bake, output, max_size, background, fps, title, quiet):
    """Write a web player for BAKE: one HTML file that plays it in any browser with WebGL2,
    nothing to install (play/pause, frame slider, drag to orbit, wheel to zoom).

    BAKE is a bake's USD stage (one file or with value clips) or PLY sequence folder, an avatar
    folder, or one splat file (.ply, .spz, .usd*). The page draws SH degree 0 (view-independent
    colour); positions are 16-bit per frame, colours and opacities 8-bit.

    \b
    Examples:
      avatarkit view clip.usdc -o clip.html
      avatarkit view clip_ply/ -o clip.html --max-size 20MB --background white
      avatarkit view me/ -o me.html
    """
    from avatarkit.export.splat_frames import open_splat_frames
    from avatarkit.export.web_player import PlayerOptions, check_output, parse_size, write_player
    from avatarkit.render.preview import parse_color

    options = PlayerOptions(max_bytes=parse_size(max_size) if max_size is not None else None,
                            background=parse_color(background), fps=fps, title=title)
    options.check()
    check_output(output)
    source = open_splat_frames(bake, fps)
    total = 2 * source.n_frames
    with progress(range(total), length=total, label="encoding", quiet=quiet) as bar:
        result = write_player(source, output, options, progress=advance(bar))
    if quiet:
        return
    if result.sh_degree_dropped:
        click.echo(f"note: the page shows SH degree 0; the source's degree {result.sh_degree_dropped} "
                   "bands (view-dependent colour) were dropped", err=True)
    dropped = sum(result.dropped.values())
    if dropped:
        parts = ", ".join(f"{n} {d:,}" for n, d in result.dropped.items() if d)
        click.echo(f"note: --max-size dropped {dropped:,} of {result.source_splats:,} splats "
                   f"({100 * dropped / result.source_splats:.1f}%: {parts})", err=True)
    click.echo(f"wrote {result.output}: {result.splats:,} splats, {result.frames} frames at "
               f"{result.fps:g} fps, {_size(result.bytes)} in {result.seconds:.1f} s")
