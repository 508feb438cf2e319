"""Writing CFA DNG files (Adobe DNG Specification 1.7.1.0) with their EXIF.

The files are uncompressed 16-bit, which LibRaw/rawpy, dcraw, darktable and
RawTherapee all open. They are laid out by :func:`rawsim.io.tiff.write_tiff`:
the EXIF block exiv2 encodes (IFD0's photo fields, the Exif and GPS IFDs) heads
the file, then IFD0 with the DNG tags, then the mosaic, in one pass.

What the EXIF says (:func:`dng_metadata`): the input photo's capture (time,
exposure, aperture, focal length, flash, GPS, artist, copyright, description,
its XMP less what describes another camera or its development), with the
simulated camera (Make, Model: the profile's), ISO and lens.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from rawsim.cfa import CFA
from rawsim.color import ILLUMINANT_D65
from rawsim.io.dng_colour import DngColour
from rawsim.io.lensfun import LensParams
from rawsim.io.metadata import Output, PhotoMetadata, exif_block, xmp_without
from rawsim.io.tiff import ASCII, BYTE, DOUBLE, LONG, RATIONAL, SHORT, SRATIONAL, write_tiff

_DENOMINATOR = 10000
#: The input photo's EXIF fields that describe its camera and lens, not the
#: simulated capture: a DNG names the profile's camera, its ISO and lens.
_DEVICE_KEYS = frozenset(
    {
        "Exif.Image.Make",
        "Exif.Image.Model",
        "Exif.Photo.BodySerialNumber",
        "Exif.Photo.LensMake",
        "Exif.Photo.LensModel",
        "Exif.Photo.LensSpecification",
        "Exif.Photo.LensSerialNumber",
        "Exif.Photo.ISOSpeedRatings",
    }
)
#: XMP namespaces dropped from the input's packet: the camera, lens and EXIF
#: duplicates (tiff, exif, exifEX, aux), a raw developer's settings for the input
#: (crs: Lightroom would apply them to the DNG), and its document history (xmpMM).
_XMP_DROPPED = ("tiff", "exif", "exifEX", "aux", "crs", "xmpMM")


@dataclass(frozen=True)
class DngInfo:
    """The metadata written into a DNG.

    Attributes:
        cfa: the mosaic's CFA pattern, or None for LinearRaw data: one sample per
            pixel (a monochrome sensor, no colour tags) or three (camera RGB, with
            the colour tags, ``rgb``). A 6×6 pattern (X-Trans) is written with
            CFARepeatPatternDim 6×6, which LibRaw reads as an X-Trans raw.
        black_level, white_level: DN; ``black_level`` one number, or (ph, pw) per
            site of the CFA's period (BlackLevelRepeatDim).
        xyz_to_camera: (3, 3) D65 XYZ → camera matrix (ColorMatrix1), where
            ``colour`` is None.
        as_shot_neutral: camera response to the scene white, 1 / white-balance gains;
            None: no AsShotNeutral (a raw that records no white balance).
        make, model, unique_model: camera identification strings.
        iso: ISO speed.
        noise_profile: (S, O) for the NoiseProfile tag, or (S, O) per colour R, G,
            B (6 numbers), or None: variance S·x + O of the signal x normalised to
            white = 1.
        baseline_exposure: stops.
        orientation: TIFF orientation 1–8.
        software: writer name.
        metadata: the input photo's EXIF and XMP (:func:`dng_metadata` says what
            is kept); its capture time gives DateTime (never the time of writing:
            outputs are byte-identical run to run).
        lens: the simulated lens, recorded in the lens tags (LensMake, LensModel,
            FocalLength, FNumber, SubjectDistance), or None.
        rgb: LinearRaw camera RGB (``cfa`` None, three samples a pixel).
        noise_reduction_applied: NoiseReductionApplied, how much of the noise was
            removed (0–1), or None (not written: none was).
        extra_tags: more tags, code → (TIFF field type, values), written as they are
            where this writer sets no tag of that code (a raw's own rendering tags:
            :func:`rawsim.pipelines.process_dng.read_source_dng`).
        colour: a raw's own DNG colour tags (ColorMatrix1/2 with their
            CalibrationIlluminant1/2, CameraCalibration1/2, AnalogBalance), written
            as they are in place of ``xyz_to_camera``; None: ``xyz_to_camera``
            under D65.
    """

    cfa: CFA | None
    black_level: float | np.ndarray
    white_level: float
    xyz_to_camera: tuple
    as_shot_neutral: tuple[float, float, float] | None
    make: str
    model: str
    unique_model: str
    iso: float
    noise_profile: tuple[float, float] | None = None
    baseline_exposure: float = 0.0
    orientation: int = 1
    software: str = "rawsim"
    metadata: PhotoMetadata = field(default_factory=PhotoMetadata)
    lens: LensParams | None = None
    colour: DngColour | None = None
    rgb: bool = False
    noise_reduction_applied: float | None = None
    extra_tags: dict = field(default_factory=dict)


def dng_tags(info: DngInfo) -> dict[int, tuple[int, object]]:
    """IFD0's DNG tags for ``info``: code → (TIFF field type, values), as
    :func:`rawsim.io.tiff.write_tiff` takes them."""
    black = np.atleast_2d(np.asarray(info.black_level, np.float64))
    tags = {
        254: (LONG, [0]),  # NewSubfileType: the main image
        262: (SHORT, [32803 if info.cfa is not None else 34892]),  # CFA, else LinearRaw
        271: (ASCII, info.make),
        272: (ASCII, info.model),
        274: (SHORT, [int(info.orientation)]),
        # ISO as TIFF/EP places it, in IFD0 (Adobe, exiftool); LibRaw reads the EXIF IFD.
        34855: (SHORT, [min(int(round(info.iso)), 65535)]),
        50706: (BYTE, bytes((1, 4, 0, 0))),  # DNGVersion
        50707: (BYTE, bytes((1, 1, 0, 0))),  # DNGBackwardVersion
        50708: (ASCII, info.unique_model),  # UniqueCameraModel
        50713: (SHORT, list(black.shape)),  # BlackLevelRepeatDim
        50714: (RATIONAL, _rationals(black.ravel(), False)),  # BlackLevel
        50717: (LONG, [int(round(info.white_level))]),  # WhiteLevel
        50730: (SRATIONAL, _rationals([info.baseline_exposure], True)),  # BaselineExposure
    }
    if info.cfa is not None:
        tags |= {
            33421: (SHORT, list(info.cfa.dng_repeat)),  # CFARepeatPatternDim: 2×2, 6×6
            33422: (BYTE, bytes(info.cfa.dng_pattern)),  # CFAPattern
            50710: (BYTE, bytes((0, 1, 2))),  # CFAPlaneColor
            50711: (SHORT, [1]),  # CFALayout: rectangular
        }
    if info.cfa is not None or info.rgb:  # monochrome DNGs have no colour tags
        if info.as_shot_neutral is not None:
            tags[50728] = (RATIONAL, _rationals(info.as_shot_neutral, False))  # AsShotNeutral
        tags |= _colour_tags(info)
    if info.noise_profile is not None:
        tags[51041] = (DOUBLE, [float(v) for v in info.noise_profile])  # NoiseProfile
    if info.noise_reduction_applied is not None:
        applied = _rationals([info.noise_reduction_applied], False)
        tags[50935] = (RATIONAL, applied)  # NoiseReductionApplied
    return {**info.extra_tags, **tags}


def _colour_tags(info: DngInfo) -> dict[int, tuple[int, object]]:
    """ColorMatrix1/2, CalibrationIlluminant1/2, CameraCalibration1/2 and AnalogBalance:
    ``info.colour``'s as they are, else ``info.xyz_to_camera`` under D65."""
    colour = info.colour
    if colour is None:
        matrix = np.asarray(info.xyz_to_camera, np.float64).ravel()
        return {
            50721: (SRATIONAL, _rationals(matrix, True)),  # ColorMatrix1
            50778: (SHORT, [ILLUMINANT_D65]),  # CalibrationIlluminant1
        }
    tags = {}
    for i, (cm, ill, cc) in enumerate(((50721, 50778, 50723), (50722, 50779, 50724)), 1):
        if i in colour.matrices:
            code, matrix = colour.matrices[i]
            tags[cm] = (SRATIONAL, _rationals(np.ravel(matrix), True))
            tags[ill] = (SHORT, [int(code)])
        if i in colour.calibration:
            tags[cc] = (SRATIONAL, _rationals(np.ravel(colour.calibration[i]), True))
    if colour.analog_balance is not None:
        tags[50727] = (RATIONAL, _rationals(colour.analog_balance, False))  # AnalogBalance
    return tags


def dng_metadata(info: DngInfo) -> PhotoMetadata:
    """The EXIF and XMP a DNG carries: the input photo's, less its camera and lens
    (:data:`_DEVICE_KEYS`, :data:`_XMP_DROPPED`), with the simulated ISO
    (ISOSpeedRatings, SensitivityType 3: ISO speed, ISOSpeed), the capture time
    also as DateTime, and the simulated lens if any (its focal length and
    aperture replace the photo's; no FNumber when it has none)."""
    fields = {k: v for k, v in info.metadata.exif if k not in _DEVICE_KEYS}
    iso = int(round(info.iso))
    fields["Exif.Photo.ISOSpeedRatings"] = str(min(iso, 65535))
    fields["Exif.Photo.SensitivityType"] = "3"
    fields["Exif.Photo.ISOSpeed"] = str(iso)
    if "Exif.Photo.DateTimeOriginal" in fields:
        fields["Exif.Image.DateTime"] = fields["Exif.Photo.DateTimeOriginal"]
    lens = info.lens
    if lens is not None:
        for key in ("Exif.Photo.FNumber", "Exif.Photo.FocalLengthIn35mmFilm"):
            fields.pop(key, None)
        fields["Exif.Photo.LensMake"] = lens.lens_maker
        fields["Exif.Photo.LensModel"] = lens.lens
        fields["Exif.Photo.FocalLength"] = _rational_text(lens.focal_length)
        fields["Exif.Photo.FocalLengthIn35mmFilm"] = str(
            int(round(lens.focal_length * lens.crop_factor))
        )
        if lens.aperture is not None:
            fields["Exif.Photo.FNumber"] = _rational_text(lens.aperture)
        fields["Exif.Photo.SubjectDistance"] = _rational_text(lens.distance)
    xmp = xmp_without(info.metadata.xmp, _XMP_DROPPED)
    return PhotoMetadata(tuple(fields.items()), xmp)


def _rationals(values, signed: bool) -> list[int]:
    """Numbers as TIFF rationals: numerator, denominator pairs, flattened (denominators
    up to :data:`_DENOMINATOR`)."""
    out: list[int] = []
    for v in values:
        f = Fraction(float(v)).limit_denominator(_DENOMINATOR)
        if not signed and f < 0:
            raise ValueError(f"unsigned rational cannot hold {v}")
        out += [f.numerator, f.denominator]
    return out


def _rational_text(value: float) -> str:
    """A positive number as exiv2 reads a rational ("35/10")."""
    numerator, denominator = _rationals([value], False)
    return f"{numerator}/{denominator}"


def write_dng(
    path: str | Path,
    mosaic: np.ndarray,
    info: DngInfo,
    metadata: PhotoMetadata | None = None,
    previews: tuple[tuple[np.ndarray | bytes, int], ...] = (),
) -> None:
    """Write a (H, W) uint16 mosaic with ``info`` as an uncompressed DNG at ``path``.

    A CFA mosaic when ``info.cfa`` is set; otherwise LinearRaw data: monochrome, or
    with ``info.rgb`` (H, W, 3) camera RGB.
    ``metadata``: the EXIF and XMP to write as they are (a raw's own, for ``process
    --format dng``); None: :func:`dng_metadata`'s (a photo's, with the simulated
    camera). ``previews``: images in the mosaic's orientation and their
    PreviewColorSpace (0 unknown, 2 sRGB), written as IFD1, IFD2, …: (h, w, 3) uint8
    arrays, or the bytes of baseline JPEGs.
    """
    shape = (3,) if info.rgb else ()
    if mosaic.shape[2:] != shape or mosaic.ndim != 2 + len(shape) or mosaic.dtype != np.uint16:
        raise ValueError(
            f"the samples must be a (H, W{', 3' * info.rgb}) uint16 array, got "
            f"{mosaic.shape} {mosaic.dtype}"
        )
    meta = dng_metadata(info) if metadata is None else metadata
    h, w = mosaic.shape[:2]
    exif = exif_block(meta, Output(info.software, "dng", w, h, orientation=info.orientation))
    reduced = tuple((image, {50970: (LONG, [space])}) for image, space in previews)
    samples = mosaic if info.rgb else mosaic[:, :, None]
    write_tiff(path, samples, exif, meta.xmp, tags=dng_tags(info), previews=reduced)
