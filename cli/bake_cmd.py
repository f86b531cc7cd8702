"""`avatarkit bake`: an avatar driven by a motion clip, written as an animated USD stage, a PLY
sequence and/or a preview video in one pass."""
from __future__ import annotations

import time
import warnings
from pathlib import Path

import click

from avatarkit.cli.options import FiniteFloatRange, advance, cli_warnings, progress, quiet_option

_COLLISION = ("none", "vertex", "proxy")  # sim.COLLISION_MODES
_PLY_FRAMES = ("yup", "ydown")  # gaussians.ply.PLY_FRAMES
# (kept literal so `--help` imports neither pxr nor numpy; a test checks they agree)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.1f} kB"


@click.command("bake")
@click.argument("avatar_dir", metavar="AVATAR", type=click.Path())
@click.argument("clip_path", metavar="CLIP", type=click.Path())
@click.option("-o", "--output", type=click.Path(), default=None,
              help="Animated USD stage: .usdc, .usda, .usd or .usdz.")
@click.option("--ply-dir", type=click.Path(), default=None,
              help="Also write a 3DGS PLY per frame (frame_00000.ply ...) + sequence.json here.")
@click.option("--split", is_flag=True, help="PLY sequence: face_*.ply and hair_*.ply instead of one file per frame.")
@click.option("--ply-frame", type=click.Choice(_PLY_FRAMES), default="yup", show_default=True,
              help="PLY sequence axes: yup (ours, +Y up) or ydown (the 3DGS/COLMAP frame splat viewers "
                   "such as SuperSplat/PlayCanvas assume for PLY: y and z negated).")
@click.option("--preview", type=click.Path(), default=None,
              help="Also render a preview video (.mp4 or .gif) with the CPU renderer.")
@click.option("--orbit", is_flag=True, help="Preview: the camera circles the head once over the clip.")
@click.option("--preview-size", type=click.IntRange(min=16), default=384, show_default=True,
              help="Preview width and height in pixels.")
@click.option("--frames", "frame_range", default=None, metavar="A:B",
              help="Bake frames A..B-1 of the clip (A: to the end, :B from the start); output frames start at 0.")
@click.option("--fps", type=FiniteFloatRange(min=0, min_open=True), default=None,
              help="Resample the clip to this frame rate first [default: the clip's].")
@click.option("--substeps", type=click.IntRange(min=1), default=None, help="Simulation substeps per frame [default: 4].")
@click.option("--iterations", type=click.IntRange(min=1), default=None,
              help="Constraint iterations per substep [default: 15].")
@click.option("--gravity", default=None, metavar="X,Y,Z", help="Gravity in m/s^2 [default: 0,-9.81,0].")
@click.option("--collision", type=click.Choice(_COLLISION), default=None,
              help="Hair-head collision: none, vertex (cage vertices) or proxy (the paper's) [default: proxy].")
@click.option("--static-hair/--dynamic-hair", default=None,
              help="No hair dynamics (the hair follows the head rigidly), or simulate it. "
                   "[default: static for avatars built with short, rigid hair, else dynamic]")
@click.option("--preroll", type=FiniteFloatRange(min=0), default=None,
              help="Seconds the hair settles at the first pose before frame 0 [default: 1].")
@click.option("--half", is_flag=True, help="USD: half-precision splat attributes.")
@click.option("--usd-points", is_flag=True,
              help="USD: Face and Hair as UsdGeom.Points (+ orientations, widths, colour, SH primvars) "
                   "for tools that do not read the 3D Gaussian splat schema yet.")
@click.option("--chunk-frames", type=click.IntRange(min=0), default=50, show_default=True,
              help="USD: frames per value-clip layer (0: one layer).")
@quiet_option
def bake_cmd(avatar_dir, clip_path, output, ply_dir, split, ply_frame, preview, orbit, preview_size, frame_range,
             fps, substeps, iterations, gravity, collision, static_hair, preroll, half, usd_points,
             chunk_frames, quiet):
    """Bake the motion CLIP on the AVATAR folder: the head follows the clip (LBS), the bald
    Gaussians ride its triangles, the hair cage is simulated (XPBD) and carries the hair.
    Frames are computed once and streamed to every output.

    CLIP: a motion .npz (GaussianAvatars/VHAP keys, or `avatarkit motion make`), .json, or a
    folder of per-frame VHAP .npz files.

    \b
    Examples:
      avatarkit avatar sample -o sample_avatar
      avatarkit motion make shake -o shake.npz
      avatarkit bake sample_avatar shake.npz -o shake.usdc
      avatarkit bake sample_avatar shake.npz -o shake.usdz --half --preview shake.mp4
      avatarkit bake sample_avatar shake.npz --ply-dir shake_ply --split --frames 10:40
      avatarkit bake sample_avatar shake.npz --ply-dir shake_ply --ply-frame ydown   # for SuperSplat
      avatarkit bake sample_avatar whip.npz -o whip.usdc --collision vertex --substeps 8
    """
    from avatarkit.errors import InputError

    # every output is checked before anything is loaded or baked
    if not (output or ply_dir or preview):
        raise InputError("nothing to write: give -o OUT.usdc, --ply-dir DIR and/or --preview OUT.mp4")
    from avatarkit.bake_writers import check_output

    out_path = check_output("usd", output) if output else None
    ply_path = check_output("ply", ply_dir) if ply_dir else None
    preview_path = check_output("preview", preview) if preview else None
    if (split or ply_frame != "yup") and not ply_dir:
        raise InputError("--split and --ply-frame apply to the PLY sequence: give --ply-dir too")
    if (orbit or preview_size != 384) and not preview:
        raise InputError("--orbit and --preview-size apply to the preview: give --preview too")

    from avatarkit.bake import BakeConfig, run_bake
    from avatarkit.bake_writers import make_writer, output_bytes, usd_clips_folder
    from avatarkit.render.preview import parse_vec3
    from avatarkit.sim.config import SimConfig

    sim = {}
    if substeps is not None:
        sim["substeps"] = substeps
    if iterations is not None:
        sim["iterations"] = iterations
    if gravity is not None:
        sim["gravity"] = parse_vec3(gravity, "--gravity")
    if collision is not None:
        sim["collision"] = collision
    if static_hair is not None:  # unset: the avatar decides (static for rigid hair)
        sim["static"] = static_hair
    config = BakeConfig(frames=BakeConfig.parse_frames(frame_range) if frame_range else None, fps=fps,
                        sim=SimConfig(**sim), preroll=preroll)

    t0 = time.perf_counter()
    with cli_warnings(quiet):
        from avatarkit.avatar import load_avatar
        from avatarkit.motion import load_clip

        avatar = load_avatar(avatar_dir)
        clip = load_clip(clip_path)
        outputs = (("usd", out_path, {"half": half, "usd_points": usd_points, "chunk_frames": chunk_frames}),
                   ("ply", ply_path, {"split": split, "ply_frame": ply_frame}),
                   ("preview", preview_path, {"size": preview_size, "orbit": orbit}))
        writers = [make_writer(kind, path, opts) for kind, path, opts in outputs if path is not None]
        from avatarkit.bake import prepare_clip

        try:  # the clip's problems name the clip file
            _, start, stop = prepare_clip(clip, avatar.head_model, config)
        except InputError as e:
            raise e.with_path(clip_path) from None
        total = stop - start
        if out_path is not None and chunk_frames and total > chunk_frames and out_path.suffix.lower() != ".usdz":
            from avatarkit.export.usd_stage import check_clips_folder, clips_folder_for

            # before the (seconds of) hair weights: a bake never replaces what it did not create
            check_clips_folder(clips_folder_for(out_path))
        deformer = avatar.rig.deformer if avatar.rig is not None else None
        if deformer is not None and not deformer.weights_ready:
            # Avatar folders do not store the hair's MVC weights; computing them takes seconds.
            with progress(range(len(avatar.hair)), length=1, label="hair weights", quiet=quiet) as wbar:
                def weights_step(done, todo):
                    if hasattr(wbar, "length"):
                        wbar.length = todo
                        wbar.update(done - wbar.pos)

                deformer.ensure_weights(progress=weights_step)
        t_load = time.perf_counter() - t0
        with progress(range(total), length=total, label="baking", quiet=quiet) as bar:
            step = advance(bar)
            with warnings.catch_warnings():  # prepare_clip already said it
                warnings.filterwarnings("ignore", message=".*expression coefficients.*")
                summary = run_bake(avatar, clip, config, writers, progress=step)
    if quiet:
        return
    click.echo(f"baked {summary.frames} frames of {Path(clip_path).name} on {avatar.name} "
               f"({len(avatar.bald):,} bald + {len(avatar.hair):,} hair Gaussians) in "
               f"{summary.seconds:.1f} s: {summary.fps:.1f} frames/s (+{t_load:.1f} s loading)")
    labels = {"usd": "USD stage", "ply": "PLY sequence", "preview": "preview"}
    for kind, path, _ in outputs:
        if path is None:
            continue
        label = labels[kind]
        clips = usd_clips_folder(path) if kind == "usd" else None
        if clips is not None:
            label += f" (+ {clips.name}/)"
        click.echo(f"  {label:<26} {path}  {_mb(output_bytes(kind, path))}")
    stages = ", ".join(f"{k} {v:.2f} s" for k, v in summary.timings.items())
    click.echo(f"  time: {stages}")
