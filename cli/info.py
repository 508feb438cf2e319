"""``rawsim info``: what rawsim reads from raws and what it will use on them."""

from __future__ import annotations

import json

import click

from rawsim_cli.options import output_options, usage_errors

HIGHLIGHTS = ("clip", "blend")


@click.command("info")
@output_options
@click.argument("inputs", nargs=-1, required=True, metavar="RAW...")
@click.option("--wb", help="White balance mode to resolve, as for 'rawsim process'.")
@click.option("--white-level", type=click.Choice(["file", "auto"]), help="As for process.")
@click.option("--highlights", type=click.Choice(HIGHLIGHTS), help="As for process.")
@click.option(
    "-c", "--config", "config_path", type=click.Path(dir_okay=False), help="ISP config (TOML)."
)
@click.option("--json", "as_json", is_flag=True, help="One JSON record per file on stdout.")
@click.pass_context
@usage_errors
def command(ctx, inputs, wb, white_level, highlights, config_path, as_json):
    """Print what rawsim reads from each raw and what 'rawsim process' would use:
    camera, whether it can render it, CFA, black and white levels, the camera's
    and daylight multipliers, the white balance it applies and why, the colour
    matrix and its source, orientation, ISO, the DNG BaselineExposure and
    whether process applies it, and the photo metadata renders carry (camera,
    lens, exposure, aperture, focal length, time, GPS, artist, …). For a raw
    it cannot render (a four-colour CFA, a full image of four samples, …) it
    prints what LibRaw read and 'renderable: no — the reason; the way out'.
    Folders are searched as 'process' searches them. Exit status 1 when a file
    cannot be read at all.

    \b
    Example:
      rawsim info IMG_0001.CR2 --wb camera
    """
    from rawsim.errors import RawsimError, shown
    from rawsim.io.images import RAW_EXTENSIONS
    from rawsim.io.raw import UnrenderableRawError, read_raw
    from rawsim.isp.config import IspConfig
    from rawsim.pipelines.process import describe
    from rawsim.run.batch import discover

    config = IspConfig.load(config_path) if config_path else IspConfig.default()
    config = config.override(wb=wb, white_level=white_level, highlights=highlights)
    found, missing, _ = discover(inputs, RAW_EXTENSIONS)
    failed = len(missing)
    for result in missing:
        click.echo(f"error: {result.message}", err=True)
    for path, _ in found:
        try:
            try:
                facts = describe(read_raw(path), config)
            except UnrenderableRawError as err:  # what could be read, and why not
                facts = describe(err.facts, config)
        except RawsimError as err:
            click.echo(f"error: {err}", err=True)
            failed += 1
            continue
        if as_json:
            click.echo(json.dumps(facts))
            continue
        click.echo(shown(path))
        for key, value in facts.items():
            if key == "renderable":
                value = "yes" if value else f"no — {facts['reason']}"
            if key == "reason":
                continue
            if key == "metadata":
                for tag, text in value.items():
                    click.echo(f"  {tag:<24} {text}")
            elif key != "file" and value not in (None, []):
                click.echo(f"  {key:<24} {value}")
    ctx.exit(1 if failed else 0)
