"""Progress, per-file messages and the summary of a batch run, on stderr."""

from __future__ import annotations

import gc
import json
import sys
import time
from dataclasses import dataclass

import click


@dataclass
class Inputs:
    """What :func:`check_inputs` found and checked, for :func:`run_files`."""

    found: list
    missing: list
    ignored: list
    out_dir: str
    shard: tuple[int, int]


def check_inputs(
    ctx: click.Context,
    inputs,
    extensions,
    what: str,
    out_dir,
    shard,
    jobs: int = 1,
    executor: str = "local",
    address: str | None = None,
) -> Inputs:
    """Find ``inputs`` and check the options of the batch, before anything heavy
    (torch, numba, the image libraries) is imported: each mistake exits 2 at once,
    with one line naming what was given, what is wrong and what to do.

    The output folder is checked, not made: the first output written makes it, so a
    run that writes nothing leaves no folder behind.
    """
    from rawsim.errors import RawsimError
    from rawsim.run import batch

    if executor == "ray" and jobs > 1:
        raise click.UsageError(
            "--jobs is for local workers; with --executor ray the "
            "cluster's CPUs set how many files run at once: drop --jobs",
            ctx,
        )
    if address and executor != "ray":
        raise click.UsageError("--address needs --executor ray: add it, or drop --address", ctx)
    try:
        parts = batch.parse_shard(shard)
    except RawsimError as err:
        raise click.BadParameter(str(err), ctx, param_hint="'--shard'") from None
    found, missing, ignored = batch.discover(inputs, extensions)
    if not found:
        if missing:
            raise click.UsageError(missing[0].message, ctx)
        listed = ", ".join(_printable(str(i)) for i in inputs)
        if ignored:
            why = f"found only {_kinds(ignored)}"
        else:
            why = "it is empty" if len(inputs) == 1 else "they are empty"
        raise click.UsageError(
            f"no {what} in {listed} ({why}): give folders of {_extensions(extensions)} "
            "files, or name a file to take it whatever its extension",
            ctx,
        )
    _check_writable(ctx, out_dir)
    return Inputs(found, missing, ignored, out_dir, parts)


def run_files(
    ctx: click.Context,
    checked: Inputs,
    seed: int,
    job,
    options,
    jobs: int,
    overwrite: bool,
    json_records: bool,
    executor: str = "local",
    address: str | None = None,
    said: tuple[str, ...] = (),
) -> None:
    """Plan the outputs of the inputs :func:`check_inputs` found, run ``job`` on each
    and report; exits. ``said``: warnings the command printed once for the whole run,
    not repeated for each file (the sidecars still record them)."""
    from rawsim.run import batch

    if checked.ignored:
        verbose = (ctx.obj or {}).get("verbose")
        click.echo(
            f"rawsim: not taken for their extension: {_kinds(checked.ignored)}"
            + ("" if verbose else " (-v lists them)"),
            err=True,
        )
        for path in checked.ignored if verbose else ():
            click.echo(f"not taken: {_printable(str(path))}", err=True)
    tasks, pre_failed = batch.plan(
        checked.found, checked.out_dir, options.output_suffixes(), seed, checked.shard
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
    run_batch(ctx, tasks, results, checked.missing + pre_failed, json_records, said)


def _extensions(extensions, shown: int = 6) -> str:
    """``.png, .jpg, .tif, … (14 kinds)``: the first few extensions a command takes."""
    exts = list(dict.fromkeys(e.lower() for e in extensions))
    more = f", … ({len(exts)} kinds)" if len(exts) > shown else ""
    return ", ".join(exts[:shown]) + more


def _kinds(paths) -> str:
    """``12 files (.txt ×10, .crw ×2)``: how many, by extension."""
    from collections import Counter

    counts = Counter(p.suffix.lower() or "no extension" for p in paths)
    kinds = ", ".join(f"{ext} ×{n}" for ext, n in counts.most_common())
    return f"{len(paths)} file{'s' * (len(paths) != 1)} ({kinds})"


def _check_writable(ctx: click.Context, out_dir) -> None:
    """Check that the output folder can be written, without making it (the first
    output written makes it): exit 2 with one message if it cannot be."""
    import os
    import tempfile
    from pathlib import Path

    from rawsim.io import remote

    out_dir = remote.localize(out_dir)
    shown = _printable(str(out_dir))
    try:
        if remote.is_url(out_dir):
            remote.check_writable(out_dir)
            return
        folder = Path(out_dir)
        nearest = folder  # the folder itself, or the nearest of its parents that exists
        while not nearest.exists() and nearest != nearest.parent:
            nearest = nearest.parent
        if not nearest.is_dir():
            which = "it" if nearest == folder else _printable(str(nearest))
            reason = f"{which} is a file, not a folder"
            fix = "give another --output, or move the file away"
        elif nearest == folder:  # write a file in it; removed on close
            with tempfile.TemporaryFile(dir=folder) as probe:
                probe.write(b"rawsim")
            return
        elif os.access(nearest, os.W_OK | os.X_OK):
            return
        else:
            reason = f"{_printable(str(nearest))} is not writable (permission denied)"
            fix = "give a folder you can write to"
    except OSError as err:
        reason = (err.strerror or str(err)).lower()
        fix = "give a folder you can write to"
    click.echo(f"rawsim: cannot write to {shown}: {reason}: {fix}", err=True)
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


def elapsed(ctx: click.Context) -> float:
    """Seconds since the command started: since the process started when run as
    ``rawsim`` (``rawsim_cli.main.STARTED``), else since the group's callback
    (a test's ``CliRunner``), so the summary counts the imports and the checks too."""
    started = (ctx.obj or {}).get("started")
    return time.monotonic() - started if started is not None else 0.0


def run_batch(
    ctx: click.Context,
    tasks,
    results_iter,
    pre_failed,
    json_records: bool,
    said: tuple[str, ...] = (),
) -> None:
    """Consume batch results with a progress bar; print failures, summary; exit.
    Warnings in ``said`` were printed once for the run and are not repeated per file.

    SIGINT or SIGTERM stops the job (no new file starts, workers are terminated,
    temporary files removed): the summary counts what was done, exit 130 or 143.
    """
    from rawsim.run.batch import Summary
    from rawsim.run.jobs import Interrupted, signal_received, stop_on_signals

    obj = ctx.obj or {}
    quiet, verbose, debug = obj.get("quiet"), obj.get("verbose", 0), obj.get("debug")
    summary = Summary()
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
                if warning not in said:
                    line = _printable(f"{result.task.source}: {warning}")
                    click.echo(f"warning: {line}", err=True)
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
            try:  # a generator: stops its workers, if not yet done, collecting what they
                results_iter.throw(stop)  # finished and it had not given out yet
            except Interrupted as again:
                interrupted = again
            except StopIteration:
                pass
            for result in interrupted.finished:
                report(result)
        except Exception:
            if signal_received() is None:
                raise
            interrupted = Interrupted(signal_received())  # a library's error for it
            results_iter.close()
    summary.seconds = elapsed(ctx)
    if interrupted is not None:
        left = total - summary.done - summary.skipped - summary.failed
        message = f"rawsim: interrupted by {interrupted}: {summary}, {left} not finished"
        click.echo(message, err=True)
        ctx.exit(interrupted.exit_code)
    click.echo(f"rawsim: {summary}", err=True)
    ctx.exit(summary.exit_code)
