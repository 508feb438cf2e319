"""Photo metadata carried from a raw into every output format, read back by exiftool
(the reference reader) and python-exiv2."""

import json
import subprocess

import exiv2
import numpy as np
import pytest
import tifffile
from click.testing import CliRunner

from rawsim.cfa import CFA
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.metadata import PhotoMetadata, read_metadata
from rawsim_cli.main import cli
from tests.conftest import DATA, require_tool

#: Every field the issue names (standard EXIF keys), GPS included, in the raw.
FIELDS = {
    "Exif.Image.Make": "Fujifilm",
    "Exif.Image.Model": "X-T3",
    "Exif.Photo.BodySerialNumber": "93A51234",
    "Exif.Photo.LensMake": "Fujifilm",
    "Exif.Photo.LensModel": "XF18-55mmF2.8-4 R LM OIS",
    "Exif.Photo.DateTimeOriginal": "2024:06:01 18:30:05",
    "Exif.Photo.SubSecTimeOriginal": "250",
    "Exif.Photo.OffsetTimeOriginal": "+02:00",
    "Exif.Photo.ExposureTime": "1/250",
    "Exif.Photo.FNumber": "56/10",
    "Exif.Photo.ISOSpeedRatings": "800",
    "Exif.Photo.ExposureBiasValue": "-2/3",
    "Exif.Photo.FocalLength": "35/1",
    "Exif.Photo.FocalLengthIn35mmFilm": "53",
    "Exif.Photo.Flash": "16",
    "Exif.GPSInfo.GPSVersionID": "2 3 0 0",
    "Exif.GPSInfo.GPSLatitudeRef": "N",
    "Exif.GPSInfo.GPSLatitude": "52/1 31/1 1234/100",
    "Exif.GPSInfo.GPSLongitudeRef": "W",
    "Exif.GPSInfo.GPSLongitude": "13/1 24/1 5/1",
    "Exif.GPSInfo.GPSAltitudeRef": "0",
    "Exif.GPSInfo.GPSAltitude": "345/10",
    "Exif.GPSInfo.GPSProcessingMethod": "charset=Ascii GPS",
    "Exif.Image.Artist": "Jane Doe",
    "Exif.Image.Copyright": "(c) 2024 Jane Doe",
    "Exif.Image.ImageDescription": "Harbour at dusk",
}
XMP = {"Xmp.dc.creator": "Jane Doe", "Xmp.xmp.Rating": "4"}
#: exiftool's names for the fields (its -n numeric values are compared).
EXIFTOOL = (
    "Make Model SerialNumber LensMake LensModel DateTimeOriginal SubSecTimeOriginal "
    "OffsetTimeOriginal ExposureTime FNumber ISO ExposureCompensation FocalLength "
    "FocalLengthIn35mmFormat Flash GPSVersionID GPSLatitudeRef GPSLatitude GPSLongitudeRef "
    "GPSLongitude GPSAltitudeRef GPSAltitude Artist Copyright ImageDescription Creator Rating"
).split()


@pytest.fixture(scope="module")
def tagged_raw(tmp_path_factory):
    """A small X-Trans DNG (Orientation 6) carrying every field and an XMP packet."""
    path = tmp_path_factory.mktemp("meta") / "tagged.dng"
    rng = np.random.default_rng(0)
    mosaic = (512 + rng.random((96, 120)) * 8000).astype(np.uint16)
    info = DngInfo(
        CFA("XTRANS"),
        512,
        16383,
        ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
        (1, 1, 1),
        "x",
        "x",
        "x",
        800,
        orientation=6,
    )
    write_dng(path, mosaic, info)
    return tag_file(path)


def tag_file(path, xmp: dict = XMP):
    """Write every field of :data:`FIELDS` and the ``xmp`` properties into the file at
    ``path`` with exiv2; returns ``path``."""
    image = exiv2.ImageFactory.open(str(path))
    image.readMetadata()
    data = image.exifData()
    for key, value in FIELDS.items():
        data[key] = value
    properties = image.xmpData()
    for key, value in xmp.items():
        properties[key] = value
    image.writeMetadata()
    return path


def _exiftool(path) -> dict:
    out = subprocess.run(
        [require_tool("exiftool"), "-j", "-n", *(f"-{t}" for t in EXIFTOOL), str(path)],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout)[0]


def _render(raw, out, *flags) -> dict:
    done = CliRunner().invoke(cli, ["process", str(raw), "-o", str(out), *flags])
    assert done.exit_code == 0, done.output
    return done


@pytest.mark.parametrize("fmt", ["jpg", "tiff", "png"])
def test_every_field_reaches_the_output(tagged_raw, tmp_path, fmt):
    _render(tagged_raw, tmp_path, "--format", fmt)
    (image,) = [p for p in tmp_path.iterdir() if not p.name.endswith(".json")]
    source, ours = _exiftool(tagged_raw), _exiftool(image)
    expected = {k: source[k] for k in EXIFTOOL}
    assert len(expected) == len(EXIFTOOL)  # the raw really carries every field
    assert {k: ours.get(k) for k in EXIFTOOL} == expected
    # python-exiv2 reads the same EXIF (standard keys, exact values) and XMP
    read = exiv2.ImageFactory.open(str(image))
    read.readMetadata()
    exif = {d.key(): d.toString() for d in read.exifData()}
    for key, value in FIELDS.items():
        canonical = exiv2.ExifData()
        canonical[key] = value
        assert exif[key] == next(iter(canonical)).toString(), key
    assert exif["Exif.Image.Orientation"] == "1"  # the pixels are rotated instead
    assert exif["Exif.Image.Software"].startswith("rawsim ")
    xmp = {d.key(): d.toString() for d in read.xmpData()}
    assert xmp["Xmp.xmp.Rating"] == "4" and "Jane Doe" in xmp["Xmp.dc.creator"]


def test_exr_header_carries_the_fields(tagged_raw, tmp_path):
    _render(tagged_raw, tmp_path, "--format", "exr")
    out = subprocess.run(
        [require_tool("exiftool"), "-j", "-n", str(tmp_path / "tagged.exr")],
        capture_output=True,
        text=True,
        check=True,
    )
    tags = json.loads(out.stdout)[0]
    assert tags["CameraMake"] == "Fujifilm" and tags["CameraModel"] == "X-T3"
    assert tags["CameraSerialNumber"] == "93A51234"
    assert tags["LensModel"] == "XF18-55mmF2.8-4 R LM OIS" and tags["LensMake"] == "Fujifilm"
    assert tags["DateTimeOriginal"].startswith("2024:06:01 18:30:05")
    assert tags["TimeZone"] == -7200  # utcOffset: UTC = local time + offset, for +02:00
    number = {k: float(tags[k]) for k in ("ExposureTime", "Aperture", "ISO", "NominalFocalLength")}
    assert number == pytest.approx(  # OpenEXR's float (single precision) attributes
        {"ExposureTime": 1 / 250, "Aperture": 5.6, "ISO": 800, "NominalFocalLength": 35}, rel=1e-6
    )
    assert tags["Owner"] == "(c) 2024 Jane Doe" and tags["Artist"] == "Jane Doe"
    assert float(tags["GPSLatitude"]) == pytest.approx(52 + 31 / 60 + 12.34 / 3600, rel=1e-6)
    assert float(tags["GPSLongitude"]) == pytest.approx(-(13 + 24 / 60 + 5 / 3600), rel=1e-6)
    assert float(tags["GPSAltitude"]) == pytest.approx(34.5, rel=1e-6)
    assert tags["Comments"] == "Harbour at dusk"
    assert "Jane Doe" in tags["Xmp"] and tags["Software"].startswith("rawsim ")


def test_strip_metadata(tagged_raw, tmp_path):
    _render(tagged_raw, tmp_path, "--format", "jpg", "--strip-metadata")
    tags = _exiftool(tmp_path / "tagged.jpg")
    assert not set(tags) & set(EXIFTOOL) - {"SourceFile"}
    read = exiv2.ImageFactory.open(str(tmp_path / "tagged.jpg"))
    read.readMetadata()
    assert read.xmpData().count() == 0


def test_rendered_tiff_reads_everywhere(tagged_raw, tmp_path):
    """rawsim's own TIFF writer: the pixels as tifffile and OpenImageIO read them, and
    exiftool finds nothing to complain about."""
    import OpenImageIO as oiio

    _render(tagged_raw, tmp_path, "--format", "tiff", "--bits", "16")
    path = tmp_path / "tagged.tif"
    pixels = tifffile.imread(path)
    assert pixels.shape == (120, 96, 3) and pixels.dtype == np.uint16  # rotated
    assert np.array_equal(oiio.ImageBuf(str(path)).get_pixels(oiio.UINT16), pixels)
    out = subprocess.run(
        [require_tool("exiftool"), "-validate", "-warning", "-a", str(path)],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "Validate                        : OK" in out.stdout, out.stdout


def test_reading_old_and_odd_raws():
    """Fields from TIFF/EP places (Kodak DC50), DNG's serial tag, and LibRaw's
    report where exiv2 knows no format (Apple QuickTake: none); never a crash."""
    kodak = read_metadata(DATA / "raw" / "kodak_dc50_grbg.kdc")
    assert kodak.get("Exif.Photo.ExposureTime") == "435/100000"
    assert kodak.get("Exif.Photo.DateTimeOriginal") == "1997:04:23 08:00:47"
    canon = read_metadata(DATA / "raw" / "canon_eos60d_mlv.dng")
    assert canon.get("Exif.Photo.BodySerialNumber") == "21FE1CD5"
    assert canon.get("Exif.Photo.ISOSpeedRatings") == "100"
    assert read_metadata(DATA / "raw" / "apple_quicktake150.qtk") == PhotoMetadata()


def test_info_shows_the_fields_and_the_baseline_exposure(tagged_raw):
    done = CliRunner().invoke(cli, ["info", "--json", str(tagged_raw)])
    assert done.exit_code == 0, done.output
    facts = json.loads(done.output)
    assert facts["metadata"]["LensModel"] == "XF18-55mmF2.8-4 R LM OIS"
    assert facts["metadata"]["ExposureTime"] == "1/250 s"
    assert facts["metadata"]["GPSLatitude"] == "52 deg 31' 12.34\""
    assert facts["baseline_exposure"] == 0.0 and facts["baseline_exposure_applied"] is True
    text = CliRunner().invoke(cli, ["info", str(tagged_raw)])
    assert "    Copyright              (c) 2024 Jane Doe" in text.output
