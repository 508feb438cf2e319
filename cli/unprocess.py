"""``rawsim unprocess``: images → noisy CFA DNGs (Bayer, X-Trans, any periodic layout).

Every usage error is found before the pipeline (torch, numba) is imported, so it is
answered at once.
"""

from __future__ import annotations

import click

from rawsim_cli.options import (
    TONES,
    bad_option,
    batch_options,
    files_in_out,
    output_options,
    profile_opt,
    seed_opt,
    usage_errors,
)
from rawsim_cli.report import check_inputs, run_files

# Literal copies of the core lists (checked by a test) keep `--help` free of torch.
NOISES = ("poisson-gaussian", "physics", "gaussian", "none")


@click.command("unprocess")
@output_options
@files_in_out
@profile_opt
@click.option(
    "--sensor",
    "sensor_kind",
    type=click.Choice(["rgb", "mono"]),
    default="rgb",
    show_default=True,
    help="rgb: the profile's CFA (or --cfa); mono: no colour filter (grey = mean of linear "
    "R, G, B, or the profile's green spectral response), the profile's levels and noise, "
    "written as a one-sample LinearRaw DNG.",
)
@click.option(
    "--cfa",
    metavar="RGGB|BGGR|GRBG|GBRG|XTRANS|ROWS",
    help="Mosaic in this CFA instead of the profile's, keeping its levels, colour and "
    "noise: a Bayer name, XTRANS (Fujifilm's 6×6, written with CFARepeatPatternDim 6×6) "
    "or rows of R/G/B joined by '/' (e.g. GRG/BGB/GRG).",
)
@click.option("--iso", type=float, help="ISO of every capture (within the profile's range).")
@click.option(
    "--iso-range",
    nargs=2,
    type=float,
    metavar="MIN MAX",
    help="Draw each file's ISO log-uniformly from [MIN, MAX] instead.",
)
@seed_opt
@click.option(
    "--randomize",
    is_flag=True,
    help="Sample colour matrix, white balance and brightness per file (Brooks et al.).",
)
@click.option("--clean", is_flag=True, help="Also write <stem>.clean.dng, the noise-free mosaic.")
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["dng", "npz", "both"]),
    default="dng",
    show_default=True,
    help="npz: packed R, Gr, Gb, B planes (Bayer) or the whole mosaic and its CFA "
    "(other layouts) + metadata, for ML loaders.",
)
@click.option(
    "--noise",
    type=click.Choice(NOISES),
    default="poisson-gaussian",
    show_default=True,
    help="Noise model: K(ISO) Poisson + Gaussian read noise; physics (ELD: Poisson + "
    "Tukey-lambda read + row noise + channel bias); the seed's Gaussian; or none.",
)
@click.option(
    "--tone",
    type=click.Choice(TONES),
    default="none",
    show_default=True,
    help="Inverse tone curve for 8/16-bit inputs, applied before the transfer decode.",
)
@click.option(
    "--transfer",
    default="srgb",
    show_default=True,
    metavar="srgb|gamma:G|linear",
    help="Transfer function of 8/16-bit inputs (exact IEC 61966-2-1 sRGB by default).",
)
@click.option(
    "--exposure",
    type=float,
    default=0.0,
    show_default=True,
    metavar="EV",
    help="Scale linear light by 2^EV. For EXR/float inputs 1.0 is the white level at 0 EV.",
)
@click.option(
    "--lens",
    metavar="NAME",
    help="Add this lens's distortion, lateral chromatic aberration and vignetting "
    "(lensfun's data, on the profile's camera), as lensfun lists it (e.g. 'Canon EF-S "
    "18-55mm f/3.5-5.6 IS STM'); 'rawsim process --lens-correction auto' takes it out.",
)
@click.option(
    "--focal-length",
    type=click.FloatRange(min=0, min_open=True),
    metavar="MM",
    help="With --lens: its focal length in mm (needed for a zoom).",
)
@click.option(
    "--aperture",
    type=click.FloatRange(min=0, min_open=True),
    metavar="F",
    help="With --lens: its f-number (without one, no vignetting is added).",
)
@click.option(
    "--vignetting",
    type=click.FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Strength of the radial lens shading added (1 = 1 + 0.3r² + 0.15r⁴ + 0.05r⁶).",
)
@click.option(
    "--wb-inverse",
    type=click.Choice(["exact", "safe"]),
    default="exact",
    show_default=True,
    help="Inverse white balance: exact (divide by the gains), or Brooks et al.'s "
    "highlight-preserving one, whose near-white highlights render pink unless "
    "clipped (--highlights clip).",
)
@click.option(
    "--illuminant",
    metavar="NAME|FILE",
    help="The light spectral scenes (.npz, wavelength-named EXR) are seen under: D50, "
    "D55, D65, D75, A, F2, F11, ISO7589, or a file of two columns (nm, power); it "
    "replaces the one a scene carries (default: the scene's; D65 for a reflectance "
    "that has none).",
)
@click.option(
    "--strip-metadata",
    is_flag=True,
    help="Write none of the input's metadata (capture time, exposure, GPS, artist, "
    "copyright, XMP) into the DNGs; by default it is carried over.",
)
@batch_options
@click.pass_context
@usage_errors
def command(
    ctx,
    inputs,
    out_dir,
    profile,
    sensor_kind,
    cfa,
    iso,
    iso_range,
    seed,
    randomize,
    clean,
    fmt,
    noise,
    tone,
    transfer,
    exposure,
    lens,
    focal_length,
    aperture,
    vignetting,
    wb_inverse,
    illuminant,
    strip_metadata,
    jobs,
    executor,
    address,
    device,
    overwrite,
    shard,
    json_records,
):
    """Turn sRGB or scene-linear images into the noisy raw DNGs a sensor would record.

    INPUTS are image files or folders (searched recursively for PNG, JPEG, TIFF,
    EXR, HDR, BMP, WebP, and NumPy .npz spectral scenes). 8/16-bit images are
    display-referred: the inverse tone curve and the transfer are undone. Float
    images (EXR, HDR, float TIFF) are scene-linear. Then: sRGB → camera RGB through
    the profile's matrix, inverse white balance. A spectral scene (an npz of
    spectra and wavelengths, or an EXR whose channels are wavelengths: 400nm, …)
    is instead seen through the camera's measured spectral sensitivities under
    its illuminant or --illuminant: its exact raw camera RGB, white at G = 1; its
    DNG gets colour matrices fitted for A and D65. Then: mosaic in the profile's
    CFA (or --cfa: a Bayer pattern, XTRANS or any periodic R/G/B layout), optional
    vignetting, black/white levels, noise at the ISO, rounding and saturation at
    the white level. --lens adds a real lens (lensfun's distortion, lateral CA and
    vignetting) to the white-balanced camera RGB, where 'rawsim process
    --lens-correction auto' corrects it.

    Each file gives <stem>.dng (and <stem>.clean.dng with --clean, <stem>.npz with
    --format npz|both) and <stem>.json with every parameter used. The DNGs keep the
    input's EXIF (capture time, exposure, GPS, artist, copyright) and XMP, with the
    profile's camera and the simulated ISO and lens, unless --strip-metadata. The npz holds
    R, Gr, Gb, B planes (4, H/2, W/2) for a Bayer CFA, the whole mosaic (1, H, W)
    with cfa_pattern and cfa_colors for any other. Existing outputs are skipped
    unless --overwrite; files are written atomically.

    \b
    --randomize samples per file, as in Brooks et al. (CVPR 2019):
      colour matrix  random convex mix of their four XYZ→camera matrices
      red gain       U(1.9, 2.4);  blue gain U(1.5, 1.9)
      brightness     image divided by 1/N(0.8, 0.1) (recorded as BaselineExposure)
      noise levels   each σ × exp(N(0, spread²)) around the profile's fits, λ uniform
                     over its range (ELD, Wei et al. CVPR 2020); K follows the ISO
    Randomness is seeded from --seed and the file's path relative to its input
    folder, so results do not depend on order, --jobs or --shard.

    \b
    Example:
      rawsim unprocess photos/ renders/ -o raw/ --profile sony_a7s2 --iso 1600 --clean
      rawsim unprocess photos/ -o xtrans/ --profile fujifilm_xt3 --iso 3200
      rawsim unprocess photos/ -o xt-a7s2/ --profile sony_a7s2 --cfa XTRANS --iso 800
      rawsim unprocess scene.npz -o raw/ --profile nikon_d850 --iso 200 --illuminant A
      rawsim unprocess photos/ -o kit/ --profile canon_eos_700d --iso 400 \\
        --lens "Canon EF-S 18-55mm f/3.5-5.6 IS STM" --focal-length 18 --aperture 3.5
    """
    from rawsim.cameras.profiles import load_profile
    from rawsim.errors import RawsimError
    from rawsim.io.images import IMAGE_EXTENSIONS
    from rawsim.io.spectral import SPECTRAL_EXTENSIONS

    # Every usage error first, each with its option named, before torch and numba load.
    if iso is not None and iso_range:
        raise click.UsageError("both --iso and --iso-range given: keep one of them", ctx)
    try:
        prof = load_profile(profile)
    except RawsimError as err:
        raise bad_option("--profile", err) from None
    if iso is None and not iso_range:
        raise click.UsageError(
            f"no ISO given: add --iso N or --iso-range MIN MAX ({_iso_span(prof)})", ctx
        )
    if iso is None and iso_range[0] > iso_range[1]:
        raise bad_option(
            "--iso-range",
            f"MIN {iso_range[0]:g} exceeds MAX {iso_range[1]:g}: give MIN MAX in increasing order",
        )
    given = [(iso, "--iso")] if iso is not None else [(v, "--iso-range") for v in iso_range]
    for value, hint in given:
        try:
            prof.check_iso(value)
        except RawsimError as err:
            raise bad_option(hint, err) from None
        try:
            prof.noise.levels(noise, value)
        except RawsimError as err:
            raise bad_option("--noise", f"{err}: choose another --noise or profile") from None
    if cfa is not None:
        if sensor_kind == "mono":
            raise click.UsageError(
                "--cfa needs --sensor rgb: a mono sensor has no colour filter; drop one of them",
                ctx,
            )
        try:
            prof = prof.with_cfa(cfa)
        except RawsimError as err:
            raise bad_option("--cfa", err) from None
    said = ()  # said once here for the run; each sidecar records it too
    if sensor_kind != "mono" and prof.colour_warning:
        said = (prof.colour_warning,)
        click.echo(f"warning: {prof.colour_warning}", err=True)
    if (focal_length or aperture) and not lens:
        raise click.UsageError(
            "--focal-length and --aperture go with --lens NAME: add --lens, or drop them", ctx
        )
    lens_record = None
    if lens:  # lensfun's lens on the profile's camera; an unknown name is a usage error
        from rawsim.io.lensfun import lens_params

        lens_record, warnings = lens_params(
            lens, focal_length, aperture, None, prof.make, prof.model, adding=True
        )
        for warning in warnings:
            click.echo(f"warning: {warning}", err=True)
    if illuminant is not None:  # read once here: a bad name or file is a usage error
        from rawsim.spectral.tables import illuminant as read_illuminant

        try:
            read_illuminant(illuminant)
        except RawsimError as err:
            raise bad_option("--illuminant", err) from None
    checked = check_inputs(
        ctx,
        inputs,
        IMAGE_EXTENSIONS + SPECTRAL_EXTENSIONS,
        "input images",
        out_dir,
        shard,
        jobs,
        executor,
        address,
    )

    # Then the pipeline (numba; torch only where a stage needs it).
    from rawsim.device import resolve_device
    from rawsim.isp.curves import TransferSpec
    from rawsim.pipelines.unprocess import UnprocessOptions, unprocess_file

    try:
        spec = str(TransferSpec.parse(transfer))
    except RawsimError as err:
        raise bad_option("--transfer", err) from None
    resolve_device(device)
    options = UnprocessOptions(
        profile=prof,
        iso=iso,
        iso_range=tuple(iso_range) if iso_range else None,
        randomize=randomize,
        clean=clean,
        formats=("dng", "npz") if fmt == "both" else (fmt,),
        noise=noise,
        tone=tone,
        transfer=spec,
        exposure_ev=exposure,
        vignetting=vignetting,
        safe_white_balance=wb_inverse == "safe",
        device=device,
        seed=seed,
        sensor=sensor_kind,
        strip_metadata=strip_metadata,
        lens=lens_record,
        illuminant=illuminant,
    )
    options.check_isos()
    run_files(
        ctx,
        checked,
        seed,
        unprocess_file,
        options,
        jobs,
        overwrite,
        json_records,
        executor,
        address,
        said,
    )


def _iso_span(prof) -> str:
    """The ISOs a profile takes, for messages: ``sony_a7s2 takes ISO 100–409600``."""
    if prof.iso_range is None:
        return f"{prof.name} takes any ISO > 0"
    lo, hi = prof.iso_range
    return f"{prof.name} takes ISO {lo:g}" + ("" if lo == hi else f"–{hi:g}")
