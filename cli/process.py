"""``rawsim process``: camera raws → RGB images through the configurable ISP."""

from __future__ import annotations

import click

from rawsim_cli.options import (
    TONES,
    PathType,
    batch_options,
    files_in_out,
    output_options,
    usage_errors,
)
from rawsim_cli.report import check_inputs, run_files

# Literal copies of the core lists (checked by a test) keep `--help` free of torch.
DEMOSAICS = ("wcd", "learned", "menon", "malvar", "bilinear")
HIGHLIGHTS = ("clip", "blend", "reconstruct", "unclip")
DENOISES = ("none", "gaussian", "bilateral", "profiled", "learned")
#: The ACES spaces, whose outputs are OpenEXR unless --format says otherwise.
ACES_SPACES = ("aces2065-1", "acescg")
SPACES = (
    "srgb", "display-p3", "adobe-rgb", "rec2020", "aces2065-1", "acescg", "prophoto", "xyz",
    "camera",
)  # fmt: skip
FORMATS = ("png", "tiff", "jpg", "exr", "dng")
#: Other usual spellings of the formats.
FORMAT_ALIASES = {"tif": "tiff", "jpeg": "jpg"}


@click.command("process")
@output_options
@files_in_out
@click.option(
    "-c",
    "--config",
    "config_path",
    type=PathType("file", exists=True),
    help="ISP config (TOML, see 'rawsim isp show'); flags below override it.",
)
@click.option(
    "--wb",
    help="White balance: camera (with LibRaw's fallbacks), daylight, auto (LibRaw's grey "
    "world) or R,G,B gains.",
)
@click.option(
    "--white-level",
    type=click.Choice(["file", "auto"]),
    help="file (default), or auto: the image's maximum if above 75% of the file's "
    "(LibRaw's default render).",
)
@click.option(
    "--saturation",
    type=click.Choice(["data", "white"]),
    help="Where each colour saturates: data (default: where its sites pile up below the "
    "white level, if they do; 'rawsim info' shows it) or white (the white level, as LibRaw "
    "with adjust_maximum_thr 0).",
)
@click.option(
    "--demosaic",
    type=click.Choice(DEMOSAICS),
    help="Demosaic method: wcd (default), learned (wcd and a learned correction: +0.5 dB "
    "on average, slower, weaker on saturated colour edges), menon, malvar, bilinear. On "
    "X-Trans (6×6) raws, bilinear stays bilinear and the others become icd, rawsim's "
    "X-Trans interpolation.",
)
@click.option(
    "--demosaic-domain",
    type=click.Choice(["sqrt", "linear"]),
    help="What the demosaic interpolates: sqrt (default: square roots, squared back, "
    "so its errors fall where the output's gamma hides them) or linear (as LibRaw).",
)
@click.option(
    "--half-size",
    is_flag=True,
    help="Half the width and height, no demosaic: one pixel per 2×2 block of the "
    "mosaic (LibRaw's half_size), for fast previews.",
)
@click.option(
    "--highlights",
    type=click.Choice(HIGHLIGHTS),
    help="reconstruct (default): rebuild clipped colours on the mosaic from the unclipped "
    "ones and the surrounding hue (as darktable's inpaint opposed); clip at white (LibRaw "
    "-H 0); unclip: keep values above white (-H 1), on the mosaic, a clipped site raised "
    "to what the unclipped colours of its 2×2 (X-Trans 3×3) block measured, neutral where "
    "all clipped; blend: dcraw's blend (-H 2).",
)
@click.option(
    "--denoise",
    type=click.Choice(DENOISES),
    help="profiled: remove the sensor's noise on the mosaic, as its noise model "
    "predicts it (see --noise-profile); learned: a network trained on rawsim's own "
    "data refines that (Bayer; others fall back to profiled); gaussian or bilateral: "
    "smoothing filters of the RGB image; none.",
)
@click.option(
    "--denoise-strength",
    type=float,
    help="Scales the noise σ --denoise profiled or learned removes (default 1: the model's).",
)
@click.option(
    "--noise-profile",
    help="The noise model for --denoise profiled or learned: a bundled profile or a profile file "
    "('rawsim calibrate' output). Default: the camera's bundled profile, else the DNG "
    "NoiseProfile tag, else an estimate from the raw.",
)
@click.option("--tone", type=click.Choice(TONES), help="Tone curve.")
@click.option(
    "--tone-exposure",
    type=float,
    metavar="STOPS",
    help="Filmic curves (reinhard, aces, hable): stops of gain before the curve, 0–4 "
    "(display white at 2^-STOPS of the sensor's white). Default 0.",
)
@click.option(
    "--tone-white",
    metavar="W|auto",
    help="Filmic curves: white point in the curve's units, 0.25–12 (auto: reinhard 4, aces 7.24, "
    "hable 11.2); larger compresses highlights more.",
)
@click.option(
    "--exposure",
    metavar="EV|auto",
    help="Exposure in stops (default 0), or auto: the 99th percentile to white, as "
    "LibRaw's auto-brightness (at most +8 stops; the file's BaselineExposure is then moot).",
)
@click.option(
    "--baseline-exposure",
    type=click.Choice(["apply", "ignore"]),
    help="The DNG's BaselineExposure: apply (default, as Adobe's DNG SDK) or ignore (as LibRaw).",
)
@click.option(
    "--dng-matrices",
    type=click.Choice(["interpolate", "libraw"]),
    help="A DNG with two colour matrices (ColorMatrix1/2): interpolate them by the white "
    "balance used (default, as the DNG specification and Adobe's DNG SDK) or take one "
    "(the D65 one, as LibRaw).",
)
@click.option(
    "--output-space",
    type=click.Choice(SPACES),
    help="Colour space of the output (default srgb), each with its own transfer and an "
    "embedded ICC profile; xyz is CIE XYZ (D65); camera is the camera's RGB, untagged; "
    "aces2065-1 and acescg are linear and written as OpenEXR unless --format is given "
    "(aces2065-1 at 16 bits as the ACES container, SMPTE ST 2065-4).",
)
@click.option(
    "--transfer",
    metavar="auto|srgb|bt2020|romm|gamma:G|linear",
    help="Output transfer function. Default auto, the space's own: the sRGB curve for "
    "srgb, display-p3, xyz and camera; gamma 563/256 for adobe-rgb; BT.2020's for "
    "rec2020; ROMM's (1.8, linear toe) for prophoto.",
)
@click.option(
    "--lens-correction",
    type=click.Choice(["auto", "off"]),
    help="Correct the lens's distortion, lateral chromatic aberration and vignetting "
    "with lensfun's data for the raw's camera, lens, focal length, aperture and focus "
    "distance (from its metadata). Default off, as LibRaw.",
)
@click.option(
    "--lens",
    metavar="NAME",
    help="The lens, as lensfun lists it (e.g. 'Canon EF-S 18-55mm f/3.5-5.6 IS STM'), "
    "for raws whose metadata lacks it; corrects the lens.",
)
@click.option(
    "--focal-length",
    type=click.FloatRange(min=0, min_open=True),
    metavar="MM",
    help="Focal length in mm, for raws whose metadata lacks it; corrects the lens.",
)
@click.option(
    "--aperture",
    type=click.FloatRange(min=0, min_open=True),
    metavar="F",
    help="f-number, for raws whose metadata lacks it (else vignetting is not "
    "corrected); corrects the lens.",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(FORMATS + tuple(FORMAT_ALIASES), case_sensitive=False),
    callback=lambda ctx, param, value: FORMAT_ALIASES.get(value.lower(), value.lower()),
    default="png",
    show_default=True,
    help="Output format; EXR is scene-linear (no tone curve or transfer); DNG is the "
    "raw's mosaic as a raw for an editor, denoised with --denoise (only that applies).",
)
@click.option(
    "--dng",
    "dng",
    type=click.Choice(["mosaic", "linear"]),
    default=None,
    help="With --format dng: 'mosaic' (the CFA mosaic; the default for raws with one) or "
    "'linear' (rawsim's demosaic, as camera RGB: LinearRaw; the default for raws without).",
)
@click.option(
    "--bits",
    type=click.Choice(["8", "16", "32"]),
    default=None,
    help="Bits per sample: 8 or 16 (PNG, TIFF; JPEG 8), 16 (half) or 32 for EXR. "
    "Default 8, EXR and DNG 16.",
)
@click.option(
    "--resize",
    type=click.IntRange(min=1),
    metavar="LONG_EDGE",
    help="Scale the output down to this many pixels on its longer side (antialiased); "
    "renders at half size first when the result is at most half the raw's size.",
)
@click.option(
    "--thumbnail",
    is_flag=True,
    help="Write the raw's embedded preview (its JPEG, as stored, with the raw's "
    "metadata) instead of rendering; --format jpg.",
)
@click.option(
    "--strip-metadata",
    is_flag=True,
    help="Write none of the raw's metadata (camera, lens, exposure, time, GPS, "
    "artist, XMP) into the images; by default it is carried over.",
)
@batch_options
@click.pass_context
@usage_errors
def command(
    ctx,
    inputs,
    out_dir,
    config_path,
    wb,
    white_level,
    saturation,
    demosaic,
    demosaic_domain,
    half_size,
    highlights,
    denoise,
    denoise_strength,
    noise_profile,
    tone,
    tone_exposure,
    tone_white,
    exposure,
    baseline_exposure,
    dng_matrices,
    output_space,
    transfer,
    lens_correction,
    lens,
    focal_length,
    aperture,
    fmt,
    bits,
    dng,
    resize,
    thumbnail,
    strip_metadata,
    jobs,
    executor,
    address,
    device,
    overwrite,
    shard,
    json_records,
):
    """Render camera raws (anything LibRaw reads) through rawsim's own ISP.

    INPUTS are raw files or folders (searched recursively for DNG, CR2, CR3,
    NEF, ARW, RAF, ORF, RW2, PEF, SRW, KDC, …). The ISP is the ordered list of
    stages in the config (default: 'rawsim isp show'): black level, white
    balance, highlights, demosaic, colour matrix, exposure, tone, transfer,
    orientation, with optional dead-pixel, lens-shading, anti-aliasing,
    denoise, lens-correction (lensfun) and YCbCr stages. No automatic
    brightening by default: at exposure 0 the white level maps to 1.0
    (--exposure auto brightens as LibRaw does; a render whose 99th percentile
    is below 1/8 of full scale gets a warning).

    Each file gives <stem>.<ext> and <stem>.process.json (camera data, warnings, the
    white balance and matrix used, and the effective config). The image keeps
    the raw's metadata (camera, serial number, lens, capture time, exposure,
    aperture, ISO, focal length, flash, GPS, artist, copyright, description,
    XMP; Orientation 1, as the pixels are rotated) unless --strip-metadata.
    Bayer and X-Trans (and other periodic R/G/B) mosaics are demosaicked; raws
    without a CFA (linear DNGs) are rendered as 3-channel data.

    \b
    Example:
      rawsim process raws/ -o renders/ --wb camera --demosaic wcd --format tiff --bits 16
    """
    from rawsim.io.images import RAW_EXTENSIONS
    from rawsim.isp.config import IspConfig

    # Every usage error first, before the pipeline (and numba) is imported.
    config = IspConfig.load(config_path) if config_path else IspConfig.default()
    if half_size and (demosaic or demosaic_domain):
        flag = "--demosaic" if demosaic else "--demosaic-domain"
        raise click.UsageError(f"--half-size replaces the demosaic: drop {flag}", ctx)
    demosaic = "half" if half_size else demosaic
    config = config.override(
        wb=wb,
        white_level=white_level,
        saturation=saturation,
        demosaic=demosaic,
        demosaic_domain=demosaic_domain,
        highlights=highlights,
        denoise=denoise,
        denoise_strength=denoise_strength,
        noise_profile=noise_profile,
        tone=tone,
        exposure=exposure,
        tone_exposure=tone_exposure,
        tone_white=tone_white,
        baseline_exposure=baseline_exposure,
        dng_matrices=dng_matrices,
        output_space=output_space,
        transfer=transfer,
        lens_correction=lens_correction,
        lens=lens,
        focal_length=focal_length,
        aperture=aperture,
    )
    if noise_profile:  # a profile that does not load is a usage error, before any file
        from rawsim.cameras.profiles import load_profile

        load_profile(noise_profile)
    if lens:  # a name lensfun does not know is a usage error, before any file
        from rawsim.io.lensfun import find_lens

        find_lens(lens, required=True)
    given = ctx.get_parameter_source("fmt") != click.core.ParameterSource.DEFAULT
    if thumbnail:
        if given and fmt != "jpg":
            raise click.UsageError(
                "--thumbnail writes the raw's embedded JPEG: use --format jpg, or drop it", ctx
            )
        fmt = "jpg"
    if output_space in ACES_SPACES and not given and not thumbnail:
        fmt = "exr"  # ACES is scene-linear: OpenEXR, as ST 2065-4 stores it
    if dng is not None and fmt != "dng":
        raise click.UsageError(
            f"--dng {dng} is the kind of --format dng: add it, or drop --dng", ctx
        )
    nbits = int(bits) if bits else (16 if fmt in ("exr", "dng") else 8)
    valid = {"png": (8, 16), "tiff": (8, 16), "jpg": (8,), "exr": (16, 32), "dng": (16,)}[fmt]
    if nbits not in valid:
        raise click.UsageError(f"--format {fmt} takes --bits {' or '.join(map(str, valid))}", ctx)
    checked = check_inputs(
        ctx, inputs, RAW_EXTENSIONS, "raw files", out_dir, shard, jobs, executor, address
    )

    from rawsim.device import resolve_device
    from rawsim.pipelines.process import ProcessOptions, process_file

    resolve_device(device)
    options = ProcessOptions(
        config=config,
        fmt=fmt,
        bits=nbits,
        device=device,
        strip_metadata=strip_metadata,
        resize=resize,
        thumbnail=thumbnail,
        dng=dng,
    )
    run_files(
        ctx,
        checked,
        0,  # processing draws no random numbers
        process_file,
        options,
        jobs,
        overwrite,
        json_records,
        executor,
        address,
    )
