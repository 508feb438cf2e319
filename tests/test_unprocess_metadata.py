"""unprocess DNGs keep the input photo's metadata (EXIF, GPS, XMP), with the
simulated camera, ISO and lens, read back by exiftool, python-exiv2 and LibRaw."""

import shutil
from dataclasses import replace

import exiv2
import pytest
import rawpy
from click.testing import CliRunner

from rawsim.cfa import CFA
from rawsim.io.dng import DngInfo, dng_metadata
from rawsim.io.lensfun import lens_params
from rawsim.io.metadata import read_metadata
from rawsim_cli.main import cli
from tests.conftest import DATA
from tests.test_metadata import EXIFTOOL, FIELDS, XMP, _exiftool, tag_file

#: What the DNG says instead of the photo's: the sony_a7s2 profile's camera, the ISO run.
CAMERA = {"Make": "Sony", "Model": "ILCE-7SM2", "ISO": 1600}
#: The photo's fields that describe its camera and lens: not in the DNG.
DEVICE = {"SerialNumber", "LensMake", "LensModel"}


@pytest.fixture(scope="module")
def tagged_photo(tmp_path_factory):
    """A JPEG carrying every field, an XMP packet and a raw developer's settings."""
    path = tmp_path_factory.mktemp("photo") / "harbour.jpg"
    shutil.copyfile(DATA / "srgb" / "rocket.jpg", path)
    return tag_file(path, {**XMP, "Xmp.crs.Exposure2012": "+0.50", "Xmp.tiff.Make": "x"})


def _unprocess(photo, out, *flags):
    done = CliRunner().invoke(
        cli,
        ["unprocess", str(photo), "-o", str(out), "--profile", "sony_a7s2", "--iso", "1600",
         "--clean", *flags],
    )  # fmt: skip
    assert done.exit_code == 0, done.output
    return out / "harbour.dng", out / "harbour.clean.dng"


def test_dng_keeps_the_photos_fields(tagged_photo, tmp_path):
    noisy, clean = _unprocess(tagged_photo, tmp_path)
    source = _exiftool(tagged_photo)
    assert all(k in source for k in EXIFTOOL)  # the photo really carries every field
    for dng in (noisy, clean):
        ours = _exiftool(dng)
        expected = {k: source[k] for k in EXIFTOOL if k not in DEVICE} | CAMERA
        assert {k: ours.get(k) for k in expected} == expected
        assert not DEVICE & set(ours)
        # python-exiv2 reads the kept EXIF with its exact values, and the kept XMP
        read = exiv2.ImageFactory.open(str(dng))
        read.readMetadata()
        exif = {d.key(): d.toString() for d in read.exifData()}
        for key, value in FIELDS.items():
            if key.split(".")[-1] in ("Make", "Model", "ISOSpeedRatings") or "Serial" in key:
                continue
            if "Lens" in key:
                assert key not in exif
                continue
            canonical = exiv2.ExifData()
            canonical[key] = value
            assert exif[key] == next(iter(canonical)).toString(), key
        assert exif["Exif.Photo.ISOSpeed"] == "1600"
        assert exif["Exif.Image.DateTime"] == FIELDS["Exif.Photo.DateTimeOriginal"]
        assert exif["Exif.Image.Software"].startswith("rawsim ")
        xmp = {d.key(): d.toString() for d in read.xmpData()}
        assert xmp["Xmp.xmp.Rating"] == "4" and "Jane Doe" in xmp["Xmp.dc.creator"]
        assert not [k for k in xmp if k.startswith(("Xmp.crs.", "Xmp.tiff."))]
    with rawpy.imread(str(noisy)) as raw:  # LibRaw reads them from the DNG too
        assert raw.other.iso_speed == 1600
        assert raw.other.artist.strip("\0 ") == FIELDS["Exif.Image.Artist"]
        assert (
            raw.other.timestamp.strftime("%Y:%m:%d %H:%M:%S")
            == (FIELDS["Exif.Photo.DateTimeOriginal"])
        )
        assert raw.raw_image.shape == (426, 640)


def test_process_carries_them_on(tagged_photo, tmp_path):
    """unprocess then process: the render says what the photo said (and the DNG's camera)."""
    noisy, _ = _unprocess(tagged_photo, tmp_path / "dng")
    done = CliRunner().invoke(cli, ["process", str(noisy), "-o", str(tmp_path), "--format", "tiff"])
    assert done.exit_code == 0, done.output
    ours = _exiftool(tmp_path / "harbour.tif")
    assert ours["GPSLatitude"] == _exiftool(tagged_photo)["GPSLatitude"]
    assert (ours["Artist"], ours["Model"], ours["ISO"]) == ("Jane Doe", "ILCE-7SM2", 1600)


def test_strip_metadata(tagged_photo, tmp_path):
    noisy, clean = _unprocess(tagged_photo, tmp_path, "--strip-metadata")
    for dng in (noisy, clean):
        ours = _exiftool(dng)
        assert {k: ours[k] for k in ours if k in EXIFTOOL} == CAMERA
        assert read_metadata(dng).xmp == ""
        with rawpy.imread(str(dng)) as raw:
            assert raw.other.iso_speed == 1600 and raw.other.timestamp.timestamp() <= 0


def test_lens_tags():
    """The simulated lens replaces the photo's lens, focal length and aperture."""
    photo = read_metadata(DATA / "srgb" / "rocket.jpg")
    name, camera = "Canon EF-S 18-55mm f/3.5-5.6 IS STM", "Canon EOS 70D"
    lens, _ = lens_params(name, 18, 5.6, None, "Canon", camera)
    identity = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    info = DngInfo(
        CFA("RGGB"), 0, 16383, identity, (1, 1, 1), "Canon", camera, camera, 400,
        metadata=photo, lens=lens,
    )  # fmt: skip
    fields = dict(dng_metadata(info).exif)
    assert fields["Exif.Photo.LensModel"] == "Canon EF-S 18-55mm f/3.5-5.6 IS STM"
    assert fields["Exif.Photo.LensMake"] == "Canon"
    assert fields["Exif.Photo.FocalLength"] == "18/1"
    assert fields["Exif.Photo.FNumber"] == "28/5"
    assert fields["Exif.Photo.FocalLengthIn35mmFilm"] == str(round(18 * lens.crop_factor))
    assert fields["Exif.Photo.ISOSpeedRatings"] == "400"
    no_aperture = replace(info, lens=replace(lens, aperture=None))
    assert "Exif.Photo.FNumber" not in dict(dng_metadata(no_aperture).exif)
