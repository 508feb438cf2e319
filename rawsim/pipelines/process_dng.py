"""``rawsim process --format dng``: a raw, denoised, back as a raw.

Two kinds (``--dng``): ``mosaic``, the CFA mosaic, for raws that have one; and
``linear``, rawsim's demosaic as camera RGB (LinearRaw, as Lightroom's and DxO
PureRAW's denoised DNGs are; :func:`~rawsim.pipelines.process._camera_rgb`), for
every raw, LinearRaw DNGs and the old 3-colour raws included.

The mosaic kind is a CFA DNG (Adobe DNG Specification 1.7.1.0; :func:`rawsim.io.dng.
write_dng`) that editors open as the original: the mosaic as LibRaw decodes it (the
visible area, linear DN), after the raw denoise stage when one is asked for, with
the raw's CFA (2 × 2 Bayer or 6 × 6 X-Trans), black level per site of the period,
white level; both kinds carry the colour (a DNG's own ColorMatrix1/2, CalibrationIlluminant1/2,
CameraCalibration1/2 and AnalogBalance as they are; otherwise LibRaw's XYZ → camera
matrix under D65, the Adobe matrix it holds, or its camera → sRGB matrix inverted,
:func:`~rawsim.io.raw.xyz_to_camera_of`), AsShotNeutral (the camera's white
balance, where LibRaw would use it), BaselineExposure, orientation and ISO, a
DNG's own Orientation and rendering tags (:data:`RENDER_TAGS`: its crop, profile and
gain maps; :func:`read_source_dng`), and
the raw's EXIF and XMP (camera, lens, exposure, time, GPS; not with
``--strip-metadata``). White balance, exposure, highlights, colour and tone stay
the editor's to choose, so options that shape a render are refused
(:meth:`~rawsim.pipelines.process.ProcessOptions.check_dng`).

The NoiseProfile tag (variance S·x + O per colour, x normalised to white = 1) says
what noise is left, so that an editor's own denoiser does not count the removed
noise again: the noise model the denoise stage took, scaled per colour by the
share of its variance that is left (:func:`noise_left`); NoiseReductionApplied
says how much was removed (1 − the mean share left), the DNG specification's way of
telling an editor to lower its own default noise reduction. Without denoising a DNG's
own NoiseProfile is kept as it is, and none is written for other raws.

The DNG embeds a preview of the result (IFD1, sRGB, at most :data:`~rawsim.
pipelines.process.DNG_PREVIEW` pixels on its longer side: the default render at
half size, highlights clipped), which file browsers and editors' libraries show
before they render, and keeps the raw's own preview where it has one (IFD2: its
JPEG as stored, or its bitmap).

Not written yet: trimming to DefaultCrop beyond LibRaw's visible area (the
DefaultCrop tags are kept).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from rawsim._version import __version__
from rawsim.errors import RawsimError
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.dng_colour import DngColour, read_dng_colour
from rawsim.io.metadata import PhotoMetadata, read_metadata
from rawsim.io.outputs import atomic_outputs
from rawsim.io.raw import RawImage, xyz_to_camera_of
from rawsim.io.task import Task

#: Sites at or above this share of the span between black and white are left out of
#: :func:`noise_left`'s statistics: clipping removes noise, not the denoiser.
NOISE_CLIPPED = 0.95
#: :func:`noise_left` reads at most about this many sites, a centred crop of whole
#: periods.
NOISE_SITES = 500_000


def write_dng_of(
    task: Task,
    options,
    raw: RawImage,
    out: RawImage,
    info: dict,
    preview: np.ndarray,
    rgb: tuple[np.ndarray, dict] | None = None,
) -> dict:
    """Write ``out`` (``raw`` after the raw denoise stage, or ``raw`` itself) to
    ``task.outputs["image"]`` as a DNG with ``raw``'s metadata and the ``preview`` of
    ``out`` ((h, w, 3) uint8 sRGB, unrotated), and its sidecar: its CFA mosaic, or
    where ``rgb`` is given, those (H, W, 3) uint16 camera RGB samples (black 0, white
    65535) and the record of their render, as LinearRaw. ``options``: the job's
    :class:`~rawsim.pipelines.process.ProcessOptions`; ``info``: the resolved
    config's record (:attr:`~rawsim.isp.config.ResolvedIsp.info`). Returns the
    sidecar's record."""
    denoising = out is not raw
    if rgb is not None:
        black, white = np.zeros((1, 1)), 65535.0
    else:
        black = np.broadcast_to(np.asarray(raw.black_level, np.float64), raw.cfa.period)
        white = raw.white_level
    source = read_source_dng(raw)
    colour = source.colour
    matrix, matrix_source = xyz_to_camera_of(raw)
    if colour is None and matrix is None:
        raise RawsimError(
            f"{task.source}: neither the file nor LibRaw gives the camera's colour "
            "matrix, which a DNG must carry; render it with --format tiff instead"
        )
    photo = PhotoMetadata() if options.strip_metadata else read_metadata(task.source)
    make = photo.get("Exif.Image.Make") or raw.make
    model = photo.get("Exif.Image.Model") or raw.model
    neutral, neutral_source = _as_shot_neutral(raw)
    noise, left = _noise_profile(raw, out, info, denoising)
    previews = ((preview, SRGB_PREVIEW), *_original_preview(raw))
    carried = dict(source.tags)
    orientation = source.orientation or raw.orientation
    warnings = list(info["warnings"]) + list(raw.warnings)
    if rgb is not None and raw.cfa is not None and OPCODE_LIST2 in carried:
        del carried[OPCODE_LIST2]  # demosaicked: no map of CFA sites holds
        warnings.append(
            "the DNG's OpcodeList2 (gain maps: its lens shading) maps mosaic sites and "
            "is not applied by rawsim: the linear DNG leaves it out, and editors render "
            "its corners darker than the original's (--dng mosaic keeps it)"
        )
    dng = DngInfo(
        cfa=raw.cfa if rgb is None else None,
        black_level=black,
        white_level=white,
        xyz_to_camera=() if colour is not None else tuple(map(tuple, matrix)),
        as_shot_neutral=neutral,
        make=make,
        model=model,
        unique_model=f"{make} {model}",
        iso=raw.iso,
        noise_profile=noise,
        baseline_exposure=raw.baseline_exposure,
        orientation=orientation,
        software=f"rawsim {__version__}",
        colour=colour,
        rgb=rgb is not None,
        noise_reduction_applied=None if left is None else 1 - float(np.mean(left)),
        extra_tags=carried,
    )
    samples = out.data if rgb is None else rgb[0]
    h, w = samples.shape[:2]
    meta = {
        "rawsim_version": __version__,
        "input": task.key,
        "camera": {"make": raw.make, "model": raw.model},
        "format": "dng",
        "dng": "mosaic" if rgb is None else "linear",
        "cfa_pattern": None if raw.cfa is None else raw.cfa.pattern,
        "linear": None if rgb is None else rgb[1],
        "width": w,
        "height": h,
        "black_level": black.tolist(),
        "white_level": white,
        "iso": raw.iso,
        "orientation": orientation,
        "colour_tags": (
            "the file's own (ColorMatrix, CalibrationIlluminant, CameraCalibration, AnalogBalance)"
            if colour is not None
            else f"ColorMatrix1 under D65: {matrix_source}"
        ),
        "as_shot_neutral": None if neutral is None else [round(v, 6) for v in neutral],
        "as_shot_neutral_source": neutral_source,
        "baseline_exposure": raw.baseline_exposure,
        "raw_denoise": info.get("raw_denoise", "none"),
        "noise_model": info.get("noise_model"),
        "noise_left": left,
        "noise_profile": None if noise is None else [float(v) for v in noise],
        "metadata": "stripped" if options.strip_metadata else "the raw's EXIF and XMP",
        "dng_tags_kept": sorted(tag_name(code) for code in carried),
        "original_preview": len(previews) > 1,
        "preview": {
            "width": preview.shape[1],
            "height": preview.shape[0],
            "kind": "the default render at half size, highlights clipped, sRGB",
        },
        "config": options.config.to_tables(),
        "warnings": warnings,
    }
    with atomic_outputs(task.outputs) as tmp:
        write_dng(tmp["image"], samples, dng, photo, previews)
        tmp["json"].write_text(json.dumps(meta, indent=2) + "\n")
    return meta


#: A DNG's tags that say how to render its raw data and still hold for the visible
#: area written back (its ActiveArea: the stage-2 image whose coordinates they use),
#: copied as they are: DefaultScale, DefaultCropOrigin, DefaultCropSize,
#: BayerGreenSplit, BaselineNoise, BaselineSharpness, LinearResponseLimit,
#: CameraSerialNumber, AntiAliasStrength, ShadowScale, BestQualityScale, ProfileName,
#: ProfileHueSatMapDims, ProfileHueSatMapData1/2, ProfileToneCurve, ProfileEmbedPolicy,
#: ProfileCopyright, ForwardMatrix1/2, ProfileLookTableDims/Data, OpcodeList2 (on the
#: linear raw data: a lens's gain maps), OpcodeList3 (after the demosaic: its
#: warps), BaselineExposureOffset, DefaultBlackRender, ProfileHueSatMapEncoding,
#: ProfileLookTableEncoding, DefaultUserCrop. Not OpcodeList1: it acts on the stored
#: data before linearisation, which LibRaw has done.
RENDER_TAGS = (
    50718, 50719, 50720, 50733, 50731, 50732, 50734, 50735, 50738, 50739, 50780,
    50936, 50937, 50938, 50939, 50940, 50941, 50942, 50964, 50965, 50981, 50982,
    51009, 51022, 51109, 51110, 51107, 51108, 51125,
)  # fmt: skip


#: The tag that holds a DNG's opcodes for the linear raw data (gain maps).
OPCODE_LIST2 = 51009


@dataclass(frozen=True)
class SourceDng:
    """What a raw that is itself a DNG says for its DNG written back, read in one pass:
    its own ``colour`` tags (:func:`~rawsim.io.dng_colour.read_dng_colour`, None
    without a 3 × 3 ColorMatrix), its ``orientation`` (IFD0's, mirrors included, which
    LibRaw's flip lacks; None without one), and its rendering ``tags``
    (:data:`RENDER_TAGS`, code → (TIFF field type, values) as
    :func:`rawsim.io.tiff.write_tiff` takes them; none where the visible area LibRaw
    decoded is not the DNG's ActiveArea, whose coordinates they use)."""

    colour: DngColour | None = None
    orientation: int | None = None
    tags: dict = field(default_factory=dict)


def read_source_dng(raw: RawImage) -> SourceDng:
    """:class:`SourceDng` of ``raw``'s file (IFD0, then the raw image's IFD); empty for
    other raws, and for what cannot be read here (LibRaw's reading stands)."""
    import tifffile

    try:
        with tifffile.TiffFile(raw.path) as tif:
            first = tif.pages.first
            if "DNGVersion" not in first.tags:
                return SourceDng()
            try:
                colour = read_dng_colour(first.tags)
            except Exception:  # a colour tag we cannot parse: LibRaw's matrix stands
                colour = None
            orientation = int(first.tags[274].value) if 274 in first.tags else None
            pages = [p for top in tif.pages for p in (top, *(top.pages or ()))]
            main = next(
                (p for p in pages if p.subfiletype == 0 and p.photometric in (32803, 34892)),
                first,
            )
            tags = {**dict(main.tags.items()), **dict(first.tags.items())}
            top, left, bottom, right = (
                tags[50829].value if 50829 in tags else (0, 0, *main.shape[:2])
            )
            kept = {}
            if (bottom - top, right - left) == raw.data.shape[:2]:
                for code in RENDER_TAGS:
                    if code not in tags:
                        continue
                    kind, value = int(tags[code].dtype), tags[code].value
                    if isinstance(value, int | float):
                        value = [value]
                    kept[code] = (kind, value if isinstance(value, str | bytes) else list(value))
    except Exception:  # not TIFF-based, or unreadable here: nothing carried over
        return SourceDng()
    return SourceDng(colour, orientation, kept)


#: PreviewColorSpace: unknown, and sRGB.
UNKNOWN_PREVIEW, SRGB_PREVIEW = 0, 2


def _original_preview(raw: RawImage) -> tuple[tuple[np.ndarray | bytes, int], ...]:
    """The raw's own embedded preview (:func:`rawsim.io.thumbnail.read_thumbnail`: its
    JPEG as stored, or its bitmap), to keep beside the render of the result; its colour
    space unknown. None where it has none."""
    from rawsim.errors import UnsupportedInputError
    from rawsim.io.thumbnail import read_thumbnail

    try:
        thumb = read_thumbnail(raw.path)
    except UnsupportedInputError:
        return ()
    return ((thumb.jpeg if thumb.jpeg is not None else thumb.bitmap, UNKNOWN_PREVIEW),)


def tag_name(code: int) -> str:
    """A TIFF/DNG tag's name (tifffile's table), or its number."""
    import tifffile

    return tifffile.TIFF.TAGS.get(code, str(code))


def _as_shot_neutral(raw: RawImage) -> tuple[tuple[float, float, float] | None, str]:
    """AsShotNeutral (the camera's response to the scene's white: 1 / each white-balance
    gain) from the camera's multipliers, and what it is; None where LibRaw would not
    use them (:attr:`~rawsim.io.raw.RawImage.as_shot_wb`): the DNG then records no
    white balance either, and an editor chooses one as for the original."""
    gains = raw.as_shot_wb
    if gains is None or not all(g > 0 for g in gains):
        return None, f"none: the file's multipliers ({raw.camera_wb_note}) are not used"
    return tuple(float(gains[1] / g) for g in gains), "the camera's multipliers"


def _noise_profile(raw: RawImage, out: RawImage, info: dict, denoising: bool):
    """(NoiseProfile values or None, the share of variance left per colour or None):
    after denoising, the model's (S, O) per colour R, G, B scaled by
    :func:`noise_left`; without it, a DNG's own tag, as it is."""
    from rawsim.denoise.noise_model import NoiseModel, dng_noise_profile

    span = float(raw.white_level) - float(np.mean(raw.black_level))
    if not denoising:
        model = dng_noise_profile(raw)
        if model is None:
            return None, None
        gain, offset = model.normalised(span)
        return _pairs(gain, offset), None
    gain, offset = NoiseModel.from_dict(info["noise_model"]).normalised(span)
    left = noise_left(raw.data, out.data, raw, gain, offset)
    kept = [(g * r, o * r) for g, o, r in zip(gain, offset, left, strict=True)]
    return _pairs(*zip(*kept, strict=True)), [round(r, 4) for r in left]


def _pairs(gain, offset) -> tuple[float, ...]:
    """NoiseProfile's values: (S, O) for R, G, B in turn."""
    return tuple(float(v) for pair in zip(gain, offset, strict=True) for v in pair)


def noise_left(before: np.ndarray, after: np.ndarray, raw: RawImage, gain, offset) -> list[float]:
    """The share (0–1) of each colour's (R, G, B) noise variance left in the (H, W)
    mosaic ``after`` of ``before``: the squared ratio of the two mosaics' robust
    noise estimates. Each estimate is the median absolute difference between each
    site and the site one period to its right (the same colour), over the σ the
    model (``gain``, ``offset``: variance gain·x + offset, x normalised to white = 1)
    gives that difference, × 1.4826; sites near white (:data:`NOISE_CLIPPED`) are
    left out. Texture counts as noise in both, so the share is if anything too high
    (an editor then removes a little more, never counts removed noise again)."""
    ph, pw = raw.cfa.period
    h, w = before.shape
    rows = min(h, max(ph, (NOISE_SITES // max(w, 1)) // ph * ph))
    y0 = (h - rows) // 2 // ph * ph
    black = np.broadcast_to(np.asarray(raw.black_level, np.float32), (ph, pw))
    black = np.tile(black, (rows // ph + 1, w // pw + 1))[:rows, : w - pw]
    span = np.float32(raw.white_level) - black
    colours = np.tile(np.array(raw.cfa.colors).reshape(ph, pw), (rows // ph + 1, w // pw + 1))
    colours = colours[:rows, : w - pw]

    def sigma(mosaic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        part = mosaic[y0 : y0 + rows].astype(np.float32)
        a, b = part[:, : w - pw], part[:, pw:]
        level = np.clip(((a + b) / 2 - black) / span, 0, None)
        g, o = np.asarray(gain, np.float32), np.asarray(offset, np.float32)
        var = 2 * (g[colours] * level + o[colours])
        return (a - b) / np.sqrt(np.maximum(var, 1e-12)), level

    z_before, level = sigma(before)
    z_after, _ = sigma(after)
    usable = level < NOISE_CLIPPED
    left = []
    for c in range(3):
        keep = np.flatnonzero(usable & (colours == c))
        s0 = float(np.median(np.abs(z_before.ravel()[keep]))) if keep.size else 0.0
        s1 = float(np.median(np.abs(z_after.ravel()[keep]))) if keep.size else 0.0
        left.append(min(1.0, (s1 / s0) ** 2) if s0 > 0 else 1.0)
    return left
