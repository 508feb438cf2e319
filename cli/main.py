"""The ``rawsim`` command group: global options and lazily loaded subcommands.

Subcommands are imported only when run, so ``rawsim --help`` and
``rawsim --version`` answer without importing torch.
"""

from __future__ import annotations

import time

#: When this process started, nearly: this module is the first the ``rawsim`` script
#: imports. Run summaries count from here (the imports and checks take seconds).
STARTED = time.monotonic()

import importlib  # noqa: E402  (after the clock starts)
import logging  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402

import click  # noqa: E402

from rawsim._version import __version__  # noqa: E402  (the package's version, as pip has it)

#: name → (module, one-line help). The help is here so that listing commands
#: needs no import.
COMMANDS = {
    "unprocess": (
        "rawsim_cli.unprocess",
        "Turn sRGB/EXR images into noisy raw DNGs (Bayer, X-Trans, …).",
    ),
    "process": ("rawsim_cli.process", "Render camera raws (and rawsim's DNGs) through its ISP."),
    "isp": ("rawsim_cli.isp", "Show and check ISP configs."),
    "info": ("rawsim_cli.info", "Print what rawsim reads from raws and will use."),
    "profiles": ("rawsim_cli.profiles", "List and show sensor profiles."),
    "calibrate": ("rawsim_cli.calibrate", "Fit a noise profile from a camera's raws."),
    "events": ("rawsim_cli.events", "Simulate event-camera (DVS) counts from frames."),
    "compile": ("rawsim_cli.compile", "Compile the engine's kernels for this CPU ahead of time."),
}


EXIT_INTERNAL, EXIT_INTERRUPTED = 3, 130
#: 128 + SIGPIPE, as a shell reports a program its pipe reader left.
EXIT_BROKEN_PIPE = 141


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module = importlib.import_module(COMMANDS[name][0])
        return module.command

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except KeyboardInterrupt:
            click.echo("rawsim: interrupted", err=True)
            ctx.exit(EXIT_INTERRUPTED)
        except BrokenPipeError:  # the reader of stdout left (`rawsim info … | head`)
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # nothing more to say there, quietly
            ctx.exit(EXIT_BROKEN_PIPE)
        except Exception as err:  # a bug: one line, or the traceback with --debug
            if ctx.obj and ctx.obj.get("debug"):
                raise
            click.echo(
                f"rawsim: internal error: {type(err).__name__}: {err} "
                "(run with --debug for the traceback)",
                err=True,
            )
            ctx.exit(EXIT_INTERNAL)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="rawsim")
@click.option("-v", "--verbose", count=True, help="More output (repeat for debug logs).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors and the summary.")
@click.option("--debug", is_flag=True, help="Show tracebacks for errors.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool, debug: bool) -> None:
    """rawsim: raw image unprocessing and processing on a differentiable torch ISP.

    Outputs that exist are never replaced without --overwrite: every command
    skips them (and says so).

    \b
    Exit codes:
      0  every file was done (or skipped because its outputs exist)
      1  some files failed; the others were done
      2  usage error: bad option, unknown or malformed profile, no inputs
      3  internal error (a bug: please report it, with --debug output)
    130  interrupted
    141  the reader of the standard output went away (e.g. '| head')

    \b
    Example:
      rawsim unprocess photos/ -o raw/ --profile sony_a7s2 --iso 1600
    """
    from rawsim.io.clibs import separate_stderr
    from rawsim_cli.options import set_log_level

    separate_stderr()  # before any reader thread collects the libraries' lines
    started = (ctx.obj or {}).get("started", time.monotonic())
    ctx.obj = {"verbose": verbose, "quiet": quiet, "debug": debug, "started": started}
    logging.basicConfig(level=logging.WARNING, format="rawsim: %(message)s", stream=sys.stderr)
    set_log_level(ctx.obj)


def main() -> None:
    import rawsim.engine

    rawsim.engine.lean_start = True  # no user code compiles here: skip numba's BLAS probe
    try:
        cli(obj={"started": STARTED})
    except SystemExit as done:
        _exit(done.code)
    _exit(0)


def _exit(code) -> None:
    """Exit with ``code`` as :class:`SystemExit` would, without the interpreter's teardown.

    Every output is written and closed by then (atomic writes); what is left is
    garbage-collecting numba's type registries module by module, about 0.15 s of
    a one-file run. Exit handlers still run and the standard streams are flushed.
    """
    import atexit

    if code is not None and not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(code or 0)


if __name__ == "__main__":
    main()
