"""Fast previews: ``--thumbnail`` (the raw's embedded preview) and ``--resize``."""

import json
import shutil

import exiv2
import numpy as np
import OpenImageIO as oiio
import pytest
from click.testing import CliRunner

from rawsim.io.images import resize_samples
from rawsim.isp.config import DemosaicStage
from rawsim_cli.main import cli
from tests.conftest import DATA


@pytest.fixture(scope="module")
def raw_with_preview(tmp_path_factory):
    """The Canon DNG with a JPEG preview in its EXIF (IFD1, where LibRaw finds it) and
    Orientation 6; (path, the preview's pixels)."""
    folder = tmp_path_factory.mktemp("preview")
    path = folder / "previewed.dng"
    shutil.copy(DATA / "raw" / "canon_eos60d_mlv.dng", path)
    y, x = np.mgrid[0:120, 0:160]
    pixels = np.stack([x * 1.5, y * 2.0, (x + y) % 50 * 5], -1).astype(np.uint8)
    oiio.ImageBuf(pixels).write(str(folder / "preview.jpg"))
    image = exiv2.ImageFactory.open(str(path))
    image.readMetadata()
    data = image.exifData()
    data["Exif.Image.Orientation"] = "6"
    exiv2.ExifThumb(data).setJpegThumbnail((folder / "preview.jpg").read_bytes())
    image.writeMetadata()
    return path, oiio.ImageBuf(str(folder / "preview.jpg")).get_pixels(oiio.UINT8)


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_thumbnail_is_the_embedded_jpeg_with_metadata(raw_with_preview, tmp_path):
    path, pixels = raw_with_preview
    done = _run("process", path, "-o", tmp_path, "--thumbnail")
    assert done.exit_code == 0, done.output
    out = tmp_path / "previewed.jpg"
    assert np.array_equal(oiio.ImageBuf(str(out)).get_pixels(oiio.UINT8), pixels)  # not re-encoded
    read = exiv2.ImageFactory.open(str(out))
    read.readMetadata()
    exif = {d.key(): d.toString() for d in read.exifData()}
    assert exif["Exif.Image.Make"] == "Canon" and exif["Exif.Photo.ExposureTime"] == "6/1000"
    assert exif["Exif.Image.Orientation"] == "6"  # the preview is stored unrotated
    side = json.loads((tmp_path / "previewed.process.json").read_text())
    assert side["thumbnail"] and (side["width"], side["height"]) == (160, 120)


def test_thumbnail_resized_and_bitmap_previews(raw_with_preview, tmp_path):
    done = _run("process", raw_with_preview[0], "-o", tmp_path, "--thumbnail", "--resize", "80")
    assert done.exit_code == 0, done.output
    spec = oiio.ImageInput.open(str(tmp_path / "previewed.jpg")).spec()
    assert (spec.width, spec.height) == (80, 60)
    kodak = _run("process", DATA / "raw" / "kodak_dc50_grbg.kdc", "-o", tmp_path, "--thumbnail")
    assert kodak.exit_code == 0, kodak.output  # a 96 × 64 bitmap, encoded as JPEG
    spec = oiio.ImageInput.open(str(tmp_path / "kodak_dc50_grbg.jpg")).spec()
    assert (spec.width, spec.height) == (96, 64)


def test_no_preview_is_one_clear_line(tmp_path):
    done = _run(
        "process", DATA / "raw" / "synthetic_colorchecker_bggr.dng", "-o", tmp_path, "--thumbnail"
    )
    assert done.exit_code == 1
    assert "holds no embedded preview; render it without --thumbnail" in done.output
    assert "Traceback" not in done.output
    bad = _run(
        "process",
        DATA / "raw" / "canon_eos60d_mlv.dng",
        "-o",
        tmp_path,
        "--thumbnail",
        "--format",
        "tiff",
    )
    assert bad.exit_code == 2 and "--format jpg" in bad.output


def test_resize(tmp_path):
    path = DATA / "raw" / "canon_eos60d_mlv.dng"
    done = _run("process", path, "-o", tmp_path, "--resize", "300", "--format", "tiff")
    assert done.exit_code == 0, done.output
    spec = oiio.ImageInput.open(str(tmp_path / "canon_eos60d_mlv.tif")).spec()
    assert (spec.width, spec.height) == (300, 169)
    side = json.loads((tmp_path / "canon_eos60d_mlv.process.json").read_text())
    demosaic = next(s for s in side["config"] if s["name"] == "demosaic")
    assert side["resize"] == 300 and demosaic["method"] == "half"  # 300 ≤ 960 / 2
    done = _run("process", path, "-o", tmp_path / "b", "--resize", "600")
    side = json.loads((tmp_path / "b" / "canon_eos60d_mlv.process.json").read_text())
    demosaic = next(s for s in side["config"] if s["name"] == "demosaic")
    assert demosaic["method"] == DemosaicStage().method  # the default, at full size


def test_resize_is_antialiased_and_keeps_small_images():
    checker = ((np.indices((400, 600)).sum(0) % 2) * 65535).astype(np.uint16)
    small = resize_samples(np.repeat(checker[..., None], 3, 2), 150)
    assert small.shape == (100, 150, 3) and small.dtype == np.uint16
    assert abs(float(small.mean()) - 32767.5) < 200 and float(small.std()) < 300  # no moiré
    image = np.zeros((10, 20, 3), np.uint8)
    assert resize_samples(image, 20) is image
