"""`avatarkit render`: preview splats on the CPU as a PNG, a contact sheet or a turntable clip."""
from __future__ import annotations

from pathlib import Path

import click

from avatarkit.cli.options import FINITE, FiniteFloatRange, advance, cli_warnings, output_option, progress, quiet_option


@click.command("render")
@click.argument("splats", type=click.Path())
@output_option("Output: .png (one view, or --contact-sheet), .mp4 or .gif (a turntable).")
@click.option("--width", type=click.IntRange(min=1), default=None,
              help="Image width in pixels [default: 512, or the --camera file's].")
@click.option("--height", type=click.IntRange(min=1), default=None,
              help="Image height in pixels [default: 512, or the --camera file's].")
@click.option("--fov", type=FiniteFloatRange(0, 180, min_open=True, max_open=True), default=30.0,
              show_default=True, help="Vertical field of view in degrees.")
@click.option("--azimuth", type=FINITE, default=0.0, show_default=True,
              help="Degrees around +Y; 0 looks at the face from the front (+Z). A turntable starts here.")
@click.option("--elevation", type=FINITE, default=0.0, show_default=True,
              help="Degrees above the horizon.")
@click.option("--distance", type=FiniteFloatRange(min=0, min_open=True), default=None,
              help="Camera distance in metres [default: frames the splats].")
@click.option("--target", default=None, metavar="X,Y,Z",
              help="Point the camera orbits and looks at [default: the splats' centre].")
@click.option("--background", default="0,0,0", show_default=True, metavar="COLOR",
              help="r,g,b in [0, 1], #rrggbb, black, white or gray.")
@click.option("--camera", "camera_file", type=click.Path(dir_okay=False), default=None,
              help="Camera JSON (fx, fy, cx, cy, width, height, world_to_camera, convention).")
@click.option("--turntable", type=click.IntRange(min=1), default=None, metavar="N",
              help="N views around the subject as an .mp4/.gif [default for videos: 36].")
@click.option("--contact-sheet", type=click.IntRange(min=1), default=None, metavar="N",
              help="N views around the subject on one PNG.")
@click.option("--columns", type=click.IntRange(min=1), default=None, help="Contact sheet columns.")
@click.option("--fps", type=FiniteFloatRange(min=0, min_open=True), default=24.0, show_default=True,
              help="Frames per second of a video.")
@click.option("--crf", type=click.IntRange(0, 51), default=None,
              help="H.264 quality of an .mp4: 0 best .. 51 worst, +6 about halves the size [default: 20].")
@quiet_option
def render_cmd(splats, output, width, height, fov, azimuth, elevation, distance, target, background,
               camera_file, turntable, contact_sheet, columns, fps, crf, quiet):
    """Render SPLATS (3DGS .ply, .spz, USD, or an avatar folder: its bald and hair Gaussians at
    rest) with the standard 3DGS image formation on the CPU.

    The default camera frames the splats from the front (+Z) with +Y up.

    \b
    Examples:
      avatarkit render head.ply -o head.png
      avatarkit render me/ -o me.gif --turntable 36
      avatarkit render head.ply -o side.png --azimuth 90 --elevation 10 --background white
      avatarkit render head.ply -o spin.mp4 --turntable 72 --fps 24
      avatarkit render head.ply -o spin.gif --turntable 24 --width 256 --height 256
      avatarkit render head.ply -o views.png --contact-sheet 8 --columns 4
      avatarkit render scene.ply -o view.png --camera scene.camera.json
    """
    from avatarkit.render.camera import Camera
    from avatarkit.render.preview import (DEFAULT_TURNTABLE_FRAMES, PreviewOptions, output_kind,
                                          parse_color, parse_vec3, render_preview)

    options = PreviewOptions(
        width=width, height=height, fov_deg=fov, azimuth_deg=azimuth, elevation_deg=elevation,
        distance=distance, target=parse_vec3(target, "--target") if target else None,
        background=parse_color(background),
        camera=Camera.from_json(camera_file) if camera_file else None,
        turntable=turntable, contact_sheet=contact_sheet, columns=columns, fps=fps, crf=crf)
    kind = output_kind(output, options)  # fail on a bad output name before loading anything
    if crf is not None and Path(output).suffix.lower() != ".mp4":
        from avatarkit.errors import InputError
        raise InputError("--crf sets the H.264 quality of .mp4 outputs only", output)
    with cli_warnings(quiet):
        if kind == "image":
            result = render_preview(splats, output, options)
        else:
            total = contact_sheet if kind == "contact_sheet" else (turntable or DEFAULT_TURNTABLE_FRAMES)
            with progress(range(total), length=total, label="rendering", quiet=quiet) as bar:
                step = advance(bar)
                result = render_preview(splats, output, options, progress=step)
    if not quiet:
        what = {"image": "image", "contact_sheet": f"contact sheet of {result.frames} views",
                "video": f"{result.frames}-frame turntable"}[result.kind]
        click.echo(f"wrote {result.output}: {what}, {result.width}x{result.height}, "
                   f"{result.seconds:.2f} s")
