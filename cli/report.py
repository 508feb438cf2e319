"""Progress, per-file messages and the summary of a batch run, on stderr."""

from __future__ import annotations

import gc
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
    executor: str = "local",
    address: str | None = None,
) -> None:
    """Discover ``inputs``, plan their outputs, run ``job`` on each and report; exits."""
    from rawsim.run import batch

    found, missing, ignored = batch.discover(inputs, extensions)
    if not found:
        if missing:
            raise click.UsageError(missing[0].message, ctx)
        hint = f" (found only {_kinds(ignored)})" if ignored else ""
        raise click.UsageError(f"no {what} found in {', '.join(inputs)}{hint}", ctx)
    if executor == "ray" and jobs > 1:
        raise click.UsageError(
            "--jobs is for local workers; with --executor ray the "
            "cluster's CPUs set how many files run at once",
            ctx,
        )
    if address and executor != "ray":
        raise click.UsageError("--address needs --executor ray", ctx)
    _check_writable(ctx, out_dir)
    if ignored:
        verbose = (ctx.obj or {}).get("verbose")
        click.echo(
            f"rawsim: not taken for their extension: {_kinds(ignored)}"
            + ("" if verbose else " (-v lists them)"),
            err=True,
        )
        for path in ignored if verbose else ():
            click.echo(f"not taken: {_printable(str(path))}", err=True)
    tasks, pre_failed = batch.plan(
        found, out_dir, options.output_suffixes(), seed, batch.parse_shard(shard)
    )
    # What is loaded by now (the pipeline, numba, torch) lives as long as the process:
    # out of the collector's reach, a full collection visits only the batch's own
    # objects (they took 0.04–0.2 s of a one-file run), and forked workers do not
    # copy the pages a collection would write to.
    gc.freeze()
    results = batch.run(
        tasks,
        job,
        jobs=jobs,
        overwrite=overwrite,
        debug=bool(ctx.obj and ctx.obj.get("debug")),
        executor=executor,
        address=address,
        options=options,
    )
    run_batch(ctx, tasks, results, missing + pre_failed, json_records)


def _kinds(paths) -> str:
    """``12 files (.txt ×10, .crw ×2)``: how many, by extension."""
    from collections import Counter

    counts = Counter(p.suffix.lower() or "no extension" for p in paths)
    kinds = ", ".join(f"{ext} ×{n}" for ext, n in counts.most_common())
    return f"{len(paths)} file{'s' * (len(paths) != 1)} ({kinds})"


def _check_writable(ctx: click.Context, out_dir) -> None:
    """Create the output folder and write a file in it, before any input is read:
    exit 2 with one message if that cannot be done."""
    import tempfile
    from pathlib import Path

    from rawsim.io import remote

    out_dir = remote.localize(out_dir)
    try:
        if remote.is_url(out_dir):
            remote.check_writable(out_dir)
            return
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out_dir) as probe:  # removed on close
            probe.write(b"rawsim")
    except OSError as err:
        reason = (err.strerror or str(err)).lower()
        click.echo(f"rawsim: cannot write to {_printable(str(out_dir))}: {reason}", err=True)
        ctx.exit(2)


def _printable(text: str) -> str:
    """``text`` on one line: control characters and undecodable bytes escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


#: Sidecar entries repeated in ``--json`` records: ISO, seeds, the parameters drawn
#: (unprocess) or the values used (process), and the warnings.
_RECORD_KEYS = (
    "iso",
    "seed",
    "file_seed",
    "params",
    "noise",
    "white_balance",
    "white_balance_source",
    "color_matrix",
    "warnings",
)


def run_batch(ctx: click.Context, tasks, results_iter, pre_failed, json_records: bool) -> None:
    """Consume batch results with a progress bar; print failures, summary; exit.

    SIGINT or SIGTERM stops the job (no new file starts, workers are terminated,
    temporary files removed): the summary counts what was done, exit 130 or 143.
    """
    from rawsim.run.batch import Summary
    from rawsim.run.jobs import Interrupted, signal_received, stop_on_signals

    obj = ctx.obj or {}
    quiet, verbose, debug = obj.get("quiet"), obj.get("verbose", 0), obj.get("debug")
    summary = Summary()
    start = time.perf_counter()
    total = len(tasks) + len(pre_failed)

    def report(result) -> None:
        summary.add(result)
        if result.status == "failed":
            click.echo(f"error: {_printable(result.message)}", err=True)
            if debug and result.detail:
                click.echo(result.detail.rstrip(), err=True)
        elif result.status == "skipped" and not quiet:
            click.echo(f"skip: {_printable(result.message)}", err=True)
        elif verbose:
            click.echo(
                f"done: {_printable(str(result.task.source))} ({result.seconds:.2f} s)", err=True
            )
        if not quiet:
            for warning in result.record.get("warnings", []):
                click.echo(f"warning: {_printable(f'{result.task.source}: {warning}')}", err=True)
        if json_records:
            record = {
                "input": str(result.task.source),
                "status": result.status,
                "outputs": {k: str(v) for k, v in result.task.outputs.items()},
            }
            if result.status == "failed":
                record["error"] = result.message
            for key in _RECORD_KEYS:  # what the job drew and used, from its sidecar
                if key in result.record:
                    record[key] = result.record[key]
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
        except Exception:
            if signal_received() is None:
                raise
            interrupted = Interrupted(signal_received())  # a library's error for it
            results_iter.close()
    summary.seconds = time.perf_counter() - start
    if interrupted is not None:
        left = total - summary.done - summary.skipped - summary.failed
        message = f"rawsim: interrupted by {interrupted}: {summary}, {left} not finished"
        click.echo(message, err=True)
        ctx.exit(interrupted.exit_code)
    click.echo(f"rawsim: {summary}", err=True)
    ctx.exit(summary.exit_code)
