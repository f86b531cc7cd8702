"""`avatarkit bake-batch`: many bakes from one batch file, on a local process pool or on Ray."""
from __future__ import annotations

import click

from avatarkit.cli.options import progress, quiet_option, verbose_option

_ENGINES = ("local", "ray")  # batch.engines.ENGINES, literal so --help imports nothing heavy

# Some jobs failed (each named in the report) while the batch itself ran: not 1, which means an
# unexpected bug, and not 2, which means the batch file is wrong and nothing ran.
EXIT_JOBS_FAILED = 3


@click.command("bake-batch")
@click.argument("batch_file", metavar="BATCH", type=click.Path())
@click.option("-o", "--output", "outdir", required=True, type=click.Path(file_okay=False),
              help="Output folder (created if missing); outputs are named by the batch file's templates.")
@click.option("--engine", type=click.Choice(_ENGINES), default="local", show_default=True,
              help="local: a process pool on this machine; ray: Ray tasks (a local Ray instance, or --address).")
@click.option("--address", default=None, metavar="RAY_ADDRESS",
              help="Ray: run on this existing cluster (e.g. ray://head:10001 or auto) [default: start a "
                   "local instance].")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Jobs run at once [default: this machine's CPUs; with --address, the cluster's].")
@click.option("--retries", type=click.IntRange(min=0), default=2, show_default=True,
              help="Extra attempts after a transient failure (I/O error, a worker that died); bad inputs "
                   "are never retried.")
@click.option("--force", is_flag=True, help="Bake every job again, even those whose outputs are up to date.")
@quiet_option
@verbose_option
def bake_batch_cmd(batch_file, outdir, engine, address, workers, retries, force, quiet, verbose):
    """Bake every job of the BATCH file (JSON, see schemas/batch.schema.json) into OUTDIR.

    Each job is an avatar (or several) x a clip (or several, or a folder of clips) with its
    outputs (USD stage, PLY sequence, preview) and settings; `defaults` apply to all jobs.
    A job whose outputs are complete and up to date (same inputs, settings and avatarkit
    version, recorded in <output>.job.json) is skipped, so a re-run redoes only what is
    missing. A failing job is reported and does not stop the others. The summary is also
    written to OUTDIR/batch_report.json. Exit code 3 if any job failed, 2 for a bad batch file.

    \b
    Examples:
      avatarkit avatar sample -o samples/avatars/alice --n-hair 5000 --n-bald 5000
      avatarkit motion make nod -o samples/clips/nod.npz
      avatarkit bake-batch samples/batch.json -o out
      avatarkit bake-batch samples/batch.json -o out --workers 4 --retries 1
      avatarkit bake-batch samples/batch.json -o out --engine ray
      avatarkit bake-batch samples/batch.json -o out --engine ray --address ray://head:10001
    """
    from avatarkit.batch import BatchInterrupted, format_summary, load_batch, run_batch
    from avatarkit.errors import InputError

    if address and engine != "ray":
        raise InputError("--address applies to --engine ray")
    batch = load_batch(batch_file)
    bar_ctx = progress(range(len(batch)), length=len(batch), label="jobs", quiet=quiet)
    with bar_ctx as bar:
        def on_event(event):
            if event.kind in ("done", "skipped", "failed", "cancelled"):
                if hasattr(bar, "update"):
                    bar.update(1)
                if event.kind == "failed" and not quiet:
                    # on its own line, so it is not lost under the bar
                    click.echo(f"\nfailed: {event.job}: {event.result.error}", err=True)
            elif event.kind == "retry" and verbose and not quiet:
                click.echo(f"\nretrying {event.job}: {event.message}", err=True)

        try:
            report = run_batch(batch, outdir, engine=engine, workers=workers, retries=retries,
                               address=address, force=force, on_event=on_event)
        except BatchInterrupted as e:
            report = e.report
            if not quiet:
                click.echo("", err=True)
                click.echo(format_summary(report, verbose=bool(verbose)), err=True)
            raise KeyboardInterrupt from None
    if not quiet:
        click.echo(format_summary(report, verbose=bool(verbose)))
    return 0 if report.ok else EXIT_JOBS_FAILED
