"""Options shared by the batch commands, and the error handling around them."""

from __future__ import annotations

import functools
import logging
import traceback

import click

# Literal copy of rawsim.isp.tone.TONE_CURVES (checked by a test), so --help needs no torch.
TONES = ("none", "smoothstep", "reinhard", "aces", "hable")

overwrite_opt = click.option(
    "--overwrite",
    is_flag=True,
    help="Replace existing outputs (default: skip files whose outputs all exist).",
)
jobs_opt = click.option(
    "-j",
    "--jobs",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Worker processes. Results are identical for any number.",
)
device_opt = click.option(
    "--device",
    type=click.Choice(["auto", "cpu", "cuda"]),
    default="cpu",
    show_default=True,
    help="Where to compute: cpu (the compiled engine where it can), cuda or auto. "
    "Results agree across devices; unprocess's noise is the same bits on each.",
)
seed_opt = click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Run seed. Each file's randomness derives from it and the file's path "
    "relative to its input folder.",
)
profile_opt = click.option(
    "-p",
    "--profile",
    "profile",
    required=True,
    metavar="NAME|PATH",
    help="Sensor profile: a bundled name (see 'rawsim profiles list') or a JSON file.",
)
shard_opt = click.option(
    "--shard",
    metavar="K/N|auto",
    default=None,
    help="Process only the K-th of N shares of the inputs, K from 1. auto: this task's "
    "share of a Slurm array (SLURM_ARRAY_TASK_ID, _MIN, _STEP, _COUNT).",
)
executor_opt = click.option(
    "--executor",
    type=click.Choice(["local", "ray"]),
    default="local",
    show_default=True,
    help="local: --jobs worker processes here; ray: tasks on a Ray cluster (pip install "
    "'rawsim[ray]'), with the same outputs, messages and exit status.",
)
address_opt = click.option(
    "--address",
    metavar="ADDR",
    default=None,
    help="With --executor ray: the cluster, as ray.init takes it (auto: the one this "
    "machine belongs to; HOST:PORT; ray://HOST:PORT). Default: a new local cluster.",
)
json_opt = click.option(
    "--json", "json_records", is_flag=True, help="Print one JSON record per file on stdout."
)


def files_in_out(func):
    """INPUTS (files or folders) and -o/--output, the folder that mirrors them."""
    func = click.option(
        "-o",
        "--output",
        "out_dir",
        required=True,
        type=click.Path(file_okay=False),
        help="Output folder or URL (s3://bucket/prefix, …); the input folder tree is "
        "mirrored under it.",
    )(func)
    return click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=str))(func)


def batch_options(func):
    """The options of every file command: --jobs, --executor, --address, --device,
    --overwrite, --shard, --json."""
    options = (jobs_opt, executor_opt, address_opt, device_opt, overwrite_opt, shard_opt, json_opt)
    for option in reversed(options):
        func = option(func)
    return func


def usage_errors(func):
    """Turn rawsim's errors raised while setting up a command into usage errors (exit 2)."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        from rawsim.errors import RawsimError

        try:
            return func(*args, **kwargs)
        except RawsimError as err:
            ctx = click.get_current_context()
            if ctx.obj and ctx.obj.get("debug"):
                click.echo(traceback.format_exc(), err=True)
            raise click.UsageError(str(err), ctx) from None

    return wrapper


def _output_flag(ctx: click.Context, param: click.Parameter, value) -> None:
    """-v/-q/--debug given after the subcommand: the same effect as before it."""
    if not value:
        return
    obj = ctx.ensure_object(dict)
    if param.name == "verbose":
        obj["verbose"] = obj.get("verbose", 0) + value
    else:
        obj[param.name] = True
    set_log_level(obj)


def set_log_level(obj: dict) -> None:
    """The log level for the -v/-q flags in ``obj``."""
    if obj.get("quiet"):
        level = logging.ERROR
    elif obj.get("verbose"):
        level = logging.INFO if obj["verbose"] == 1 else logging.DEBUG
    else:
        level = logging.WARNING
    logging.getLogger().setLevel(level)


def output_options(func):
    """-v, -q and --debug on a subcommand too (``rawsim process … -q``)."""
    options = (
        click.option(
            "-v",
            "--verbose",
            count=True,
            expose_value=False,
            callback=_output_flag,
            help="More output (repeat for debug logs).",
        ),
        click.option(
            "-q",
            "--quiet",
            is_flag=True,
            expose_value=False,
            callback=_output_flag,
            help="Only errors and the summary.",
        ),
        click.option(
            "--debug",
            is_flag=True,
            expose_value=False,
            callback=_output_flag,
            help="Show tracebacks for errors.",
        ),
    )
    for option in reversed(options):
        func = option(func)
    return func
