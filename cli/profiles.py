"""``rawsim profiles``: list and show sensor profiles."""

from __future__ import annotations

import json

import click
import numpy as np

from rawsim_cli.options import (
    PathType,
    bad_option,
    output_options,
    profile_output_opt,
    usage_errors,
)


@click.group("profiles")
def command():
    """List sensor profiles (bundled, and every camera LibRaw knows), or show one.

    A profile is named by its file name (sony_a7s2), or a camera by its own
    name in any case, with or without the maker ("Sony ILCE-7M3",
    "sony a7 iii"); --profile in unprocess takes the same names.

    \b
    Example:
      rawsim profiles list --search "eos r"
      rawsim profiles show "sony a7 iii" --iso 3200
    """


@command.command("list")
@output_options
@click.option(
    "--search",
    "text",
    metavar="TEXT",
    help="Only cameras whose name, maker, model or an alias contains TEXT (any case).",
)
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list with every field.")
@usage_errors
def list_cmd(text, as_json):
    """List every profile: the bundled ones, then each camera LibRaw knows.

    Each row says whether the camera's noise is measured (a published
    calibration) or estimated from its sensor's physics, which of its
    values are assumed (no public table gives them; 'profiles show' says how
    each was chosen), or "-" where none is, and its spectral sensitivities
    ("curves"): measured (published), estimated from its colour matrix, or
    "-" for none ('profiles matrices' fits colour matrices from them;
    unprocess renders spectral scenes through them).
    --json prints each profile whole (levels, matrix, noise, sources,
    "assumed", the keys assumed, and its spectral sensitivities' source), as
    'profiles show --json'.

    \b
    Example:
      rawsim profiles list --search "a7 iii"
      rawsim profiles list --json > cameras.json
    """
    from rawsim import cameras
    from rawsim.cameras.profiles import list_profiles, load_profile, profile_from_dict

    found = cameras.cameras() if text is None else cameras.search(text)
    aliases = {c.bundled: c.data["aliases"] for c in cameras.cameras() if c.bundled}
    hit_bundled = {c.bundled for c in found if c.bundled}
    profiles = []
    for name in list_profiles():
        p = load_profile(name)
        if (
            text is None
            or name in hit_bundled
            or cameras.matches(text, [f"{name} {p.make} {p.model}"])
        ):
            profiles.append(p)
    for cam in found:
        if not cam.bundled:
            aliases[cam.name] = cam.data["aliases"]
            profiles.append(
                profile_from_dict(cam.profile_data(), f"<camera database: {cam.label}>")
            )
    if as_json:
        rows = [
            {**p.to_dict(), "aliases": aliases.get(p.name, []), "assumed": list(p.assumed)}
            for p in profiles
        ]
        click.echo(json.dumps(rows, indent=1, ensure_ascii=False))
        return
    if not profiles:
        click.echo(
            f"no camera matches {text!r}; try part of the model, e.g. 'a7' or 'eos r'", err=True
        )
        return
    rows = [
        {
            "name": p.name,
            "camera": f"{p.make} {p.model}",
            "cfa": p.cfa.name,
            "bits": p.bit_depth,
            "noise": p.noise_kind or "unstated",
            "iso": _iso_range(*p.iso_range),
            "assumed": ",".join(_SHORT.get(k, k) for k in p.assumed) or "-",
            "curves": c.kind if (c := p.curves) else "-",
        }
        for p in profiles
    ]
    widths = {k: max(len(k), *(len(str(r[k])) for r in rows)) for k in rows[0]}
    click.echo("  ".join(f"{k:<{widths[k]}}" for k in rows[0]).rstrip())
    for r in rows:
        click.echo("  ".join(f"{str(v):<{widths[k]}}" for k, v in r.items()).rstrip())


#: Short names of a profile's keys for the "assumed" column of 'profiles list'.
_SHORT = {
    "cfa_pattern": "cfa",
    "bit_depth": "bits",
    "black_level": "black",
    "white_level": "white",
    "iso_range": "iso",
    "xyz_to_camera": "matrix",
    "white_balance": "wb",
}


def _iso_range(lo: float, hi: float) -> str:
    return f"{lo:g} only" if lo == hi else f"{lo:g}–{hi:g}"


def _curve(spec: dict, unit: str) -> str:
    """A noise curve of a profile, readable: its model and values, not a dict."""
    spec = dict(spec)
    model = spec.pop("model", "?")
    if model == "table" and "iso" in spec:
        name = next(k for k, v in spec.items() if k != "iso" and isinstance(v, list))  # sigma, k
        points = ", ".join(
            f"{i:g} → {v:g}" for i, v in zip(spec.pop("iso"), spec.pop(name), strict=False)
        )
        rest = ", ".join(f"{k} {v:g}" for k, v in spec.items() if v)
        return f"table by ISO ({unit}): {points}" + (f"; {rest}" if rest else "")
    return f"{model}: " + ", ".join(
        f"{k} {v:g}" if isinstance(v, int | float) else f"{k} {v}" for k, v in spec.items()
    )


@command.command("show")
@output_options
@click.argument("profile", metavar="NAME|PATH")
@click.option("--iso", type=float, help="Also print the noise model's values at this ISO.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@click.option(
    "--plot",
    type=PathType("out_file", example="noise.png"),
    help="Write a PNG of noise σ versus signal at several ISOs.",
)
@usage_errors
def show_cmd(profile, iso, as_json, plot):
    """Show a profile: levels, matrix, white balance, noise and sources.

    Each value no public table or file gives is marked "(assumed)" on its
    line; its source line says how it was chosen.

    With --iso N --json only the noise model's values at that ISO are printed:
    K (DN/e⁻), the read noise's standard deviation (read_std_dn, the default
    model's), the physics model's tukey_scale_dn, tukey_lambda and row_sigma_dn
    (null where the profile has no physics parameters), and each model's values.

    \b
    Example:
      rawsim profiles show nikon_d850 --iso 6400 --json
      rawsim profiles show sony_a7s2 --plot noise.png
    """
    from rawsim.cameras import spectra
    from rawsim.cameras.profiles import load_profile
    from rawsim.errors import RawsimError

    try:
        p = load_profile(profile)
    except RawsimError as err:
        raise bad_option("NAME|PATH", err) from None
    if plot:
        from rawsim.plots import plot_noise_profile

        click.echo(f"wrote {plot_noise_profile(p, plot)}", err=True)
    data = p.to_dict()
    if iso is not None:
        models = ["poisson-gaussian", "gaussian"] + (["physics"] if p.noise.has_physics else [])
        at = {m: p.noise.levels(m, p.check_iso(iso)).to_dict() for m in models}
        physics = at.get("physics", {})
        data["at_iso"] = {
            "iso": iso,
            "K": at["poisson-gaussian"]["gain_dn_per_electron"],
            "read_std_dn": at["poisson-gaussian"]["read_std_dn"],  # the default model's
            "tukey_scale_dn": physics.get("tukey_scale_dn"),
            "tukey_lambda": physics.get("tukey_lambda"),
            "row_sigma_dn": physics.get("row_sigma_dn"),
            "models": at,
        }
    data["assumed"] = list(p.assumed)
    if as_json:
        click.echo(json.dumps(data if iso is None else data["at_iso"], indent=2))
        return

    def mark(key: str) -> str:
        return " (assumed)" if key in p.assumed else ""

    click.echo(f"{p.name}: {p.make} {p.model}")
    kind = {"measured": "measured (a calibration)", "estimated": "estimated (sensor physics)"}
    click.echo(f"  noise: {kind.get(p.noise_kind, 'not stated by the profile')}")
    click.echo(
        f"  CFA {p.cfa.pattern}{mark('cfa_pattern')}, {p.bit_depth}-bit{mark('bit_depth')}, "
        f"black {p.black_level:g} DN{mark('black_level')}, "
        f"white {p.white_level:g} DN{mark('white_level')}"
    )
    iso_text = f"ISO {_iso_range(*p.iso_range)}" if p.iso_range else "ISO any"
    click.echo(f"  {iso_text}{mark('iso_range')}")
    click.echo(
        "  XYZ→camera: "
        + "; ".join(" ".join(f"{v:+.4f}" for v in row) for row in p.xyz_to_camera)
        + mark("xyz_to_camera")
    )
    if p.colour_warning:
        click.echo(f"  warning: {p.colour_warning}")
    click.echo(
        "  daylight WB gains: "
        + " ".join(f"{v:.4f}" for v in p.white_balance)
        + mark("white_balance")
    )
    click.echo(f"  noise K(ISO): {_curve(data['noise']['gain'], 'DN/e⁻')}")
    click.echo(f"  read σ(ISO): {_curve(data['noise']['read_sigma'], 'DN')}")
    if iso is not None:
        for model, values in data["at_iso"]["models"].items():
            click.echo(
                f"  at ISO {iso:g} ({model}): "
                + ", ".join(
                    f"{k} {v:.4g}" for k, v in values.items() if isinstance(v, float) and k != "iso"
                )
            )
    if c := p.curves:
        # an estimate's source says "estimated …" itself (it is all a sidecar keeps)
        what = c.source if c.source.startswith(c.kind) else f"{c.kind} ({c.source})"
        click.echo(f"  spectral sensitivities: {what}")
    elif (far := spectra.not_estimated(p)) is not None:
        click.echo(
            "  spectral sensitivities: none published, and none estimated: no curves "
            "like the measured cameras' reproduce its colour matrix (the best renders "
            f"the training patches {far[0]:.1f} ΔE00 off)"
        )
    else:
        click.echo(
            "  spectral sensitivities: none published or estimated for this camera "
            "('rawsim profiles list' marks the cameras that have them)"
        )
    for key, src in p.source.items():
        click.echo(f"  source[{key}]: {src}")
    for why in p.unreliable:
        click.echo(f"  unreliable: {why}")


@command.command("path")
@output_options
@click.argument("profile", metavar="NAME")
@usage_errors
def path_cmd(profile):
    """Print where a bundled profile's JSON file is (to copy one and edit it).

    \b
    Example:
      cp "$(rawsim profiles path nikon_d850)" mycam.json
    """
    from pathlib import Path

    from rawsim.cameras.profiles import load_profile
    from rawsim.errors import RawsimError

    try:
        p = load_profile(profile)
    except RawsimError as err:
        raise bad_option("NAME", err) from None
    if p.path is None or not Path(p.path).is_file():
        raise bad_option(
            "NAME",
            f"{p.make} {p.model} is a camera of the database, which has no file of its "
            "own: give a bundled profile ('rawsim profiles list' lists them first), or "
            "make a file with 'rawsim profiles from-raw' on one of its raws",
        )
    click.echo(p.path)


@command.command("from-raw")
@output_options
@click.argument("raw", metavar="FILE", type=PathType("file", exists=True))
@profile_output_opt
@click.option("--overwrite", is_flag=True, help="Replace an existing output profile.")
@usage_errors
def from_raw_cmd(raw, output, overwrite):
    """Write a profile for the camera that took the raw FILE.

    From the raw, as LibRaw reads it: the CFA layout, the black and white levels
    (and so the bit depth), the XYZ→camera matrix 'rawsim process' renders it
    with (LibRaw's table for the camera, else a DNG's own ColorMatrix, else
    LibRaw's built-in matrix; the source says which) and the daylight white
    balance. The noise is the camera database's where it knows the camera
    (measured or estimated, as 'profiles list' says), else estimated from the
    raw's own flat regions at its ISO. One line says which. Every number's
    source names the file. Raws without any colour matrix or a CFA mosaic
    (linear DNGs) are refused.

    \b
    Example:
      rawsim profiles from-raw IMG_0001.CR2 -o mycam.json
      rawsim unprocess photos/ -o raw/ --profile mycam.json --iso 800
    """
    from pathlib import Path

    out = Path(output)
    if out.exists() and not overwrite:  # the same policy as every command: skip
        click.echo(f"skip: {out} exists (use --overwrite to replace it)", err=True)
        return

    from rawsim.cameras.from_raw import noise_summary, profile_from_raw
    from rawsim.cameras.profiles import profile_from_dict
    from rawsim.errors import ProfileError, UnsupportedInputError, shown
    from rawsim.io.atomic import atomic_output

    try:
        profile = profile_from_raw(raw)
        p = profile_from_dict(profile, f"the profile of {shown(raw)}")  # it must load
    except (UnsupportedInputError, ProfileError) as err:
        raise bad_option("FILE", err) from None
    with atomic_output(out) as tmp:
        tmp.write_text(json.dumps(profile, indent=2, ensure_ascii=False) + "\n")
    if p.make == "unknown" or p.model.casefold().startswith(p.make.casefold()):
        camera = "an unknown camera" if p.model == "unknown" else p.model
    else:
        camera = f"{p.make} {p.model}"
    click.echo(
        f"wrote {shown(out)}: {camera}, CFA {p.cfa.name}, {p.bit_depth}-bit, "
        f"black {p.black_level:g}, white {p.white_level:g} DN, ISO {_iso_range(*p.iso_range)}"
    )
    click.echo(noise_summary(profile))


@command.command("matrices")
@output_options
@click.argument("profile", metavar="NAME|PATH")
@click.option(
    "--illuminant",
    "lights",
    multiple=True,
    metavar="NAME|FILE",
    help="Fit under this light: D50, D55, D65, D75, A, F2, F11, ISO7589, or a file of "
    "two columns (nm, power). Repeat for several. [default: D65 and A]",
)
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
@usage_errors
def matrices_cmd(profile, lights, as_json):
    """Fit a camera's colour matrices from its spectral sensitivities.

    For each light: the XYZ→camera matrix (a DNG ColorMatrix, the light's
    white mapping to a largest camera value of 1) that minimises the CIEDE2000
    ΔE of rawtoaces' 190 training reflectances lit by it, the camera's white
    kept exactly. Each fit prints its mean and worst ΔE00 on those patches; under
    D65 the profile's own matrix (usually Adobe's) is measured on the same
    patches beside it. Only cameras with curves ('profiles list' marks them);
    for estimated curves, which were fitted to that matrix, the fits say what
    such a camera's curves would give.

    \b
    Example:
      rawsim profiles matrices nikon_d850
      rawsim profiles matrices "Canon EOS R6" --illuminant F2 --json
    """
    from rawsim.cameras import spectra
    from rawsim.cameras.profiles import load_profile
    from rawsim.errors import RawsimError
    from rawsim.spectral import fit, tables

    try:
        p = load_profile(profile)
    except RawsimError as err:
        raise bad_option("NAME|PATH", err) from None
    curves = p.curves
    if curves is None:
        have = spectra.labels()
        raise bad_option(
            "NAME|PATH",
            f"no spectral sensitivities are published or estimated for {p.make} "
            f"{p.model}; the {len(have)} cameras with measured ones: {', '.join(have)} "
            "('rawsim profiles list' marks the estimated ones)",
        )
    fits = []
    for light in lights or ("D65", "A"):
        try:
            spd = tables.illuminant(light)
            f = fit.color_matrix(curves.rgb, spd)
        except RawsimError as err:
            raise bad_option("--illuminant", err) from None
        entry = {
            "illuminant": str(light),
            "calibration_illuminant": tables.LIGHT_SOURCES.get(str(light).upper()),
            "xyz_to_camera": np.round(f.xyz_to_camera, 6).tolist(),
            "white_xyz": np.round(f.white_xyz, 6).tolist(),
            "delta_e00": {"mean": round(f.mean_delta_e, 3), "max": round(f.max_delta_e, 3)},
        }
        if str(light).upper() == "D65":
            own = fit.delta_e(curves.rgb, spd, p.xyz_to_camera)
            entry["profile_matrix_delta_e00"] = {
                "mean": round(float(own.mean()), 3),
                "max": round(float(own.max()), 3),
                "source": p.source.get("xyz_to_camera"),
            }
        fits.append(entry)
    patches = tables.source("training_190")
    if as_json:
        out = {
            "camera": curves.label,
            "curves_kind": curves.kind,
            "curves": curves.source,
            "patches": patches,
        }
        click.echo(json.dumps({**out, "fits": fits}, indent=2, ensure_ascii=False))
        return
    click.echo(f"{curves.label}: curves {curves.source}")
    click.echo(f"  fitted on {patches}")
    for e in fits:
        code = e["calibration_illuminant"]
        tag = f" (CalibrationIlluminant {code})" if code else ""
        click.echo(f"  {e['illuminant']}{tag}: XYZ→camera")
        for row in e["xyz_to_camera"]:
            click.echo("    " + " ".join(f"{v:+.4f}" for v in row))
        de = e["delta_e00"]
        click.echo(f"    ΔE00 on the patches: mean {de['mean']:.2f}, worst {de['max']:.2f}")
        if "profile_matrix_delta_e00" in e:
            own = e["profile_matrix_delta_e00"]
            click.echo(
                f"    the profile's own matrix there: mean {own['mean']:.2f}, "
                f"worst {own['max']:.2f} ({own['source']})"
            )
