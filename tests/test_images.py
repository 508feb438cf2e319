"""Decoding images for unprocessing: strip-wise reads against OpenImageIO's own
whole-image read, on real files and on files of several strips."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import OpenImageIO as oiio
import pytest
import tifffile

from rawsim.errors import UnsupportedInputError
from rawsim.io.images import STRIP_BYTES, even_rgb, read_image
from rawsim.io.progress import DecodeProgress
from rawsim.io.spare import Spare
from tests.conftest import DATA


def _openimageio_samples(path):
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    base = spec.format.basetype
    fmt = base if base in (oiio.UINT8, oiio.UINT16) else oiio.FLOAT
    pixels = inp.read_image(0, 0, 0, spec.nchannels, fmt)
    inp.close()
    return even_rgb(np.asarray(pixels).reshape(spec.height, spec.width, spec.nchannels))


def _tall(tmp_path, name, width=600, sixteen=False, **attributes):
    """A real photo stretched over several strips (an odd number of rows), written
    as ``name``."""
    rows = 549
    assert rows * width * 3 > 4 * STRIP_BYTES  # several reads of 8-bit RGB
    buf = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "srgb" / "coffee.png")), roi=oiio.ROI(0, width, 0, rows)
    )
    for key, value in attributes.items():
        buf.specmod().attribute(key, value)
    if sixteen:
        buf.set_write_format(oiio.UINT16)
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


@pytest.mark.parametrize(
    "name,attributes,dtype",
    [
        ("tall.jpg", {}, np.uint8),
        ("tall.png", {"sixteen": True}, np.uint16),
        ("tall.exr", {}, np.float32),
        ("odd.tif", {"width": 601, "tiff:planarconfig": "separate"}, np.uint8),
    ],
)
def test_files_of_several_strips_read_whole(tmp_path, name, attributes, dtype):
    path = _tall(tmp_path, name, **attributes)
    pixels = read_image(path).pixels
    assert pixels.dtype == dtype
    assert np.array_equal(pixels, _openimageio_samples(path))


def test_tiled_files_read_whole(tmp_path):
    path = tmp_path / "tiled.tif"
    samples = np.random.default_rng(1).integers(0, 65535, (600, 200, 3), dtype=np.uint16)
    tifffile.imwrite(path, samples, tile=(64, 64), photometric="rgb")
    assert np.array_equal(read_image(path).pixels, samples)


def test_a_batchs_next_image_is_decoded_into_the_last_ones_samples(tmp_path):
    rng = np.random.default_rng(2)
    paths = []
    for i, shape in enumerate([(300, 200, 3), (300, 200, 3), (300, 202, 3)]):
        paths.append(tmp_path / f"{i}.png")
        tifffile.imwrite(tmp_path / f"{i}.tif", rng.integers(0, 255, shape, dtype=np.uint8))
        oiio.ImageBuf(str(tmp_path / f"{i}.tif")).write(str(paths[-1]))
    spare = Spare()
    first = read_image(paths[0], spare)
    kept = first.pixels
    spare.keep_array(first.pixels)
    second = read_image(paths[1], spare)  # the same size: into the kept array
    assert np.shares_memory(second.pixels, kept)
    assert np.array_equal(second.pixels, _openimageio_samples(paths[1]))
    spare.keep_array(second.pixels)
    third = read_image(paths[2], spare)  # another size: a new array, the kept one stays
    assert not np.shares_memory(third.pixels, kept) and len(spare) == 1
    assert np.array_equal(third.pixels, _openimageio_samples(paths[2]))


def _even(tmp_path, name, channels=3):
    """coffee.png at 600 × 548 (several strips), with ``channels`` channels."""
    buf = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(str(DATA / "srgb" / "coffee.png")), roi=oiio.ROI(0, 600, 0, 548)
    )
    buf = oiio.ImageBufAlgo.channels(buf, tuple(range(channels)))
    assert buf.write(str(tmp_path / name)), oiio.geterror()
    return tmp_path / name


def _decode_beside(path, rows=64):
    """read_image of ``path`` in a thread while this one follows its progress:
    (the array given, the bands of rows, the decoded image or the exception)."""
    progress = DecodeProgress()
    with ThreadPoolExecutor(1) as pool:
        decoding = pool.submit(read_image, path, None, progress)
        pixels = progress.pixels()
        bands = list(progress.bands(rows))
        return pixels, bands, decoding.exception() or decoding.result()


def test_a_decode_gives_its_rows_as_it_writes_them(tmp_path):
    path = _even(tmp_path, "even.png")
    pixels, bands, decoded = _decode_beside(path)
    assert np.shares_memory(pixels, decoded.pixels) and pixels.shape == decoded.pixels.shape
    assert bands[0][0] == 0 and bands[-1][1] == 548
    assert all(a[1] == b[0] for a, b in zip(bands[:-1], bands[1:], strict=True))  # in order
    assert all(stop - start >= 64 for start, stop in bands[:-1])
    assert np.array_equal(decoded.pixels, _openimageio_samples(path))
    # unprocessing takes these after a copy: no rows are given, the decode is whole
    for other in (_tall(tmp_path, "odd.png"), _even(tmp_path, "grey.png", 1)):
        pixels, bands, decoded = _decode_beside(other)
        assert pixels is None and bands == [] and decoded.pixels.shape[2] == 3
    # a decode that fails: its bands end before the last row; read_image says why
    cut = tmp_path / "cut.png"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 3 // 4])
    pixels, bands, error = _decode_beside(cut, rows=1)
    assert pixels is not None and (bands == [] or bands[-1][1] < 548)
    assert isinstance(error, UnsupportedInputError) and "cut.png" in str(error)


def test_a_file_cut_after_its_first_strips_is_refused(tmp_path):
    path = _tall(tmp_path, "cut.png")
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.8)])
    with pytest.raises(UnsupportedInputError, match="cut.png: "):
        read_image(path)


def test_large_buffers_are_written_in_pieces_whole():
    """write_pieces writes every byte, in order, at most PIECE_BYTES per write()."""
    import io

    from rawsim.io.pieces import PIECE_BYTES, write_pieces

    sizes = []

    class Recorder(io.BytesIO):
        def write(self, b):
            sizes.append(len(b))
            return super().write(b)

    rng = np.random.default_rng(1)
    head = b"header"
    pixels = rng.integers(0, 65535, (3 * PIECE_BYTES // 2 + 7,), dtype=np.uint16)
    f = Recorder()
    write_pieces(f, head, pixels, b"")
    assert f.getvalue() == head + pixels.tobytes()
    assert max(sizes) == PIECE_BYTES and len(sizes) == 1 + 4


def test_open_empty_replaces_what_was_there(tmp_path):
    """open_empty creates an absent file, leaves no tail of a longer one, writes into
    an empty one (a temporary), and gives new files the umask's mode as open() does."""
    from rawsim.io.pieces import open_empty

    absent, longer, empty = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    longer.write_bytes(b"x" * 100)
    empty.touch()
    for path in (absent, longer, empty):
        with open_empty(path) as f:
            f.write(b"new")
        assert path.read_bytes() == b"new"
    with open(tmp_path / "d", "wb"):
        pass
    assert absent.stat().st_mode == (tmp_path / "d").stat().st_mode
