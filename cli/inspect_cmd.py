"""`avatarkit inspect FILE`: a readable summary of a PLY (and, as they land, USD, avatar, clip)."""
from __future__ import annotations

import json

import click


@click.command("inspect")
@click.argument("file", type=click.Path(dir_okay=True, file_okay=True))
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def inspect_cmd(file: str, as_json: bool) -> None:
    """Summarise FILE: for a 3DGS PLY the count, SH degree, bounds, opacity and scale
    statistics and extra properties.

    \b
    Examples:
      avatarkit inspect head.ply
      avatarkit inspect head.ply --json | jq .gaussians
    """
    from avatarkit.inspect import inspect_file

    summary = inspect_file(file)
    click.echo(json.dumps(summary.to_dict(), indent=2) if as_json else summary.to_text())
