"""Decoding images for unprocessing: strip-wise reads against OpenImageIO's own
whole-image read, on real files and on files of several strips, and unprocessing
while decoding against unprocessing the decoded image."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
import tifffile

from rawsim.batch import Task
from rawsim.errors import UnsupportedInputError
from rawsim.io.images import STRIP_ROWS, even_rgb, read_image
from rawsim.pipelines.unprocess import Simulation, UnprocessOptions, _pack, simulate, unprocess_file
from rawsim.profiles import load_profile
from tests.conftest import DATA


def _openimageio_samples(path):
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    base = spec.format.basetype
    fmt = base if base in (oiio.UINT8, oiio.UINT16) else oiio.FLOAT
    pixels = inp.read_image(0, 0, 0, spec.nchannels, fmt)
    inp.close()
    return even_rgb(np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels))


def _tall(tmp_path, name, width=90, **attributes):
    """A real photo stretched to more than two strips (an odd number of rows),
    written as ``name``."""
    rows = 2 * STRIP_ROWS + 37
    buf = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "srgb" / "coffee.png")), roi=oiio.ROI(0, width, 0, rows)
    )
    for key, value in attributes.items():
        buf.specmod().attribute(key, value)
    path = tmp_path / name
    assert buf.write(str(path)), oiio.geterror()
    return path


@pytest.mark.parametrize(
    "name",
    [
        "srgb/rocket.jpg",
        "srgb/coffee.png",
        "srgb16/painted_figure_16bit.tif",
        "exr/img2601_float_zip.exr",
    ],
)
def test_strip_reads_give_openimageios_samples(name):
    path = DATA / name
    assert np.array_equal(read_image(path).pixels, _openimageio_samples(path))


@pytest.mark.parametrize("name", ["tall.jpg", "tall.png", "tall.exr"])
def test_files_of_several_strips_read_whole(tmp_path, name):
    path = _tall(tmp_path, name)
    pixels = read_image(path).pixels
    assert pixels.shape[0] > 2 * STRIP_ROWS
    assert np.array_equal(pixels, _openimageio_samples(path))


def test_tiled_files_read_whole(tmp_path):
    path = tmp_path / "tiled.tif"
    samples = np.random.default_rng(1).integers(0, 65535, (600, 200, 3), dtype=np.uint16)
    tifffile.imwrite(path, samples, tile=(64, 64), photometric="rgb")
    assert np.array_equal(read_image(path).pixels, samples)


def test_a_file_cut_after_its_first_strips_is_refused(tmp_path):
    path = _tall(tmp_path, "cut.png")
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.8)])
    with pytest.raises(UnsupportedInputError, match="cut.png: "):
        read_image(path)


@pytest.mark.parametrize(
    "name,attributes",
    [
        ("tall.jpg", {}),  # streamed: the engine runs each band as it is decoded
        ("tall.png", {"oiio:BitsPerSample": 16}),  # streamed, 16-bit codes
        ("tall.tif", {"tiff:planarconfig": "separate"}),
        ("odd.png", {"width": 91}),  # cropped to an even width: simulated once decoded
    ],
)
def test_unprocessing_while_decoding_gives_the_mosaics_of_the_decoded_image(
    tmp_path, name, attributes
):
    path = _tall(tmp_path, name, **attributes)
    options = UnprocessOptions(profile=load_profile("sony_a7s2"), iso=3200, clean=True)
    task = Task(path, name, {"npz": tmp_path / "o.npz", "json": tmp_path / "o.json"}, 11)
    unprocess_file(task, options)
    decoded = read_image(path)
    assert decoded.pixels.shape[0] % 2 == 0 and decoded.pixels.shape[0] > 2 * STRIP_ROWS
    expected = simulate(options.make_sensor(), decoded.pixels, options, 11, engine=True)
    got = np.load(tmp_path / "o.npz")
    cfa = options.profile.cfa
    for field, mosaic in (("mosaic", expected.noisy), ("clean", expected.clean)):
        assert np.array_equal(got[field], _pack(cfa, Simulation.codes(mosaic)))


def test_a_file_cut_while_unprocessing_is_refused_and_writes_nothing(tmp_path):
    path = _tall(tmp_path, "cut.jpg")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    options = UnprocessOptions(profile=load_profile("sony_a7s2"), iso=3200)
    task = Task(path, "cut.jpg", {"dng": tmp_path / "o.dng", "json": tmp_path / "o.json"}, 11)
    with pytest.raises(UnsupportedInputError, match="cut.jpg: "):
        unprocess_file(task, options)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.jpg"]
