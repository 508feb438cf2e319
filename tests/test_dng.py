"""DNGs written by rawsim, read back by real readers (rawpy/LibRaw, tifffile, dcraw)."""

import json
import subprocess

import numpy as np
import pytest
import rawpy
import tifffile

from rawsim.cameras.profiles import load_profile, profile_dir
from rawsim.io.task import Task
from rawsim.pipelines.unprocess import UnprocessOptions, unprocess_file
from tests.conftest import DATA, require_tool


def _profile(tmp_path, pattern):
    data = json.loads((profile_dir() / "sony_a7s2.json").read_text())
    data["cfa_pattern"] = pattern
    path = tmp_path / f"sony_{pattern}.json"
    path.write_text(json.dumps(data))
    return load_profile(path)


def _unprocess(tmp_path, profile, src, **kw):
    options = UnprocessOptions(profile, **{"iso": 1600, "clean": True, **kw})
    outputs = {k: tmp_path / f"{src.stem}{v}" for k, v in options.output_suffixes().items()}
    meta = unprocess_file(Task(src, src.name, outputs, 7), options)
    return outputs, meta


def test_dng_read_back_by_rawpy_for_every_pattern(tmp_path, pattern):
    profile = _profile(tmp_path, pattern)
    outputs, meta = _unprocess(tmp_path, profile, DATA / "srgb" / "chelsea.png")
    with rawpy.imread(str(outputs["dng"])) as raw:
        letters = "".join(raw.color_desc.decode()[i] for i in raw.raw_pattern.flatten())
        assert letters.replace("G", "g") == pattern.replace("G", "g")
        assert list(raw.black_level_per_channel) == [512] * 4
        assert raw.white_level == 16383
        wb = np.array(raw.camera_whitebalance[:3]) / raw.camera_whitebalance[1]
        assert np.allclose(wb, meta["params"]["wb_gains"], rtol=1e-3)
        assert raw.raw_image.shape == (meta["height"], meta["width"]) == (300, 450)
        assert raw.other.iso_speed == 1600
        assert np.allclose(raw.rgb_xyz_matrix[:3], meta["params"]["xyz_to_camera"], atol=1e-4)
        noisy = raw.raw_image.copy()
    with rawpy.imread(str(outputs["clean_dng"])) as raw:
        clean = raw.raw_image.copy()
    assert 0 < np.abs(noisy.astype(int) - clean).mean() < 200


def test_dng_tags(tmp_path):
    outputs, meta = _unprocess(tmp_path, load_profile("nikon_d850"), DATA / "srgb" / "rocket.jpg")
    with tifffile.TiffFile(outputs["dng"]) as tif:
        tags = tif.pages.first.tags
        assert tuple(tags["DNGVersion"].value) == (1, 4, 0, 0)
        assert tags["UniqueCameraModel"].value == "Nikon D850"
        assert (tags["Make"].value, tags["Model"].value) == ("Nikon", "D850")
        assert tags["PhotometricInterpretation"].value == 32803
        assert tuple(tags["CFARepeatPatternDim"].value) == (2, 2)
        assert bytes(tags["CFAPattern"].value) == b"\x00\x01\x01\x02"
        assert tags["CalibrationIlluminant1"].value == 21
        assert tags["WhiteLevel"].value == 16383
        neutral = np.array(tags["AsShotNeutral"].value, float).reshape(3, 2)
        assert np.allclose(
            neutral[:, 0] / neutral[:, 1], 1 / np.array(meta["params"]["wb_gains"]), atol=1e-4
        )
        s, o = tags["NoiseProfile"].value
        assert [s, o] == pytest.approx(meta["noise"]["noise_profile"])
        assert tags["ExifTag"].value["ISOSpeedRatings"] == 1600
        assert tags["Orientation"].value == 1
    with tifffile.TiffFile(outputs["clean_dng"]) as tif:
        assert "NoiseProfile" not in tif.pages.first.tags


def test_noise_profile_tag_matches_measured_noise(tmp_path):
    """Flat grey input: the DNG's NoiseProfile predicts the measured variance."""
    import OpenImageIO as oiio

    src = tmp_path / "grey.exr"
    spec = oiio.ImageSpec(512, 512, 3, oiio.FLOAT)
    buf = oiio.ImageBuf(spec)
    oiio.ImageBufAlgo.fill(buf, [0.18, 0.18, 0.18])
    assert buf.write(str(src))
    outputs, meta = _unprocess(
        tmp_path, load_profile("sony_a7s2"), src, iso=3200, safe_white_balance=False
    )
    with rawpy.imread(str(outputs["dng"])) as raw:
        noisy = raw.raw_image.astype(np.float64)
    with rawpy.imread(str(outputs["clean_dng"])) as raw:
        clean = raw.raw_image.astype(np.float64)
    with tifffile.TiffFile(outputs["dng"]) as tif:
        s, o = tif.pages.first.tags["NoiseProfile"].value
    span = 16383 - 512
    for site in ((0, 0), (0, 1), (1, 1)):
        n = noisy[site[0] :: 2, site[1] :: 2]
        c = clean[site[0] :: 2, site[1] :: 2]
        x = (c.mean() - 512) / span
        assert n.mean() == pytest.approx(c.mean(), abs=1.0)
        assert n.var() == pytest.approx((s * x + o) * span**2, rel=0.03)


def test_dcraw_decodes_our_dng(tmp_path):
    dcraw = require_tool("dcraw")
    outputs, _ = _unprocess(tmp_path, load_profile("canon_eos_70d"), DATA / "srgb" / "coffee.png")
    info = subprocess.run(
        [dcraw, "-i", "-v", str(outputs["dng"])], capture_output=True, text=True, check=True
    ).stdout
    assert "Canon EOS 70D" in info and "ISO speed: 1600" in info
    assert "Filter pattern: RG/GB" in info
    ppm = subprocess.run(
        [dcraw, "-c", "-w", "-6", str(outputs["dng"])], capture_output=True, check=True
    ).stdout
    header = ppm.split(b"\n", 3)
    assert header[0] == b"P6" and header[1] == b"600 400" and header[2] == b"65535"
    pixels = np.frombuffer(header[3], dtype=">u2").reshape(400, 600, 3)
    assert 0.1 < pixels.mean() / 65535 < 0.9
