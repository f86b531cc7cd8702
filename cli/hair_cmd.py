"""`avatarkit transfer-hair` (one avatar's hair on another's head) and `avatarkit hair-grid`
(one head wearing several hairstyles, on a contact sheet)."""
from __future__ import annotations

import click

from avatarkit.cli.options import FiniteFloatRange, advance, progress, quiet_option

_MARGIN_HELP = ("Metres outside the target head where hair pushed out of it lands (none stays "
                "closer than half of it).")


def _margin_option(f):
    return click.option("--margin", type=FiniteFloatRange(0.0, 0.05), default=0.0015, show_default=True,
                        help=_MARGIN_HELP)(f)


def _keep_skin_option(f):
    return click.option("--keep-skin", is_flag=True,
                        help="Skip the clean-up that drops hair Gaussians looking like the source's "
                             "skin.")(f)


def _check_png_output(path) -> None:
    """Fail on an unusable image path before any work (OutputError: exit 2)."""
    from pathlib import Path

    from avatarkit.errors import OutputError
    from avatarkit.fileio import check_output_folder

    p = Path(path)
    if p.suffix.lower() != ".png":
        raise OutputError(f"the image must be a .png file, got {p.suffix or 'no extension'}", p)
    check_output_folder(p.parent)
    if p.is_dir():
        raise OutputError("is a folder, expected a .png file", p)


def _folder_name(path) -> str:
    from pathlib import Path

    p = Path(path)
    return (p.resolve() if p.name in ("", ".", "..") else p).name


class _Bar:
    """progress(done, total) callbacks -> a click progress bar (or nothing when quiet)."""

    def __init__(self, bar):
        self.bar, self.last = bar, 0

    def __call__(self, done, total):
        pct = int(100 * done / max(total, 1))
        if hasattr(self.bar, "update") and pct > self.last:
            self.bar.update(pct - self.last)
            self.last = pct


@click.command("transfer-hair")
@click.option("--hair", "hair_source", required=True, type=click.Path(),
              help="Avatar folder whose hair is taken.")
@click.option("--onto", "target", required=True, type=click.Path(),
              help="Avatar folder whose head and identity get the hair.")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="Avatar folder to write (an existing avatar folder is replaced).")
@click.option("--preview", "preview_png", type=click.Path(dir_okay=False), default=None,
              help="Also write a front view of the result to this .png.")
@_margin_option
@_keep_skin_option
@click.option("--cage", type=click.Choice(["rebuild", "carry"]), default="rebuild", show_default=True,
              help="A fresh cage around the seated hair, or the source's cage re-seated (rebuilt "
                   "if it no longer holds the hair).")
@click.option("--cage-vertices", type=click.IntRange(min=20), default=500, show_default=True,
              help="Vertices of a fresh cage (at most).")
@click.option("--name", default=None, help="Name of the result [default: <target>_<source>_hair].")
@quiet_option
def transfer_hair_cmd(hair_source, target, output, preview_png, margin, keep_skin, cage, cage_vertices,
                      name, quiet):
    """Put the hair of one avatar on another avatar's head: the hair is re-expressed relative to
    the source's scalp, re-seated on the target's scalp (another size or shape), cleaned of the
    source's skin, pushed outside the target head by --margin, and given a fresh cage, weights
    and simulation roots. The result is an avatar folder that bakes like any other.

    \b
    Examples:
      avatarkit transfer-hair --hair alice --onto bob -o bob_with_alice_hair
      avatarkit transfer-hair --hair alice --onto bob -o out --preview out.png --margin 0.002
      avatarkit bake out nod.npz -o nod.usdc
    """
    import time

    from avatarkit.avatar import check_avatar_target, load_avatar
    from avatarkit.hairstyle import transfer_hair

    from avatarkit.fileio import check_not_an_input

    check_not_an_input(output, {"--hair": hair_source, "--onto": target})
    check_avatar_target(output)  # fail on a bad output before loading and rigging
    if preview_png:
        _check_png_output(preview_png)
    t0 = time.perf_counter()
    source = load_avatar(hair_source)
    onto = load_avatar(target)
    with progress(range(100), length=100, label="cage weights", quiet=quiet) as bar:
        result = transfer_hair(source, onto, margin, cleanup=not keep_skin, cage=cage,
                               cage_vertices=cage_vertices, name=name, progress=_Bar(bar))
    path = result.save(output)
    if preview_png:
        from avatarkit.export.images import read_png, write_png

        write_png(preview_png, read_png(path / "preview.png")[..., :3])
    if not quiet:
        t = result.provenance["transfer"]
        click.echo(f"wrote {path}: {result.name}, {t['hair']:,} hair Gaussians of {t['source_hair']:,} "
                   f"({t['dropped_skin']} dropped as skin, {t['pushed_outside']} pushed outside the "
                   f"head), head scale {t['head_scale']:.3f}, {t['cage']} cage of "
                   f"{result.cage.n_vertices} vertices, {time.perf_counter() - t0:.1f} s")
        if preview_png:
            click.echo(f"wrote {preview_png}")


@click.command("hair-grid")
@click.option("--head", "head", required=True, type=click.Path(),
              help="Avatar folder whose head wears the hairstyles.")
@click.option("--hair", "hair", multiple=True, required=True, type=click.Path(),
              help="Avatar folder(s) whose hair to show: --hair A1 A2 ... (or --hair A1 --hair A2).")
@click.argument("more_hair", nargs=-1, type=click.Path(), metavar="")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="Contact sheet .png.")
@click.option("--views", default="front,three-quarter", show_default=True,
              help="Comma-separated columns: front, three-quarter, profile, back, top.")
@click.option("--size", type=click.IntRange(16, 4096), default=384, show_default=True,
              help="Pixels per cell (square).")
@click.option("--own", "include_own", is_flag=True, help="First row: the head with its own hair.")
@_margin_option
@_keep_skin_option
@click.option("--no-labels", is_flag=True, help="Do not write names on the cells.")
@quiet_option
def hair_grid_cmd(head, hair, more_hair, output, views, size, include_own, margin, keep_skin, no_labels,
                  quiet):
    """A hair library view: the head of one avatar wearing the hair of several others, one row
    per hairstyle and one column per view, on one PNG contact sheet.

    \b
    Examples:
      avatarkit hair-grid --head bob --hair alice carol dave -o looks.png
      avatarkit hair-grid --head bob --hair alice carol -o looks.png --views front,profile,back --own
    """
    from avatarkit.avatar import load_avatar
    from avatarkit.export.images import write_png
    from avatarkit.hairstyle.grid import hair_grid, parse_views

    names = parse_views(views)  # bad input fails before loading anything
    _check_png_output(output)
    head_avatar = load_avatar(head)
    paths = [*hair, *more_hair]
    sources = [load_avatar(p) for p in paths]
    total = (len(sources) + int(include_own)) * len(names)
    with progress(range(total), length=total, label="rendering", quiet=quiet) as bar:
        step = advance(bar)
        grid = hair_grid(head_avatar, sources, names, size, include_own=include_own, margin=margin,
                         cleanup=not keep_skin, labels=not no_labels,
                         names=[_folder_name(p) for p in paths], progress=step)
    write_png(output, grid.image)
    if not quiet:
        h, w = grid.image.shape[:2]
        click.echo(f"wrote {output}: {len(grid.rows)} hairstyles x {len(grid.views)} views on "
                   f"{head_avatar.name}, {w}x{h}")
