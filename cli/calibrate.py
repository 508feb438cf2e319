"""``rawsim calibrate``: estimate a camera's noise model from its raw files."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import click

from rawsim_cli.options import output_options, usage_errors


@click.command("calibrate")
@output_options
@click.argument("raws", nargs=-1, required=True, type=click.Path(exists=True))
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="The profile JSON to write.",
)
@click.option(
    "--dark",
    "darks",
    multiple=True,
    type=click.Path(exists=True),
    help="A dark frame (lens cap on), repeatable; a folder adds every raw in it.",
)
@click.option(
    "--method",
    type=click.Choice(["flat", "patches"]),
    default="flat",
    show_default=True,
    help="flat: flat-field frames (photon transfer). patches: ordinary photos, from "
    "their smoothest patches (less accurate).",
)
@click.option("--iso", type=float, help="Use this ISO for every file instead of its metadata.")
@click.option("--name", help="Profile name (default: from the output file name).")
@click.option("--plot", type=click.Path(dir_okay=False), help="Write a PNG of the fits.")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list, one object per ISO.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output profile.")
@usage_errors
def command(raws, output, darks, method, iso, name, plot, as_json, overwrite):
    """Fit K (DN/e⁻), read σ, row σ and λ per ISO from RAWS and write a profile.

    RAWS are flat-field frames of one camera (or ordinary photos with --method
    patches); folders are searched for raws. Frames are grouped by the ISO in
    their metadata. Per ISO and CFA channel, tile variance versus mean is fitted
    robustly: the slope is K, the offset the read noise. Dark frames (--dark)
    give the read σ, the row σ (full-width row means), the per-channel bias and
    the Tukey-lambda shape λ; without them λ is not fitted and the profile has
    no physics model. The profile also takes the files' CFA pattern, black and
    white levels and colour matrix, and a "calibration" list with every fit.

    \b
    Example:
      rawsim calibrate flats/ --dark darks/ -o mycam.json --plot fit.png
      rawsim calibrate photos/*.CR2 --method patches -o mycam.json --json
    """
    from rawsim.batch import discover
    from rawsim.calibrate import build_profile, calibrate_iso, same_camera
    from rawsim.errors import ParameterError
    from rawsim.io.atomic import atomic_output
    from rawsim.io.images import RAW_EXTENSIONS
    from rawsim.io.raw import read_raw
    from rawsim.profiles import profile_from_dict

    out = Path(output)
    if out.exists() and not overwrite:  # the same policy as every command: skip
        click.echo(f"skip: {out} exists (use --overwrite to replace it)", err=True)
        return

    def load(paths) -> list:
        found = discover(paths, RAW_EXTENSIONS).found  # click already checked they exist
        files = [path for path, _ in found]
        if not files and paths:
            raise ParameterError(f"no raw files in {', '.join(paths)}")
        frames = []
        for f in files:
            raw = read_raw(f)
            if iso is None and not raw.iso > 0:
                raise ParameterError(f"{f}: no ISO in the metadata; give --iso")
            frames.append(raw)
        return frames

    flats, dark_frames = load(raws), load(darks)
    same_camera(flats + dark_frames)
    by_iso: dict[float, list] = defaultdict(list)
    dark_by_iso: dict[float, list] = defaultdict(list)
    for raw in flats:
        by_iso[iso or raw.iso].append(raw)
    for raw in dark_frames:
        dark_by_iso[iso or raw.iso].append(raw)
    orphans = sorted(set(dark_by_iso) - set(by_iso))
    if orphans:
        raise ParameterError(f"dark frames at ISO {orphans[0]:g} have no flat frames")
    fits = [
        calibrate_iso(value, by_iso[value], dark_by_iso.get(value, []), method)
        for value in sorted(by_iso)
    ]
    profile = build_profile(fits, flats[0], name or out.stem, method)
    profile_from_dict(profile, str(out))  # the written profile must load
    for warning in profile["warnings"]:
        click.echo(f"warning: {warning}", err=True)
    with atomic_output(out) as tmp:
        tmp.write_text(json.dumps(profile, indent=2) + "\n")
    if plot:
        from rawsim.plots import plot_calibration

        plot_calibration(fits, plot, f"{flats[0].make} {flats[0].model} ({method})")
    if as_json:
        click.echo(json.dumps([f.to_dict() for f in fits], indent=2))
    else:
        click.echo(f"{'ISO':>7} {'K DN/e⁻':>10} {'read σ':>8} {'row σ':>8} {'λ':>6}  frames")
        for f in fits:
            row = "–" if f.row_sigma is None else f"{f.row_sigma:.3f}"
            lam = "–" if f.lam is None else f"{f.lam:+.2f}"
            click.echo(
                f"{f.iso:>7g} {f.K:>10.4f} {f.read_sigma:>8.3f} {row:>8} {lam:>6}  "
                f"{f.frames} + {f.darks} dark"
            )
    click.echo(f"wrote {out}" + (f" and {plot}" if plot else ""), err=True)
