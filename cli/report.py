"""Progress, per-file messages and the summary of a batch run, on stderr."""

from __future__ import annotations

import json
import sys
import time

import click


def run_batch(ctx: click.Context, tasks, results_iter, pre_failed, json_records: bool) -> None:
    """Consume batch results with a progress bar; print failures, summary; exit."""
    from rawsim.batch import Summary

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
    with click.progressbar(
        length=total, label="rawsim", file=sys.stderr, hidden=not show_bar
    ) as bar:
        for result in pre_failed:
            report(result)
            bar.update(1)
        for result in results_iter:
            report(result)
            bar.update(1)
    summary.seconds = time.perf_counter() - start
    click.echo(f"rawsim: {summary}", err=True)
    ctx.exit(summary.exit_code)
