"""`avatarkit` entry point: a lazily loaded command group and the one place errors become exit codes.

Exit codes (DESIGN.md): 0 ok; 2 bad input (one line naming the file and the problem, no
traceback); 1 an unexpected bug; 3 (`bake-batch`) the batch ran and some of its jobs failed (the
report names them); 130 interrupted (Ctrl-C); 143 terminated (SIGTERM).

SIGTERM is handled like Ctrl-C: it raises `Terminated` (a KeyboardInterrupt) in the main thread,
so every writer's cleanup runs and nothing partial is left. Library warnings are held while a
command runs: printed as `warning: ...` lines when it succeeds, dropped when it fails, so a
failure is exactly one line on stderr.
"""
from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
import threading
import warnings

import click

# Command name -> "module:attribute" under avatarkit.cli. Loaded only when used, so
# `avatarkit --help` stays fast and one command's heavy imports never slow another.
COMMANDS: dict[str, str] = {
    "inspect": "avatarkit.cli.inspect_cmd:inspect_cmd",
    "head": "avatarkit.cli.head_cmd:head",
    "motion": "avatarkit.cli.motion_cmd:motion",
    "convert": "avatarkit.cli.convert_cmd:convert_cmd",
    "render": "avatarkit.cli.render_cmd:render_cmd",
    "bake": "avatarkit.cli.bake_cmd:bake_cmd",
    "avatar": "avatarkit.cli.avatar_cmd:avatar",
    "build": "avatarkit.cli.build_cmd:build_cmd",
    "face": "avatarkit.cli.face_cmd:face_cmd",
    "bake-batch": "avatarkit.cli.batch_cmd:bake_batch_cmd",
    "transfer-hair": "avatarkit.cli.hair_cmd:transfer_hair_cmd",
    "hair-grid": "avatarkit.cli.hair_cmd:hair_grid_cmd",
    "track": "avatarkit.cli.track_cmd:track_cmd",
    "evaluate": "avatarkit.cli.evaluate_cmd:evaluate_cmd",
    "view": "avatarkit.cli.view_cmd:view_cmd",
}


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        target = COMMANDS.get(name)
        if target is None:
            return None
        module, attr = target.split(":")
        return getattr(importlib.import_module(module), attr)


def _version() -> str:
    from avatarkit import __version__
    return __version__


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(_version(), "--version", prog_name="avatarkit")
def cli():
    """avatarkit: one portrait in, an animated 3D Gaussian head avatar out.

    Build avatars, bake motion clips to OpenUSD / 3DGS PLY sequences and render previews on the CPU.
    """


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: unwinds like Ctrl-C (every writer cleans up), exit code 143."""


def _on_sigterm(signum, frame):
    raise Terminated()


@contextlib.contextmanager
def _sigterm_as_interrupt():
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def held_warnings(held: list[str]):
    """Collect the library's warnings (UserWarnings; numpy's RuntimeWarnings and deprecation
    noise are not for users) into `held` instead of printing them."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        warnings.simplefilter("default", UserWarning)
        warnings.showwarning = lambda message, *a, **k: held.append(str(message))
        yield


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns (and exits with) the exit code."""
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    from avatarkit.errors import AvatarKitError

    args = sys.argv[1:] if argv is None else list(argv)
    held: list[str] = []
    try:
        with _sigterm_as_interrupt(), held_warnings(held):
            rv = cli.main(args=argv, prog_name="avatarkit", standalone_mode=False)
        code = rv if isinstance(rv, int) else 0
        if not ({"-q", "--quiet"} & set(args)):
            for message in dict.fromkeys(held):
                click.echo(f"warning: {message}", err=True)
    except AvatarKitError as e:
        # one line whatever a lower layer's text held (a library message quoting a multi-line one)
        click.echo("error: " + " ".join(part.strip() for part in str(e).splitlines() if part.strip()), err=True)
        code = 2
    except click.exceptions.Abort as e:  # click turns a KeyboardInterrupt into Abort
        terminated = isinstance(e.__cause__ or e.__context__, Terminated)
        click.echo("terminated" if terminated else "interrupted", err=True)
        code = 143 if terminated else 130
    except Terminated:
        click.echo("terminated", err=True)
        code = 143
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        code = 130
    except click.ClickException as e:
        e.show()
        code = e.exit_code
    except click.exceptions.Exit as e:
        code = e.exit_code
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":
    main()
