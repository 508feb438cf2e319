"""Progress, per-file messages and the summary of a batch run, on stderr."""

from __future__ import annotations

import json
import sys
import time

import click


def run_files(
    ctx: click.Context,
    inputs,
    extensions,
    what: str,
    out_dir,
    seed: int,
    shard,
    job,
    options,
    jobs: int,
    overwrite: bool,
    json_records: bool,
) -> None:
    """Discover ``inputs``, plan their outputs, run ``job`` on each and report; exits."""
    from rawsim import batch

    found, missing = batch.discover(inputs, extensions)
    if not found:
        raise click.UsageError(f"no {what} found in {', '.join(inputs)}", ctx)
    tasks, pre_failed = batch.plan(
        found, out_dir, options.output_suffixes(), seed, batch.parse_shard(shard)
    )
    results = batch.run(
        tasks,
        job,
        jobs=jobs,
        overwrite=overwrite,
        debug=bool(ctx.obj and ctx.obj.get("debug")),
        options=options,
    )
    run_batch(ctx, tasks, results, missing + pre_failed, json_records)


def run_batch(ctx: click.Context, tasks, results_iter, pre_failed, json_records: bool) -> None:
    """Consume batch results with a progress bar; print failures, summary; exit.

    SIGINT or SIGTERM stops the job (no new file starts, workers are terminated,
    temporary files removed): the summary counts what was done, exit 130 or 143.
    """
    from rawsim.batch import Interrupted, Summary, stop_on_signals

    obj = ctx.obj or {}
    quiet, verbose, debug = obj.get("quiet"), obj.get("verbose", 0), obj.get("debug")
    summary = Summary()
    start = time.perf_counter()
    total = len(tasks) + len(pre_failed)

    def report(result) -> None:
        summary.add(result)
        if result.status == "failed":
            click.echo(f"error: {result.message}", err=True)
            if debug and result.detail:
                click.echo(result.detail.rstrip(), err=True)
        elif result.status == "skipped" and not quiet:
            click.echo(f"skip: {result.message}", err=True)
        elif verbose:
            click.echo(f"done: {result.task.source} ({result.seconds:.2f} s)", err=True)
        if not quiet:
            for warning in result.record.get("warnings", []):
                click.echo(f"warning: {result.task.source}: {warning}", err=True)
        if json_records:
            record = {
                "input": str(result.task.source),
                "status": result.status,
                "outputs": {k: str(v) for k, v in result.task.outputs.items()},
            }
            if result.status == "failed":
                record["error"] = result.message
            click.echo(json.dumps(record))

    show_bar = not quiet and sys.stderr.isatty()
    interrupted = None
    with stop_on_signals():
        try:
            with click.progressbar(
                length=total, label="rawsim", file=sys.stderr, hidden=not show_bar
            ) as bar:
                for result in pre_failed:
                    report(result)
                    bar.update(1)
                for result in results_iter:
                    report(result)
                    bar.update(1)
        except Interrupted as stop:
            interrupted = stop
            results_iter.close()  # a generator: stops its workers, if not yet done
    summary.seconds = time.perf_counter() - start
    if interrupted is not None:
        left = total - summary.done - summary.skipped - summary.failed
        message = f"rawsim: interrupted by {interrupted}: {summary}, {left} not finished"
        click.echo(message, err=True)
        ctx.exit(interrupted.exit_code)
    click.echo(f"rawsim: {summary}", err=True)
    ctx.exit(summary.exit_code)
