"""Options shared by several commands, defined once."""
from __future__ import annotations

import sys

import click

quiet_option = click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")
verbose_option = click.option("-v", "--verbose", count=True, help="More detail (repeatable).")


def output_option(help_text: str = "Output file."):
    return click.option("-o", "--output", "output", required=True,
                        type=click.Path(dir_okay=False, writable=False), help=help_text)


def progress(iterable, *, length: int | None = None, label: str = "", quiet: bool = False):
    """A progress bar on stderr for anything that may take more than a couple of seconds."""
    if quiet:
        return _NullBar(iterable)
    return click.progressbar(iterable, length=length, label=label, file=sys.stderr,
                             show_eta=True, show_pos=True)


class _NullBar:
    def __init__(self, iterable):
        self._it = iterable

    def __enter__(self):
        return self._it

    def __exit__(self, *exc):
        return False
