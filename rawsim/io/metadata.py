"""Photo metadata (EXIF, GPS, XMP) read from a raw or a photo and carried into outputs.

A camera file's metadata is read with exiv2 (python-exiv2: every raw format
exiv2 knows, and JPEG, TIFF, PNG, WebP, …) into a :class:`PhotoMetadata`: the
fields a photo manager sorts and searches by (:data:`FIELDS`: camera, serial
number, lens, capture time with sub-seconds and time-zone offset, exposure,
aperture, ISO, exposure bias, focal length and its 35 mm equivalent, flash,
artist, copyright, description), every GPS tag, and the XMP packet. Each field
is taken from the first of its sources that the file has (raws record some in
TIFF/EP's or their maker notes' places; exiv2's "easy access" finds
those), and written under its standard EXIF key. Files exiv2 cannot read fall
back to what LibRaw reports (ISO, exposure, aperture, focal length, time,
artist).

A zero where zero means "not recorded" (exposure time, f-number, ISO, focal
length, subject distance: a firmware's or a converter's placeholder) is no value:
it is neither shown nor carried. Exposure bias 0 and Flash 0 ("no flash") are values.

Canon's maker notes hold some fields as raw codes (ISO, and in CRW files exposure,
aperture and focal length, which CRW has nowhere else); they are decoded as
exiftool decodes them (:data:`_CANON`), not through exiv2's CRW conversion, which
reads the signed exposure code as unsigned (every exposure longer than 1 s
became 1 s), turns a 0 aperture code into F1, and gives the capture time in the
reading machine's time zone.

Writing (:func:`exif_block`, :func:`embed`): exiv2 encodes the EXIF (its own
TIFF structure: IFD0, the Exif and GPS IFDs), which goes as it is into a PNG
``eXIf`` chunk and heads rawsim's TIFF files (:mod:`rawsim.io.tiff`); JPEG files
get it through exiv2 itself; EXR headers get the standard OpenEXR attributes.
Outputs always say Orientation 1 (rawsim rotates the pixels) and name rawsim
as their Software. The same metadata gives the same bytes.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

#: Standard EXIF key → the keys it is read from, in order of preference: the
#: standard places, TIFF/EP's, DNG's and the maker notes' (values there are taken
#: as exiv2 prints them: a lens code becomes the lens's name). exiv2's own "easy
#: access" search is not used: it crashes on some old raws (Kodak DC50).
FIELDS: dict[str, tuple[str, ...]] = {
    "Exif.Image.Make": ("Exif.Image.Make",),
    "Exif.Image.Model": ("Exif.Image.Model", "Exif.Image.UniqueCameraModel"),
    "Exif.Photo.BodySerialNumber": (
        "Exif.Photo.BodySerialNumber",
        "Exif.Image.CameraSerialNumber",
        "Exif.Canon.SerialNumber",
        "Exif.Nikon3.SerialNumber",
        "Exif.Fujifilm.SerialNumber",
        "Exif.OlympusEq.SerialNumber",
        "Exif.Pentax.SerialNumber",
        "Exif.Panasonic.InternalSerialNumber",
        "Exif.Sigma.SerialNumber",
    ),
    "Exif.Photo.LensMake": ("Exif.Photo.LensMake",),
    "Exif.Photo.LensModel": (
        "Exif.Photo.LensModel",
        "Exif.Canon.LensModel",
        "Exif.CanonCs.LensType",
        "Exif.OlympusEq.LensModel",
        "Exif.NikonLd3.LensIDNumber",
        "Exif.NikonLd2.LensIDNumber",
        "Exif.Sony2.LensID",
        "Exif.Sony1.LensID",
        "Exif.Minolta.LensID",
        "Exif.Pentax.LensType",
        "Exif.PentaxDng.LensType",
        "Exif.Panasonic.LensType",
        "Exif.Samsung2.LensType",
    ),
    "Exif.Photo.LensSpecification": ("Exif.Photo.LensSpecification",),
    "Exif.Photo.LensSerialNumber": ("Exif.Photo.LensSerialNumber",),
    "Exif.Photo.DateTimeOriginal": (
        "Exif.Photo.DateTimeOriginal",
        "Exif.Image.DateTimeOriginal",
        "Exif.Image.DateTime",
    ),
    "Exif.Photo.SubSecTimeOriginal": ("Exif.Photo.SubSecTimeOriginal", "Exif.Photo.SubSecTime"),
    "Exif.Photo.OffsetTimeOriginal": ("Exif.Photo.OffsetTimeOriginal", "Exif.Photo.OffsetTime"),
    "Exif.Photo.ExposureTime": (
        "Exif.Photo.ExposureTime",
        "Exif.Image.ExposureTime",
        "Exif.CanonSi.ShutterSpeedValue",
    ),
    "Exif.Photo.FNumber": (
        "Exif.Photo.FNumber",
        "Exif.Image.FNumber",
        "Exif.CanonSi.ApertureValue",
    ),
    "Exif.Photo.ISOSpeedRatings": (
        "Exif.Photo.ISOSpeedRatings",
        "Exif.Image.ISOSpeedRatings",
        "Exif.CanonCs.ISOSpeed",
        "Exif.Nikon3.ISOSpeed",
    ),
    "Exif.Photo.ExposureProgram": ("Exif.Photo.ExposureProgram", "Exif.Image.ExposureProgram"),
    "Exif.Photo.ExposureBiasValue": (
        "Exif.Photo.ExposureBiasValue",
        "Exif.Image.ExposureBiasValue",
    ),
    "Exif.Photo.MeteringMode": ("Exif.Photo.MeteringMode", "Exif.Image.MeteringMode"),
    "Exif.Photo.Flash": ("Exif.Photo.Flash", "Exif.Image.Flash"),
    "Exif.Photo.FocalLength": (
        "Exif.Photo.FocalLength",
        "Exif.Image.FocalLength",
        "Exif.Canon.FocalLength",
    ),
    "Exif.Photo.FocalLengthIn35mmFilm": ("Exif.Photo.FocalLengthIn35mmFilm",),
    "Exif.Photo.SubjectDistance": ("Exif.Photo.SubjectDistance", "Exif.Image.SubjectDistance"),
    "Exif.Image.Artist": ("Exif.Image.Artist",),
    "Exif.Image.Copyright": ("Exif.Image.Copyright",),
    "Exif.Image.ImageDescription": ("Exif.Image.ImageDescription",),
}
#: Every tag of this group is kept as it is.
GPS_GROUP = "Exif.GPSInfo."
SOFTWARE_KEY = "Exif.Image.Software"
#: Tags every output carries: the tags EXIF 2.32 requires (its version, FlashPix
#: version, resolution).
_OUTPUT_TAGS = (
    ("Exif.Image.XResolution", "72/1"),
    ("Exif.Image.YResolution", "72/1"),
    ("Exif.Image.ResolutionUnit", "2"),
    ("Exif.Photo.ExifVersion", "48 50 51 50"),
    ("Exif.Photo.FlashpixVersion", "48 49 48 48"),
)
_JPEG_TAGS = (
    ("Exif.Image.YCbCrPositioning", "1"),
    ("Exif.Photo.ComponentsConfiguration", "1 2 3 0"),
)
#: Fields whose 0 means "not recorded" (EXIF 2.32 says so of SubjectDistance and
#: FocalLengthIn35mmFilm, and of ExposureProgram and MeteringMode's 0; an exposure,
#: f-number, ISO or focal length of 0 cannot be). Other fields' 0 is a value.
_ZERO_UNKNOWN = frozenset(
    {
        "Exif.Photo.ExposureTime",
        "Exif.Photo.FNumber",
        "Exif.Photo.ISOSpeedRatings",
        "Exif.Photo.FocalLength",
        "Exif.Photo.FocalLengthIn35mmFilm",
        "Exif.Photo.SubjectDistance",
        "Exif.Photo.LensSpecification",
        "Exif.Photo.ExposureProgram",
        "Exif.Photo.MeteringMode",
    }
)
#: Fields that are numbers: a maker-note source must give a positive number.
_NUMBERS = frozenset({"Exif.Photo.ISOSpeedRatings"})
#: What exiv2 makes up for a CRW (its CrwMap) rather than reads: skipped there, in
#: favour of Canon's own codes (:data:`_CANON`).
_CRW_MADE_UP = frozenset({"Exif.Photo.ExposureTime", "Exif.Photo.FNumber"})
_CRW_MIME = "image/x-canon-crw"
#: Descriptions some raws carry in ImageDescription that describe nothing (a
#: firmware's placeholder): dropped.
_EMPTY_DESCRIPTIONS = ("", "OLYMPUS DIGITAL CAMERA", "SONY DSC", "DCIM")


@dataclass(frozen=True)
class PhotoMetadata:
    """EXIF fields (standard key → exiv2's text form of the value, which it parses
    back to the tag's type) in :data:`FIELDS` order then GPS, and the XMP packet."""

    exif: tuple[tuple[str, str], ...] = ()
    xmp: str = ""
    source: str = field(default="", compare=False)

    def __bool__(self) -> bool:
        return bool(self.exif or self.xmp)

    def get(self, key: str) -> str | None:
        """The value of EXIF ``key``, or None."""
        return dict(self.exif).get(key)

    def summary(self) -> dict[str, str]:
        """Tag name → value (exiv2's human-readable form), for ``rawsim info`` and sidecars."""

        data = self._exif_data()
        return {d.tagName(): _shown(d, data) for d in data}

    def _exif_data(self, output: Output | None = None):
        """exiv2's ExifData of the fields; for an ``output``, also the tags EXIF
        requires of it (version, resolution, ColorSpace: 1 sRGB, else uncalibrated;
        but for TIFF, the pixel size; for JPEG its YCbCr layout), its Orientation
        and its Software."""
        import exiv2

        data = exiv2.ExifData()
        for key, value in self.exif:
            data[key] = value
        if output is not None:
            for key, value in _OUTPUT_TAGS + (_JPEG_TAGS if output.fmt == "jpg" else ()):
                data[key] = value
            if output.fmt not in ("tiff", "dng"):  # these have ImageWidth and ImageLength
                data["Exif.Photo.PixelXDimension"] = str(output.width)
                data["Exif.Photo.PixelYDimension"] = str(output.height)
            if output.fmt != "dng":  # a raw's colours are the camera's
                data["Exif.Photo.ColorSpace"] = "1" if output.srgb else "65535"
            data["Exif.Image.Orientation"] = str(output.orientation)
            data[SOFTWARE_KEY] = output.software
        return data


def _shown(datum, data) -> str:
    """exiv2's human-readable form of a value; an f-number to one decimal, as exiftool
    and cameras show it (exiv2's two significant figures make f/22.6 "F23")."""
    if datum.key() == "Exif.Photo.FNumber" and datum.count() == 1:
        f = datum.toFloat(0)
        if f > 0:
            return f"F{f:.1f}".removesuffix(".0")
    return datum.print(data)


@dataclass(frozen=True)
class Output:
    """What an output's own EXIF tags say: its Software, format (``png``, ``tiff``,
    ``jpg``, ``exr``, ``dng``), pixel size, and whether it is sRGB."""

    software: str
    fmt: str
    width: int
    height: int
    srgb: bool = True
    orientation: int = 1  # rawsim rotates what it renders; embedded previews keep the raw's


def read_metadata(path: str | Path, libraw: bool = True) -> PhotoMetadata:
    """The photo metadata of a raw or image file (see the module doc); empty where the
    file has none or neither exiv2 nor (if ``libraw``: for raws) LibRaw can read any."""
    import exiv2

    from rawsim.io.clibs import openable_name

    try:
        with openable_name(path) as name:  # exiv2 takes UTF-8 names only
            image = exiv2.ImageFactory.open(name)
            image.readMetadata()
    except exiv2.Exiv2Error:
        return _from_libraw(path) if libraw else PhotoMetadata()
    data = image.exifData()
    crw = image.mimeType() == _CRW_MIME
    fields: list[tuple[str, str]] = []
    for key, sources in FIELDS.items():
        if crw and key == "Exif.Photo.DateTimeOriginal":
            value = _crw_capture_time(path)
        else:
            value = _first(data, key, sources, crw)
        if value is not None:
            fields.append((key, value))
    fields += [
        (d.key(), d.toString())
        for d in data
        if d.key().startswith(GPS_GROUP) and d.key() != "Exif.GPSInfo.GPSTag"
    ]
    xmp = image.xmpPacket() if image.xmpData().count() else ""
    return PhotoMetadata(tuple(fields), xmp or "", str(path))


def _first(data, key: str, sources: tuple[str, ...], crw: bool = False) -> str | None:
    """The first usable value of field ``key`` among ``sources`` (see :data:`FIELDS`),
    as text; in a CRW (``crw``) not what exiv2 makes up (:data:`_CRW_MADE_UP`)."""
    for source in sources:
        if crw and source in _CRW_MADE_UP:
            continue
        found = _find(data, source)
        if found is None:
            continue
        standard = source.split(".")[1] in ("Image", "Photo")
        if source in _CANON:
            value = _CANON[source](data, found, crw)
        else:
            # maker-note values (lens codes) read best as exiv2 prints them
            value = found.toString() if standard else found.print(data)
        value = None if value is None else value.strip().strip("\0").strip()
        if value is not None and _usable(key, source, value, standard):
            return value
    return None


def _usable(key: str, source: str, value: str, standard: bool) -> bool:
    """Whether a value of field ``key`` read from ``source`` carries information: not
    empty, not a zero where zero means unknown (:data:`_ZERO_UNKNOWN`), not a
    placeholder description, a positive number where a number is due, and from maker
    notes not a code exiv2 cannot name."""
    if not value or value in ("0/0", "(0)", "n/a") or value.startswith("Unknown"):
        return False
    if key in _ZERO_UNKNOWN and _all_zero(value):
        return False
    if source.endswith("ImageDescription") and value.upper() in _EMPTY_DESCRIPTIONS:
        return False
    if key in _NUMBERS:
        return _number(value) is not None
    return standard or source in _CANON or not (value[0] == "(" or value.isdigit())


def _all_zero(value: str) -> bool:
    """Whether every number of an EXIF value's text (``0``, ``0/10``, ``0/1 0/1``) is 0."""
    parts = value.split()
    return all(p.partition("/")[0].strip("+-").strip("0.") == "" for p in parts)


def _number(value: str) -> float | None:
    """A positive finite number written as ``x`` or ``n/d``, else None."""
    head, _, tail = value.partition("/")
    try:
        x = float(head) / float(tail) if tail else float(head)
    except (ValueError, ZeroDivisionError):
        return None
    return x if 0 < x < float("inf") else None


# ------------------------------------------------------------------ Canon's codes
def _int16(datum, i: int) -> int | None:
    """Element ``i`` of a maker-note array exiv2 holds as unsigned shorts, as the
    signed number Canon wrote; None where the array is shorter."""
    if datum.count() <= i:
        return None
    v = int(datum.toInt64(i))
    return v - 0x10000 if v >= 0x8000 else v


def _find(data, key: str):
    """exiv2's datum of ``key`` in ``data``, or None."""
    import exiv2

    found = data.findKey(exiv2.ExifKey(key))
    return None if found == data.end() else found


def _canon_ev(code: int) -> float:
    """Canon's EV code (1/32 EV, with 0x0c and 0x14 for 1/3 and 2/3), as exiftool's
    ``CanonEv``."""
    sign, code = (-1, -code) if code < 0 else (1, code)
    frac = code & 0x1F
    whole = code - frac
    thirds = {0x0C: 32 / 3, 0x14: 64 / 3}.get(frac, frac)
    return sign * (whole + thirds) / 32


def _canon_iso(data, found, crw: bool) -> str | None:
    """exiftool's Canon ISO: CameraSettings' CameraISO where it is a number, else
    ShotInfo's BaseISO × AutoISO / 100, rounded."""
    if found.count() < 1:
        return None
    code = int(found.toInt64(0))  # unsigned: 0x4000 flags an ISO written as a number
    if code >= 0x7FFF:
        return None
    if code & 0x4000:
        return str(code & 0x3FFF)
    if code in _CANON_ISO_CODES:
        return str(_CANON_ISO_CODES[code])
    base = _find(data, "Exif.CanonSi.ISOSpeed")
    auto = _find(data, "Exif.CanonSi.AutoISO")
    base = None if base is None else _int16(base, 0)
    auto = None if auto is None else _int16(auto, 0)
    if not base or auto is None:
        return None
    iso = 2 ** (base / 32) * 100 / 32 * 2 ** (auto / 32)
    return f"{iso:.0f}"


_CANON_ISO_CODES = {16: 50, 17: 100, 18: 200, 19: 400, 20: 800}


def _canon_exposure(data, found, crw: bool) -> str | None:
    """A CRW's exposure time from ShotInfo's code (a signed 1/32 EV; 0 is 1 s in a
    CRW, as exiftool takes it), as a camera writes it: 1/N below 1/4 s, else tenths."""
    code = _int16(found, 0)
    if not crw or code is None:
        return None  # other files' EXIF has it; their 0 means "not recorded"
    seconds = 2 ** -_canon_ev(code)
    if seconds < 0.25001:
        return f"1/{round(1 / seconds)}"
    return _fraction(round(seconds * 10), 10)


def _canon_aperture(data, found, crw: bool) -> str | None:
    """A CRW's f-number from ShotInfo's code (1/32 EV of Av; 0: not recorded), to two
    significant figures as exiftool prints it."""
    code = _int16(found, 0)
    if not crw or not code:
        return None
    f = float(f"{2 ** (_canon_ev(code) / 2):.2g}")
    return _fraction(round(f * 10), 10)


def _canon_focal_length(data, found, crw: bool) -> str | None:
    """Canon's FocalLength record's focal length over CameraSettings' FocalUnits (per mm)."""
    focal = _int16(found, 1)
    units = _find(data, "Exif.CanonCs.FocalUnits")
    units = (None if units is None else _int16(units, 0)) or 1
    if not focal or focal < 0 or units < 0:
        return None
    return _fraction(focal, units)


def _fraction(n: int, d: int) -> str:
    from math import gcd

    g = gcd(n, d) or 1
    return f"{n // g}/{d // g}"


#: Maker-note sources held as Canon's raw codes: source key → decoder
#: ``(exif data, datum, crw) → text or None``, each as exiftool decodes it.
_CANON = {
    "Exif.CanonCs.ISOSpeed": _canon_iso,
    "Exif.CanonSi.ShutterSpeedValue": _canon_exposure,
    "Exif.CanonSi.ApertureValue": _canon_aperture,
    "Exif.Canon.FocalLength": _canon_focal_length,
}


def _crw_capture_time(path: str | Path) -> str | None:
    """A CRW's capture time: its CIFF TimeStamp record (0x180e: seconds since 1970 of
    the camera's clock, local time), as exiftool and LibRaw read it, in UTC terms.
    (exiv2 converts it to the reading machine's time zone.) None if absent or 0."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
            if len(head) < 14 or head[6:14] != b"HEAPCCDR":
                return None
            order = {b"II": "<", b"MM": ">"}.get(head[:2])
            if order is None:
                return None
            (start,) = struct.unpack(order + "I", head[2:6])
            fh.seek(0, 2)
            size = fh.tell()
            stamp = _ciff_find(fh, order, start, size - start, 0x180E, depth=0)
    except OSError:
        return None
    if not stamp:
        return None
    import datetime

    when = datetime.datetime(1970, 1, 1) + datetime.timedelta(seconds=stamp)
    return when.strftime("%Y:%m:%d %H:%M:%S")


def _ciff_find(fh, order: str, start: int, length: int, tag: int, depth: int) -> int | None:
    """The first 32-bit value of CIFF record ``tag`` in the heap at ``start``
    (``length`` bytes) or the heaps below it; None if absent."""
    if depth > 8 or length < 6:
        return None
    fh.seek(start + length - 4)
    (table,) = struct.unpack(order + "I", fh.read(4))
    if table + 2 > length:
        return None
    fh.seek(start + table)
    (count,) = struct.unpack(order + "H", fh.read(2))
    entries = fh.read(10 * count)
    if len(entries) < 10 * count:
        return None
    for i in range(count):
        kind, size, offset = struct.unpack(order + "HII", entries[10 * i : 10 * i + 10])
        if (kind & 0x3FFF) == tag:
            if kind & 0x4000:  # the value sits in the entry itself
                return size
            if size < 4 or offset + 4 > length:
                return None
            fh.seek(start + offset)
            return struct.unpack(order + "I", fh.read(4))[0]
        if kind & 0x3800 in (0x2800, 0x3000) and offset + size <= length:  # a heap
            found = _ciff_find(fh, order, start + offset, size, tag, depth + 1)
            if found is not None:
                return found
    return None


def _from_libraw(path: str | Path) -> PhotoMetadata:
    """What LibRaw reports, for files exiv2 cannot read (e.g. Apple QuickTake)."""
    import rawpy

    from rawsim.io.clibs import collected_stderr, openable_name

    try:
        with collected_stderr([]), openable_name(Path(path)) as name, rawpy.imread(name) as raw:
            other = raw.other
    except (rawpy.LibRawError, OSError):
        return PhotoMetadata()
    fields = []
    if other.iso_speed > 0:
        fields.append(("Exif.Photo.ISOSpeedRatings", f"{other.iso_speed:g}"))
    if other.shutter_speed > 0:
        fields.append(("Exif.Photo.ExposureTime", _rational(other.shutter_speed)))
    if other.aperture > 0:
        fields.append(("Exif.Photo.FNumber", _rational(other.aperture)))
    if other.focal_length > 0:
        fields.append(("Exif.Photo.FocalLength", _rational(other.focal_length)))
    if other.timestamp.timestamp() > 0:  # LibRaw's 0 is "unknown"
        stamp = other.timestamp.strftime("%Y:%m:%d %H:%M:%S")
        fields.append(("Exif.Photo.DateTimeOriginal", stamp))
    if other.artist.strip("\0 "):
        fields.append(("Exif.Image.Artist", other.artist.strip("\0 ")))
    order = list(FIELDS)
    fields.sort(key=lambda kv: order.index(kv[0]))
    return PhotoMetadata(tuple(fields), "", str(path))


def _rational(x: float) -> str:
    """A positive float as an exact-enough EXIF rational (1/N for short exposures)."""
    from fractions import Fraction

    if x < 1:
        denominator = round(1 / x)
        if abs(1 / denominator - x) <= 1e-6 * x:
            return f"1/{denominator}"
    f = Fraction(x).limit_denominator(100000)
    return f"{f.numerator}/{f.denominator}"


# ------------------------------------------------------------------ writing
#: A 1×1 grey PNG: exiv2 encodes EXIF into its eXIf chunk, which :func:`exif_block` keeps.
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


_TINY_PNG = (
    _PNG_SIGNATURE
    + _png_chunk(b"IHDR", struct.pack(">2IBBBBB", 1, 1, 8, 0, 0, 0, 0))
    + _png_chunk(b"IDAT", zlib.compress(b"\0\0"))
    + _png_chunk(b"IEND", b"")
)


def exif_block(meta: PhotoMetadata, output: Output) -> bytes:
    """The EXIF of ``meta`` for ``output`` (see :meth:`PhotoMetadata._exif_data`) as
    exiv2 encodes it: a TIFF structure (byte-order header, IFD0, Exif and GPS IFDs;
    offsets from its first byte), the body of a PNG ``eXIf`` chunk."""
    import exiv2

    image = exiv2.ImageFactory.open(_TINY_PNG)
    image.setExifData(meta._exif_data(output))
    image.writeMetadata()
    io = image.io()
    data = bytes(io.mmap())
    io.munmap()
    at = len(_PNG_SIGNATURE)
    while at < len(data):
        (size,) = struct.unpack(">I", data[at : at + 4])
        if data[at + 4 : at + 8] == b"eXIf":
            return data[at + 8 : at + 8 + size]
        at += 12 + size
    raise RuntimeError("exiv2 wrote no eXIf chunk")  # exiv2 always writes one for EXIF data


def xmp_without(packet: str, groups: tuple[str, ...]) -> str:
    """The XMP ``packet`` less the properties of the namespaces ``groups`` (prefixes
    as exiv2 names them: ``"crs"``, ``"tiff"``, …), re-encoded by exiv2; ``""`` when
    nothing is left."""
    import exiv2

    if not packet:
        return ""
    image = exiv2.ImageFactory.open(_TINY_PNG)
    image.setXmpPacket(packet)
    image.writeMetadata()
    image.readMetadata()
    prefixes = tuple(f"Xmp.{g}." for g in groups)
    kept = exiv2.XmpData()
    for datum in image.xmpData():
        if not datum.key().startswith(prefixes):
            kept[datum.key()] = datum.value()
    if not kept.count():
        return ""
    image.setXmpData(kept)
    image.writeMetadata()
    image.readMetadata()
    return image.xmpPacket()


def embed_jpeg(path: str | Path, meta: PhotoMetadata, output: Output) -> None:
    """Write ``meta`` as ``output``'s EXIF (see :meth:`PhotoMetadata._exif_data`) and its
    XMP into the JPEG at ``path`` with exiv2, which keeps the file's other segments
    (its ICC profile)."""
    import exiv2

    image = exiv2.ImageFactory.open(str(path))
    image.readMetadata()
    image.setExifData(meta._exif_data(output))
    if meta.xmp:
        image.setXmpPacket(meta.xmp)
    image.writeMetadata()


#: EXIF key → OpenEXR standard attribute (name, kind): ``str``, ``float``, or ``date``.
_EXR_ATTRIBUTES = {
    "Exif.Image.Make": ("cameraMake", "str"),
    "Exif.Image.Model": ("cameraModel", "str"),
    "Exif.Photo.BodySerialNumber": ("cameraSerialNumber", "str"),
    "Exif.Photo.LensMake": ("lensMake", "str"),
    "Exif.Photo.LensModel": ("lensModel", "str"),
    "Exif.Photo.LensSerialNumber": ("lensSerialNumber", "str"),
    "Exif.Photo.ExposureTime": ("expTime", "float"),
    "Exif.Photo.FNumber": ("aperture", "float"),
    "Exif.Photo.ISOSpeedRatings": ("isoSpeed", "float"),
    "Exif.Photo.FocalLength": ("nominalFocalLength", "float"),
    "Exif.Photo.SubjectDistance": ("focus", "float"),
    "Exif.Image.Copyright": ("owner", "str"),
    "Exif.Image.ImageDescription": ("comments", "str"),
}


#: The capture time: OpenEXR's ``capDate`` and ``utcOffset``, sub-seconds as a string.
_EXR_TIME = ("Exif.Photo.DateTimeOriginal", "Exif.Photo.OffsetTimeOriginal")


def exr_attributes(meta: PhotoMetadata, software: str) -> dict[str, object]:
    """OpenEXR header attributes for ``meta``: the standard ones (OpenEXR's
    ImfStandardAttributes: cameraMake, lensModel, expTime, aperture, isoSpeed,
    capDate, utcOffset, latitude/longitude/altitude, owner (the copyright),
    comments, …), and for
    EXIF fields without one, a string attribute named after the EXIF tag."""

    data = meta._exif_data()
    out: dict[str, object] = {"Software": software}
    for datum in data:
        key = datum.key()
        if key.startswith(GPS_GROUP) or key in _EXR_TIME:
            continue
        name, kind = _EXR_ATTRIBUTES.get(key, (datum.tagName(), "str"))
        out[name] = datum.toFloat(0) if kind == "float" else datum.print(data)
    when = meta.get("Exif.Photo.DateTimeOriginal")
    if when:
        out["capDate"] = when
        offset = meta.get("Exif.Photo.OffsetTimeOriginal")
        if offset and len(offset) == 6 and offset[0] in "+-":
            seconds = int(offset[1:3]) * 3600 + int(offset[4:6]) * 60
            out["utcOffset"] = float(-seconds if offset[0] == "+" else seconds)  # UTC − local
    position = _gps_degrees(data)
    out.update(position)
    if meta.xmp:
        out["xmp"] = meta.xmp
    return {k: v for k, v in out.items() if v not in ("", None)}


def _gps_degrees(data) -> dict[str, float]:
    """latitude, longitude (degrees, north and east positive) and altitude (metres)."""
    out = {}
    for axis, negative in (("Latitude", "S"), ("Longitude", "W")):
        found = _find(data, f"Exif.GPSInfo.GPS{axis}")
        if found is None or found.count() != 3:
            continue
        d, m, s = (found.toFloat(i) for i in range(3))
        ref = _find(data, f"Exif.GPSInfo.GPS{axis}Ref")
        sign = -1.0 if ref is not None and ref.toString().strip() == negative else 1.0
        out[axis.lower()] = sign * (d + m / 60 + s / 3600)
    found = _find(data, "Exif.GPSInfo.GPSAltitude")
    if found is not None:
        ref = _find(data, "Exif.GPSInfo.GPSAltitudeRef")
        below = ref is not None and ref.toInt64(0) == 1
        out["altitude"] = -found.toFloat(0) if below else found.toFloat(0)
    return out
