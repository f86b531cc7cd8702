"""`avatarkit avatar`: make the sample avatar, and summarise avatar folders."""
from __future__ import annotations

import json

import click

from avatarkit.cli.options import progress, quiet_option

_STYLES = ("long_straight", "bob", "ponytail", "curly", "short")  # synthetic.HAIR_STYLES, kept
# literal so `--help` does not import numpy; tests check they agree


@click.group("avatar")
def avatar():
    """Make and inspect avatar folders (avatar.json, bald.ply, hair.ply, cage.ply, rig.npz,
    preview.png)."""


@avatar.command("sample")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
              help="Avatar folder to write (an existing avatar folder is replaced).")
@click.option("--hair-style", type=click.Choice(_STYLES), default="long_straight", show_default=True,
              help="Procedural hair style.")
@click.option("--n-hair", type=click.IntRange(min=100), default=50_000, show_default=True,
              help="Hair Gaussians (strands that do not root on the scalp are dropped, so a few "
                   "styles end up with fewer).")
@click.option("--n-bald", type=click.IntRange(min=100), default=50_000, show_default=True,
              help="Bald head Gaussians.")
@click.option("--seed", type=int, default=0, show_default=True, help="Varies the hair and the skin.")
@click.option("--no-preview", is_flag=True, help="Do not render preview.png.")
@quiet_option
def sample(output, hair_style, n_hair, n_bald, seed, no_preview, quiet):
    """Write the sample avatar, made in code: the built-in template head, bald Gaussians on
    its surface, procedural hair grown from its scalp, the hair cage and its rig.

    \b
    Examples:
      avatarkit avatar sample -o sample_avatar
      avatarkit avatar sample -o bob --hair-style bob --n-hair 20000 --n-bald 30000
      avatarkit bake sample_avatar nod.npz -o nod.usdc
    """
    import time

    from avatarkit.avatar import check_avatar_target
    from avatarkit.synthetic.sample_avatar import make_sample_avatar

    check_avatar_target(output)  # fail on a bad output before tens of seconds of work
    t0 = time.perf_counter()
    if not quiet:
        click.echo("building the sample avatar (head, hair, cage, simulation model)...", err=True)
    with progress(range(100), length=100, label="cage weights", quiet=quiet) as bar:
        last = [0]

        def step(done, total):
            pct = int(100 * done / max(total, 1))
            if hasattr(bar, "update") and pct > last[0]:
                bar.update(pct - last[0])
                last[0] = pct

        av = make_sample_avatar(n_hair=n_hair, n_bald=n_bald, style=hair_style, seed=seed,
                                progress=step)
    path = av.save(output, preview=not no_preview)
    if not quiet:
        c = av.counts()
        size = sum(p.stat().st_size for p in path.iterdir())
        click.echo(f"wrote {path}: {c['bald']:,} bald + {c['hair']:,} hair Gaussians, "
                   f"{c['cage_vertices']} cage vertices, {size / 1e6:.1f} MB, "
                   f"{time.perf_counter() - t0:.1f} s")


@avatar.command("info")
@click.argument("folder", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option("--check", is_flag=True,
              help="Also load every file and check it (counts, bindings, rig), as a bake would.")
def info(folder, as_json, check):
    """Summarise the avatar FOLDER (same as `avatarkit inspect FOLDER`).

    \b
    Examples:
      avatarkit avatar info sample_avatar
      avatarkit avatar info sample_avatar --check --json
    """
    from avatarkit.avatar import inspect_avatar, load_avatar

    summary = inspect_avatar(folder)
    if check:
        load_avatar(folder)
        summary.add("check", "ok: every file loads and agrees with avatar.json")
    click.echo(json.dumps(summary.to_dict(), indent=2) if as_json else summary.to_text())
