"""``rawsim isp``: show and check ISP configs."""

from __future__ import annotations

import click

from rawsim_cli.options import PathType, output_options, usage_errors


@click.group("isp")
def command():
    """Show the default ISP config, or check one.

    \b
    Example:
      rawsim isp show > isp.toml && rawsim isp check isp.toml
    """


@command.command("show")
@output_options
@usage_errors
def show_cmd():
    """Print the default ISP config as TOML (edit it and pass it to 'rawsim process -c')."""
    from rawsim.isp.config import IspConfig

    click.echo(IspConfig.default().to_toml(), nl=False)


@command.command("check")
@output_options
@click.argument("config", type=PathType("file", exists=True))
@usage_errors
def check_cmd(config):
    """Validate a config file; print the effective stage order."""
    from rawsim.isp.config import IspConfig

    click.echo(" → ".join(s.name for s in IspConfig.load(config).enabled))
