"""``rawsim info``: what rawsim reads from raws and what it will use on them."""

from __future__ import annotations

import json

import click

from rawsim_cli.options import output_options, usage_errors
from rawsim_cli.process import HIGHLIGHTS


@click.command("info")
@output_options
@click.argument("inputs", nargs=-1, required=True, metavar="RAW...")
@click.option("--wb", help="White balance mode to resolve, as for 'rawsim process'.")
@click.option("--white-level", type=click.Choice(["file", "auto"]), help="As for process.")
@click.option("--saturation", type=click.Choice(["data", "white"]), help="As for process.")
@click.option("--highlights", type=click.Choice(HIGHLIGHTS), help="As for process.")
@click.option(
    "-c", "--config", "config_path", type=click.Path(dir_okay=False), help="ISP config (TOML)."
)
@click.option("--json", "as_json", is_flag=True, help="One JSON record per file on stdout.")
@click.pass_context
@usage_errors
def command(ctx, inputs, wb, white_level, saturation, highlights, config_path, as_json):
    """Print what rawsim reads from each raw and what 'rawsim process' would use:
    camera, whether it can render it, CFA, black and white levels, where each
    colour saturates (DN) and how that was found in the data, the camera's
    and daylight multipliers, the white balance it applies and why, the colour
    matrix and its source, orientation, ISO, the DNG BaselineExposure and
    whether process applies it, the noise model '--denoise profiled' takes (and
    where from: a bundled profile, the DNG NoiseProfile tag, or an estimate from
    the raw), and the photo metadata renders carry (camera,
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
    config = config.override(
        wb=wb, white_level=white_level, saturation=saturation, highlights=highlights
    )
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
        if not facts.get("iso"):  # LibRaw's 0: not recorded, not a value
            facts["iso"] = None
        if as_json:
            click.echo(json.dumps(facts))
            continue
        click.echo(shown(path))
        for line in _lines(facts):
            click.echo(line)
    ctx.exit(1 if failed else 0)


def _lines(facts: dict) -> list[str]:
    """The text form of ``describe``'s record: one ``key value`` line a fact (none for
    an unknown one), then the photo metadata under its own heading, less the Make and
    Model already given as ``make`` and ``model``."""
    out = []
    metadata = facts.get("metadata") or {}
    for key, value in facts.items():
        if key in ("file", "reason", "metadata") or value in (None, []):
            continue
        if key == "renderable":
            value = "yes" if value else f"no — {facts['reason']}"
        elif key == "saturation":
            value = "; ".join(
                f"{colour} {level:g} ({found})"
                for colour, level, found in zip("RGB", value["levels"], value["found"], strict=True)
            )
        elif key == "noise_model":
            value = f"{value['source']}: {value['detail']}"
        elif key == "unprocess_profile":
            value = f"{value['name']} ({value['camera']}; noise {value['noise']})"
        elif key == "iso":
            value = f"{value:g}"
            if "ISOSpeedRatings" not in metadata:  # e.g. a Kodak DC50's, from LibRaw's table
                value += " (LibRaw's figure for this camera; the file records no ISO)"
        out.append(f"  {key:<24} {value}")
    same = {"Make": facts.get("make"), "Model": facts.get("model")}
    shown = {tag: text for tag, text in metadata.items() if same.get(tag) != text}
    if shown:
        out.append("  metadata (carried into renders)")
        out += [f"    {tag:<22} {text}" for tag, text in shown.items()]
    return out
