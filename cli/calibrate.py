"""``rawsim calibrate``: estimate a camera's noise model from its raw files."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import click

from rawsim_cli.options import PathType, output_options, profile_output_opt, usage_errors


@click.command("calibrate")
@output_options
@click.argument("raws", nargs=-1, required=True, type=PathType("input"))
@profile_output_opt
@click.option(
    "--dark",
    "darks",
    multiple=True,
    type=PathType("input"),
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
@click.option(
    "--plot", type=PathType("out_file", example="fit.png"), help="Write a PNG of the fits."
)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list, one object per ISO.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output profile.")
@click.option(
    "--force",
    is_flag=True,
    help="Write the profile even when a fit cannot be trusted; it is marked unreliable.",
)
@click.option(
    "--dark-shading",
    is_flag=True,
    help="Also measure the dark frames' fixed pattern (k·ISO + b per pixel, written beside "
    "the profile as <name>.dark.npz) and the black-level error per ISO.",
)
@click.option(
    "--gain-switch",
    "gain_switch",
    multiple=True,
    type=float,
    help="An ISO where the sensor switches conversion gain: dark shading is fitted per "
    "range. Repeatable.",
)
@click.pass_context
@usage_errors
def command(
    ctx,
    raws,
    output,
    darks,
    method,
    iso,
    name,
    plot,
    as_json,
    overwrite,
    force,
    dark_shading,
    gain_switch,
):
    """Fit K (DN/e⁻), read σ, row σ and λ per ISO from RAWS and write a profile.

    RAWS are flat-field frames of one camera (or ordinary photos with --method
    patches); folders are searched for raws. Frames are grouped by the ISO in
    their metadata and read one at a time. Per ISO and CFA channel (R, Gr, Gb, B
    for Bayer; R, G, B for X-Trans and other layouts, each pooling its sites of
    the period), block variance versus mean is fitted robustly: the slope is K,
    the offset the read noise. Dark frames (--dark) give the read σ, the row σ (full-width row
    means), the per-channel bias and the Tukey-lambda shape λ; without them λ is
    not fitted and the profile has no physics model. Every figure comes with a
    standard error (±, a bootstrap over image regions); K's (and, without dark
    frames, read σ's) also holds the systematic error, the spread between two
    variance estimators that the method's bias reaches unequally (texture, for
    patches).

    --dark-shading also fits each pixel's dark level as k·ISO + b (per gain
    range; --gain-switch ISO starts a new one) and the spread of the frames'
    black levels per ISO, and takes that pattern out of every frame before the
    noise fits. It needs at least 8 dark frames per ISO, more when the pattern is
    weak against the noise (the refusal says how many), and two ISOs per range.

    A fit that cannot be trusted (frames that are not flat fields, too few
    signal levels, no shot noise, a negative read variance, a poor line fit,
    dark frames that are not dark, mixed cameras or ISOs) is refused: exit 1,
    the reasons, nothing written. --force writes it anyway and marks the
    profile unreliable.

    \b
    Example:
      rawsim calibrate flats/ --dark darks/ -o mycam.json --plot fit.png
      rawsim calibrate photos/*.CR2 --method patches -o mycam.json --json
      rawsim calibrate flats/ --dark darks/ --dark-shading --gain-switch 800 -o mycam.json
    """
    from rawsim.errors import shown
    from rawsim.io.images import RAW_EXTENSIONS
    from rawsim.run.batch import discover

    # The usage errors first, before the fitting code (torch, SciPy) is imported.
    if dark_shading and not darks:
        raise click.UsageError(
            "--dark-shading needs dark frames: add --dark FOLDER (8 or more frames per "
            "ISO), or drop --dark-shading",
            ctx,
        )
    for given, what in ((raws, "RAWS"), (darks, "--dark")):
        if given and not discover(given, RAW_EXTENSIONS).found:
            raise click.UsageError(
                f"{what}: no raw files in {', '.join(shown(g) for g in given)}: give raw "
                "files (DNG, CR2, NEF, ARW, RAF, …) or folders of them",
                ctx,
            )

    from rawsim.cameras.calibrate import (
        CalibrationRefused,
        build_profile,
        calibrate_iso,
        dark_stats,
        frame_stats,
        same_camera,
    )
    from rawsim.cameras.dark_calibration import (
        PatternRemoval,
        accumulate,
        add_to_profile,
        count_problems,
    )
    from rawsim.cameras.profiles import profile_from_dict
    from rawsim.errors import ParameterError
    from rawsim.io.atomic import atomic_output
    from rawsim.io.raw import read_raw

    out = Path(output)
    if out.exists() and not overwrite:  # the same policy as every command: skip
        click.echo(f"skip: {out} exists (use --overwrite to replace it)", err=True)
        return

    def load(paths, reduce) -> list:
        """Each file's statistics; files are read one at a time and not kept."""
        found = discover(paths, RAW_EXTENSIONS).found  # click already checked they exist
        if not found and paths:
            raise ParameterError(f"no raw files in {', '.join(paths)}")
        stats, isos = [], set()
        for f, _ in found:
            raw = read_raw(f)
            if iso is None and not raw.iso > 0:
                raise ParameterError(f"{f}: no ISO in the metadata; give --iso")
            isos.add(raw.iso)
            stats.append(reduce(raw, iso))
        if iso is not None and len(isos - {0.0}) > 1:
            listed = ", ".join(f"{i:g}" for i in sorted(isos - {0.0}))
            why = f"--iso {iso:g} would fit files shot at ISO {listed} as one"
            raise CalibrationRefused([why + "; calibrate each ISO on its own (leave out --iso)"])
        return stats

    def dark_pass():
        """The dark frames, one at a time, with the ISO they are fitted at."""
        for f, _ in discover(darks, RAW_EXTENSIONS).found:
            raw = read_raw(f)
            yield raw, float(iso or raw.iso)

    try:
        flat, dark = (lambda raw, value: raw), (lambda raw, value: raw)
        if dark_shading:  # a first pass over the dark frames measures the pattern
            if not darks:
                raise ParameterError("--dark-shading needs dark frames (--dark)")
            acc = accumulate(dark_pass())
            early = count_problems(acc.n, tuple(gain_switch))
            if early and not force:  # before the flats are read and fitted
                raise CalibrationRefused(early)
            removal = PatternRemoval(acc)
            flat = lambda raw, value: removal.flat(raw, float(value or raw.iso))  # noqa: E731
            dark = lambda raw, value: removal.dark(raw, float(value or raw.iso))  # noqa: E731
        flats = load(raws, lambda raw, value: frame_stats(flat(raw, value), method, value))
        dark_frames = load(darks, lambda raw, value: dark_stats(dark(raw, value), value))
        same_camera(flats + dark_frames)
        by_iso: dict[float, list] = defaultdict(list)
        dark_by_iso: dict[float, list] = defaultdict(list)
        for f in flats:
            by_iso[f.iso].append(f)
        for d in dark_frames:
            dark_by_iso[d.iso].append(d)
        orphans = sorted(set(dark_by_iso) - set(by_iso))
        if orphans:
            raise ParameterError(f"dark frames at ISO {orphans[0]:g} have no flat frames")
        fits = [
            calibrate_iso(value, by_iso[value], dark_by_iso.get(value, []), method)
            for value in sorted(by_iso)
        ]
        profile = build_profile(fits, flats[0], name or out.stem, method, forced=force)
        if dark_shading:
            add_to_profile(profile, acc, out, tuple(gain_switch), forced=force)
    except CalibrationRefused as err:
        for problem in err.problems:
            click.echo(f"rawsim: cannot calibrate: {problem}", err=True)
        click.echo(
            f"rawsim: nothing written to {out} (--force writes it anyway, marked unreliable)",
            err=True,
        )
        raise SystemExit(1) from None
    written = profile_from_dict(profile, str(out))  # the written profile must load
    for problem in profile.get("unreliable", [])[1:]:
        click.echo(f"warning: unreliable: {problem}", err=True)
    if written.colour_warning:
        click.echo(f"warning: {written.colour_warning}", err=True)
    with atomic_output(out) as tmp:
        tmp.write_text(json.dumps(profile, indent=2) + "\n")
    if plot:
        from rawsim.plots import plot_calibration

        camera = flats[0].camera.describe()
        plot_calibration(fits, plot, f"{camera} ({method})")
    if as_json:
        click.echo(json.dumps([f.to_dict() for f in fits], indent=2))
    else:
        click.echo(summary(fits))
    click.echo(f"wrote {out}" + (f" and {plot}" if plot else ""), err=True)


def summary(fits) -> str:
    """The fits as a table, each figure ± its standard error."""

    def pm(value, key, fit, digits):
        if value is None:
            return "–"
        err = fit.errors.get(key)
        text = f"{value:.{digits}f}"
        return text + (f" ± {err:.{digits}f}" if err is not None and err == err else "")

    rows = [("ISO", "K DN/e⁻", "read σ DN", "row σ DN", "λ", "frames")]
    for f in fits:
        rows.append(
            (
                f"{f.iso:g}",
                pm(f.K, "K", f, 4),
                pm(f.read_sigma, "read_sigma", f, 3),
                pm(f.row_sigma, "row_sigma", f, 3),
                pm(f.lam, "lambda", f, 2),
                f"{f.frames} + {f.darks} dark" + ("" if not f.problems else "  (unreliable)"),
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    table = [
        "  ".join(
            c.rjust(w) if i < 5 else c for i, (c, w) in enumerate(zip(r, widths, strict=True))
        )
        for r in rows
    ]
    for f in fits:  # where the ± is mostly the bias the method is known to have, say so
        stat, sys = f.errors.get("K_statistical"), f.errors.get("K_systematic")
        if stat is not None and sys is not None and sys > stat:
            table.append(
                f"ISO {f.iso:g}: K's ± is mostly systematic ({sys:.4f} DN/e⁻: estimators, "
                f"signal levels or channels disagree; statistical {stat:.4f})"
            )
    return "\n".join(table)
