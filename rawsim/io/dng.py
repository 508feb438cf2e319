"""Writing CFA DNG files with tifffile (Adobe DNG Specification 1.7.1.0).

The files are uncompressed 16-bit, which LibRaw/rawpy, dcraw, darktable and
RawTherapee all open.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from rawsim.cfa import CFA
from rawsim.color import ILLUMINANT_D65

_DENOMINATOR = 10000
_EXIF_IFD = 34665
# tifffile refuses to write tag 34665 itself; an unused code that sorts in the same
# place in IFD0 is written instead and renamed once the EXIF IFD exists.
_EXIF_PLACEHOLDER = 34666


@dataclass(frozen=True)
class DngInfo:
    """The metadata written into a DNG.

    Attributes:
        cfa: the mosaic's CFA pattern, or None for a monochrome sensor (one
            sample per pixel, LinearRaw, no colour tags). A 6×6 pattern
            (X-Trans) is written with CFARepeatPatternDim 6×6, which LibRaw
            reads as an X-Trans raw.
        black_level, white_level: DN.
        xyz_to_camera: (3, 3) D65 XYZ → camera matrix (ColorMatrix1).
        as_shot_neutral: camera response to the scene white, 1 / white-balance gains.
        make, model, unique_model: camera identification strings.
        iso: ISO speed.
        noise_profile: (S, O) for the NoiseProfile tag, or None.
        baseline_exposure: stops.
        orientation: TIFF orientation 1–8.
        software: writer name.
        datetime: the capture time ``"YYYY:MM:DD HH:MM:SS"`` (DateTime and EXIF
            DateTimeOriginal), e.g. from the input image, or None for no time tag
            (never the time of writing: outputs are byte-identical run to run).
    """

    cfa: CFA | None
    black_level: float
    white_level: float
    xyz_to_camera: tuple
    as_shot_neutral: tuple[float, float, float]
    make: str
    model: str
    unique_model: str
    iso: float
    noise_profile: tuple[float, float] | None = None
    baseline_exposure: float = 0.0
    orientation: int = 1
    software: str = "rawsim"
    datetime: str | None = None


def _rationals(values, signed: bool) -> tuple[int, ...]:
    out: list[int] = []
    for v in values:
        f = Fraction(float(v)).limit_denominator(_DENOMINATOR)
        if not signed and f < 0:
            raise ValueError(f"unsigned rational cannot hold {v}")
        out += [f.numerator, f.denominator]
    return tuple(out)


def dng_tags(info: DngInfo) -> list[tuple]:
    """tifffile ``extratags`` for ``info``: (code, type, count, value, writeonce)."""
    matrix = [v for row in info.xyz_to_camera for v in row] if info.cfa is not None else []
    iso = int(round(info.iso))
    tags = [
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, info.unique_model, True),  # UniqueCameraModel
        (271, "s", 0, info.make, True),
        (272, "s", 0, info.model, True),
        (274, "H", 1, int(info.orientation), True),
        (50713, "H", 2, (1, 1), True),  # BlackLevelRepeatDim
        (50714, "2I", 1, _rationals([info.black_level], False), True),  # BlackLevel
        (50717, "I", 1, int(round(info.white_level)), True),  # WhiteLevel
        (50730, "2i", 1, _rationals([info.baseline_exposure], True), True),  # BaselineExposure
        # ISO as TIFF/EP places it, in IFD0 (Adobe, exiftool); LibRaw reads the EXIF IFD.
        (34855, "H", 1, min(iso, 65535), True),
        (_EXIF_PLACEHOLDER, "I", 1, 0, True),  # becomes the ExifIFD pointer, see below
    ]
    if info.cfa is not None:  # monochrome DNGs have one colour plane and no colour tags
        pattern = tuple(info.cfa.dng_pattern)
        tags += [
            (33421, "H", 2, info.cfa.dng_repeat, True),  # CFARepeatPatternDim: 2×2, 6×6
            (33422, "B", len(pattern), pattern, True),  # CFAPattern
            (50710, "B", 3, (0, 1, 2), True),  # CFAPlaneColor
            (50711, "H", 1, 1, True),  # CFALayout: rectangular
            (50721, "2i", 9, _rationals(matrix, True), True),  # ColorMatrix1
            (50778, "H", 1, ILLUMINANT_D65, True),  # CalibrationIlluminant1
            (50728, "2I", 3, _rationals(info.as_shot_neutral, False), True),  # AsShotNeutral
        ]
    if info.noise_profile is not None:
        tags.append((51041, "d", 2, tuple(float(v) for v in info.noise_profile), True))
    return tags


def write_dng(path: str | Path, mosaic: np.ndarray, info: DngInfo) -> None:
    """Write a (H, W) uint16 mosaic with ``info`` as an uncompressed DNG at ``path``.

    A CFA mosaic when ``info.cfa`` is set; otherwise monochrome LinearRaw data.
    """
    import tifffile

    mosaic = np.ascontiguousarray(mosaic)
    if mosaic.ndim != 2 or mosaic.dtype != np.uint16:
        raise ValueError(f"mosaic must be a (H, W) uint16 array, got {mosaic.shape} {mosaic.dtype}")
    tifffile.imwrite(
        path,
        mosaic,
        # tifffile refuses one-sample LinearRaw: mono is written MinIsBlack, then retagged
        photometric=32803 if info.cfa is not None else "minisblack",
        subfiletype=0,
        metadata=None,
        software=info.software,
        datetime=info.datetime,
        extratags=dng_tags(info),
    )
    _append_exif_ifd(path, int(round(info.iso)), info.datetime)
    if info.cfa is None:
        with tifffile.TiffFile(path, mode="r+") as tif:
            tif.pages.first.tags["PhotometricInterpretation"].overwrite(34892)  # LinearRaw


def _append_exif_ifd(path: str | Path, iso: int, datetime: str | None = None) -> None:
    """Append a minimal EXIF IFD (ISO speed, and DateTimeOriginal when ``datetime`` is
    given) and point IFD0's ExifIFD tag at it.

    tifffile writes no EXIF sub-IFD, and LibRaw and dcraw read the ISO only from
    there. EXIF 2.3: ISOSpeedRatings is a SHORT, 65535 meaning "see ISOSpeed".
    The placeholder entry in IFD0 is rewritten in place: code → 34665, value →
    the new IFD's offset (its type, LONG, is what EXIF prescribes).
    """
    import tifffile

    entries = [
        (34855, 3, 1, min(iso, 65535)),  # ISOSpeedRatings, SHORT
        (34864, 3, 1, 3),  # SensitivityType: ISO speed, SHORT
        (34867, 4, 1, iso),  # ISOSpeed, LONG
    ]
    text = (datetime.encode("ascii") + b"\0") if datetime else b""
    if text:
        entries.append((36867, 2, len(text), 0))  # DateTimeOriginal, ASCII after the IFD
    with tifffile.TiffFile(path, mode="r+") as tif:
        order = tif.byteorder
        fh = tif.filehandle
        fh.seek(0, 2)
        if fh.tell() % 2:
            fh.write(b"\0")
        offset = fh.tell()
        after = offset + 2 + 12 * len(entries) + 4  # where the ASCII value goes
        body = struct.pack(order + "H", len(entries))
        for code, kind, count, value in entries:
            if kind == 2:
                packed = struct.pack(order + "I", after)
            else:
                packed = struct.pack(order + ("H2x" if kind == 3 else "I"), value)
            body += struct.pack(order + "HHI", code, kind, count) + packed
        body += struct.pack(order + "I", 0) + text
        fh.write(body)
        placeholder = tif.pages.first.tags[_EXIF_PLACEHOLDER]
        fh.seek(placeholder.offset)
        fh.write(struct.pack(order + "H", _EXIF_IFD))
        fh.seek(placeholder.valueoffset)
        fh.write(struct.pack(order + "I", offset))
