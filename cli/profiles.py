"""``rawsim profiles``: list and show sensor profiles."""

from __future__ import annotations

import json

import click

from rawsim_cli.options import PathType, bad_option, output_options, usage_errors


@click.group("profiles")
def command():
    """List the bundled sensor profiles, or show one.

    \b
    Example:
      rawsim profiles list
      rawsim profiles show sony_a7s2 --iso 3200
    """


@command.command("list")
@output_options
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list.")
@usage_errors
def list_cmd(as_json):
    """List bundled profiles: name, camera, CFA, bit depth, ISO range."""
    from rawsim.profiles import list_profiles, load_profile

    rows = []
    for name in list_profiles():
        p = load_profile(name)
        lo, hi = p.iso_range
        rows.append(
            {
                "name": name,
                "camera": f"{p.make} {p.model}",
                "cfa": p.cfa.name,
                "bits": p.bit_depth,
                "iso_min": lo,
                "iso_max": hi,
            }
        )
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    name_w = max(len("name"), *(len(r["name"]) for r in rows))
    camera_w = max(len("camera"), *(len(r["camera"]) for r in rows))
    cfa_w = max(len("cfa"), *(len(r["cfa"]) for r in rows))
    click.echo(f"{'name':<{name_w}}  {'camera':<{camera_w}}  {'cfa':<{cfa_w}}  {'bits':>4}  iso")
    for r in rows:
        click.echo(
            f"{r['name']:<{name_w}}  {r['camera']:<{camera_w}}  {r['cfa']:<{cfa_w}}  "
            f"{r['bits']:>4}  "
            f"{_iso_range(r['iso_min'], r['iso_max'])}"
        )


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

    With --iso N --json only the noise model's values at that ISO are printed:
    K (DN/e⁻), the read noise's standard deviation (read_std_dn, the default
    model's), the physics model's tukey_scale_dn, tukey_lambda and row_sigma_dn
    (null where the profile has no physics parameters), and each model's values.

    \b
    Example:
      rawsim profiles show nikon_d850 --iso 6400 --json
      rawsim profiles show sony_a7s2 --plot noise.png
    """
    from rawsim.errors import RawsimError
    from rawsim.profiles import load_profile

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
    if as_json:
        click.echo(json.dumps(data if iso is None else data["at_iso"], indent=2))
        return
    click.echo(f"{p.name}: {p.make} {p.model}")
    click.echo(
        f"  CFA {p.cfa.pattern}, {p.bit_depth}-bit, black {p.black_level:g}, "
        f"white {p.white_level:g} DN"
    )
    click.echo(f"  ISO {_iso_range(*p.iso_range)}" if p.iso_range else "  ISO any")
    click.echo(
        "  XYZ→camera: " + "; ".join(" ".join(f"{v:+.4f}" for v in row) for row in p.xyz_to_camera)
    )
    click.echo("  daylight WB gains: " + " ".join(f"{v:.4f}" for v in p.white_balance))
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
    for key, src in p.source.items():
        click.echo(f"  source[{key}]: {src}")
    for why in p.unreliable:
        click.echo(f"  unreliable: {why}")
