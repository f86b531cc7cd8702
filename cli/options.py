"""Options shared by several commands, defined once."""
from __future__ import annotations

import contextlib
import math
import sys
import warnings

import click

class FiniteFloatRange(click.FloatRange):
    """click.FloatRange that also refuses nan and infinities (which compare False with every
    bound, so a plain FloatRange lets them through)."""

    name = "finite float"

    def convert(self, value, param, ctx):
        rv = super().convert(value, param, ctx)
        if rv is not None and not math.isfinite(rv):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return rv


#: a finite float, any value
FINITE = FiniteFloatRange()

quiet_option = click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")

#: `--refine`'s choices: `track.tracker.REFINE_SETTINGS`' names, written out because the commands
#: do not import the library to build their options (a test keeps the two equal)
REFINE_NAMES = ("photometric", "photometric-pose", "photometric-fast")
refine_every_option = click.option(
    "--refine-every", type=click.IntRange(min=1), default=None,
    help="With --refine: refine every k-th frame, interpolate the change between (default 1; photometric-fast: 5).")
verbose_option = click.option("-v", "--verbose", count=True, help="More detail (repeatable).")


def output_option(help_text: str = "Output file."):
    return click.option("-o", "--output", "output", required=True,
                        type=click.Path(dir_okay=False, writable=False), help=help_text)


def progress(iterable, *, length: int | None = None, label: str = "", quiet: bool = False):
    """A progress bar on stderr for anything that may take more than a couple of seconds; none
    when stderr is not a terminal (click would print the bare label there, and a log or a
    script reading stderr wants the result or the one error line only)."""
    if quiet or not _is_terminal(sys.stderr):
        return _NullBar(iterable)
    return click.progressbar(iterable, length=length, label=label, file=sys.stderr,
                             show_eta=True, show_pos=True)


@contextlib.contextmanager
def cli_warnings(quiet: bool):
    """Library warnings as one `warning: ...` line each on stderr (none with --quiet), printed
    when the block succeeds; a block that fails drops them, so the error is the only line."""
    held: list[str] = []

    def show(message, category, filename, lineno, file=None, line=None):
        held.append(str(message))

    with warnings.catch_warnings():
        # ours (and other UserWarnings) are for the user; deprecation and resource noise is not
        warnings.simplefilter("ignore")
        warnings.simplefilter("always", UserWarning)
        warnings.showwarning = show
        yield
    if not quiet:
        for message in dict.fromkeys(held):
            click.echo(f"warning: {message}", err=True)


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def advance(bar):
    """A library-style `progress(done, total)` callback that moves `bar` to `done`."""
    last = [0]

    def step(done, _total=None):
        if hasattr(bar, "update"):
            bar.update(done - last[0])
        last[0] = done

    return step


class _NullBar:
    def __init__(self, iterable):
        self._it = iterable

    def __enter__(self):
        return self._it

    def __exit__(self, *exc):
        return False
