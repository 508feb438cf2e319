"""The threaded PNG writer against real readers (OpenImageIO, libpng via imagecodecs, Pillow)."""

import imagecodecs
import numpy as np
import OpenImageIO as oiio
import pytest
from PIL import Image

from rawsim.io import png
from rawsim.io.png import write_png


def samples(h, w, c, dtype, seed=0):
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    ramp = np.linspace(0, top, h * w * c).reshape(h, w, c)  # smooth, with noise on it
    return np.clip(ramp + rng.normal(0, top / 50, ramp.shape), 0, top).astype(dtype)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
@pytest.mark.parametrize("shape", [(1, 1), (3, 5), (png.BAND_ROWS * 2 + 7, 33)])
def test_readers_get_the_samples_back(tmp_path, dtype, channels, shape):
    data = samples(*shape, channels, dtype)
    path = tmp_path / "x.png"
    write_png(path, data, srgb=channels >= 3, attributes={"Software": "rawsim test"})
    decoded = imagecodecs.png_decode(path.read_bytes())
    assert np.array_equal(decoded.reshape(data.shape), data)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # alpha as written, not premultiplied
    buf = oiio.ImageBuf(str(path), 0, 0, config)
    assert not buf.has_error, buf.geterror()
    pixels = buf.get_pixels(oiio.UINT8 if dtype == np.uint8 else oiio.UINT16)
    assert np.array_equal(pixels.reshape(data.shape), data)
    assert buf.spec().get_string_attribute("Software") == "rawsim test"
    if dtype == np.uint8:  # Pillow reads 16-bit colour as 8-bit
        with Image.open(path) as image:
            assert np.array_equal(np.asarray(image).reshape(data.shape), data)


def test_average_filter_by_hand():
    # one row, two RGB pixels, nothing above: the first pixel as is, the second less
    # ⌊left / 2⌋; the second row less ⌊(left + above) / 2⌋, modulo 256
    data = np.array([[[10, 200, 255], [20, 100, 0]], [[30, 0, 7], [40, 60, 9]]], np.uint8)
    rows = png.filtered_rows(png._big_endian_bytes(data), 0, 2, 3)
    assert rows.tolist() == [
        [3, 10, 200, 255, 15, 0, 129],
        [3, 25, 156, 136, 15, 10, 6],
    ]


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_bands_filter_as_the_whole_image(dtype):
    data = samples(png.BAND_ROWS + 5, 9, 2, dtype)
    raw = png._big_endian_bytes(data)
    step = 2 * data.dtype.itemsize
    whole = png.filtered_rows(raw, 0, len(raw), step)
    first = png.filtered_rows(raw, 0, png.BAND_ROWS, step)
    bands = [first, png.filtered_rows(raw, png.BAND_ROWS, len(raw), step)]
    assert np.array_equal(np.concatenate(bands), whole)


def test_srgb_tag_reads_as_openimageio_own(tmp_path):
    data = samples(16, 16, 3, np.uint8)
    write_png(tmp_path / "ours.png", data, srgb=True)
    spec = oiio.ImageSpec(16, 16, 3, oiio.UINT8)
    spec.attribute("oiio:ColorSpace", "sRGB")
    out = oiio.ImageOutput.create(str(tmp_path / "theirs.png"))
    assert out.open(str(tmp_path / "theirs.png"), spec) and out.write_image(data)
    out.close()
    space = [
        oiio.ImageBuf(str(tmp_path / name)).spec().get_string_attribute("oiio:ColorSpace")
        for name in ("ours.png", "theirs.png")
    ]
    assert space[0] == space[1]
    write_png(tmp_path / "linear.png", data, srgb=False)
    assert b"sRGB" not in (tmp_path / "linear.png").read_bytes()[:100]


def test_bytes_do_not_depend_on_threads(tmp_path):
    data = samples(png.BAND_ROWS * 3 + 1, 40, 3, np.uint16)
    files = []
    for threads in (1, 2, 3, 8):
        write_png(tmp_path / f"{threads}.png", data, threads=threads)
        files.append((tmp_path / f"{threads}.png").read_bytes())
    assert all(f == files[0] for f in files)


def test_refuses_what_png_cannot_hold(tmp_path):
    with pytest.raises(ValueError, match="PNG takes"):
        write_png(tmp_path / "x.png", np.zeros((2, 2, 3), np.float32))
    with pytest.raises(ValueError, match="PNG takes"):
        write_png(tmp_path / "x.png", np.zeros((2, 2, 5), np.uint8))
