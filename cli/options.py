"""Options shared by the batch commands, and the error handling around them."""

from __future__ import annotations

import functools
import logging
import os
import traceback

import click

# Literal copy of rawsim.isp.tone.TONE_CURVES (checked by a test), so --help needs no torch.
TONES = ("none", "smoothstep", "reinhard", "aces", "hable")


class PathType(click.ParamType):
    """A path option or argument whose refusals say what was given, what is wrong
    and what to do: ``Invalid value for '-o' / '--output': out.png is a file, not a
    folder: …``. ``kind`` is one of

    * ``"input"``: a file or folder that exists;
    * ``"file"``: a file to read (``exists``: it must be there), not a folder;
    * ``"out_folder"``: a folder to write into, which need not exist: not a file;
    * ``"out_file"``: a file to write, which need not exist: not a folder.

    Values stay ``str``; nothing is created here.
    """

    name = "path"

    def __init__(self, kind: str, exists: bool = False, example: str = "out.json") -> None:
        if kind not in ("input", "file", "out_folder", "out_file"):
            raise ValueError(f"unknown path kind {kind!r}")
        self.kind, self.exists, self.example = kind, exists or kind == "input", example

    def convert(self, value, param, ctx):
        from rawsim.errors import shown

        text = os.fspath(value)
        if self.kind == "input" and not os.path.lexists(text):
            what = "folder" if text.endswith(os.sep) or not os.path.splitext(text)[1] else "file"
            self.fail(f"{shown(text)}: no such {what} (check the path)", param, ctx)
        if self.kind == "file":
            if os.path.isdir(text):
                self.fail(f"{shown(text)} is a folder: give the file in it", param, ctx)
            if self.exists and not os.path.exists(text):
                self.fail(f"{shown(text)}: no such file (check the path)", param, ctx)
        if self.kind == "out_folder" and os.path.exists(text) and not os.path.isdir(text):
            self.fail(
                f"{shown(text)} is a file, not a folder: give a folder (made when the "
                "first output is written), or move the file away",
                param,
                ctx,
            )
        if self.kind == "out_file" and os.path.isdir(text):
            example = os.path.join(text, self.example)
            self.fail(
                f"{shown(text)} is a folder: give a file name, e.g. {shown(example)}", param, ctx
            )
        return text


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
    help="Sensor profile: a bundled name, a camera's own name ('Sony ILCE-7M3', "
    "'sony a7 iii'; see 'rawsim profiles list --search TEXT') or a JSON file.",
)
#: ``-o FILE``: the profile JSON a command writes (calibrate, profiles from-raw).
profile_output_opt = click.option(
    "-o",
    "--output",
    required=True,
    type=PathType("out_file", example="mycam.json"),
    help="The profile JSON to write.",
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
        type=PathType("out_folder"),
        help="Output folder or URL (s3://bucket/prefix, …), made when the first output "
        "is written; the input folder tree is mirrored under it.",
    )(func)
    # Not PathType("input"): an input may be a URL, and a missing one is reported with
    # the others (rawsim.run.batch.discover), once the options are known to be good.
    return click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=str))(func)


def batch_options(func):
    """The options of every file command: --jobs, --executor, --address, --device,
    --overwrite, --shard, --json."""
    options = (jobs_opt, executor_opt, address_opt, device_opt, overwrite_opt, shard_opt, json_opt)
    for option in reversed(options):
        func = option(func)
    return func


def bad_option(hint: str, err: Exception) -> click.BadParameter:
    """``err`` (a :class:`~rawsim.errors.RawsimError`) as a usage error of the option
    ``hint`` (``"--iso"``): click prints ``Invalid value for '--iso': <err>``."""
    return click.BadParameter(str(err), param_hint=f"'{hint}'")


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
