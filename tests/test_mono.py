"""Monochrome sensor: unprocess to one-sample LinearRaw DNGs, noise, and grey renders."""

import json

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import torch
from click.testing import CliRunner

from rawsim.io.images import read_image
from rawsim.io.raw import read_raw
from rawsim.isp.levels import quantize, saturate
from rawsim.pipelines.unprocess import unprocess_tensor
from rawsim.sensors import MonoSensor
from rawsim_cli.main import cli
from tests.conftest import DATA


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def mono_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("mono")
    args = ["unprocess", DATA / "srgb" / "chelsea.png", "-o", out, "--profile", "canon_eos_70d"]
    r = run(*args, "--sensor", "mono", "--iso", 1600, "--clean", "--format", "both")
    assert r.exit_code == 0, r.output
    return out


def test_mono_dng_round_trip_through_rawpy(mono_run):
    sensor = MonoSensor.from_profile("canon_eos_70d")
    decoded = read_image(DATA / "srgb" / "chelsea.png")
    image = torch.from_numpy(decoded.pixels).permute(2, 0, 1)[None].to(torch.float32) / 255
    dn = sensor.linrgb2raw(sensor.unprocess(image, "rgb", sensor.default_params(1600)))
    expected = saturate(quantize(dn), sensor.white_level)[0, 0].numpy()
    npz = np.load(mono_run / "chelsea.npz")
    assert npz["mosaic"].shape == (1, 300, 450) and list(npz["planes"]) == ["Y"]
    for name, want in (("chelsea.clean.dng", expected), ("chelsea.dng", npz["mosaic"][0])):
        with rawpy.imread(str(mono_run / name)) as raw:
            assert raw.num_colors == 1 and raw.raw_image.ndim == 2
            assert raw.black_level_per_channel[0] == 2048 and raw.white_level == 15303
            assert raw.other.iso_speed == 1600
            got = raw.raw_image.astype(np.float64)
        assert np.abs(got - want).max() <= 1  # float32 LUT vs stage-by-stage rounding
    meta = json.loads((mono_run / "chelsea.json").read_text())
    assert meta["sensor"] == "mono" and meta["cfa_pattern"] is None
    assert meta["noise"]["noise_profile"][0] > 0
    raw = read_raw(mono_run / "chelsea.dng")
    assert raw.cfa is None and raw.data.shape == (300, 450, 1) and not raw.warnings


@pytest.mark.parametrize("model", ["poisson-gaussian", "physics"])
def test_mono_noise_statistics_match_the_model(model):
    sensor = MonoSensor.from_profile("canon_eos_70d")
    grey = torch.full((1, 3, 512, 512), 0.2)
    params = sensor.default_params(3200)
    levels = sensor.noise_levels(3200, model)
    noisy, clean = unprocess_tensor(
        sensor,
        grey,
        params,
        noise=model,
        key=3,
        display_referred=False,
        clean=True,
    )
    signal = float(clean.mean()) - sensor.black_level
    span = sensor.white_level - sensor.black_level
    a, b = levels.affine_variance(span)
    assert float(noisy.var()) == pytest.approx(a * signal + b, rel=0.03)
    assert float(noisy.mean()) == pytest.approx(float(clean.mean()), abs=0.5)


def test_process_renders_mono_dngs_to_grey(mono_run, tmp_path):
    out = tmp_path / "grey"
    r = run("process", mono_run / "chelsea.clean.dng", "-o", out, "--format", "png")
    assert r.exit_code == 0, r.output
    assert "warning" not in r.output
    img = oiio.ImageBuf(str(out / "chelsea.clean.png"))
    assert img.spec().nchannels == 1 and (img.spec().width, img.spec().height) == (450, 300)
    grey = img.get_pixels(oiio.FLOAT)[..., 0]
    with rawpy.imread(str(mono_run / "chelsea.clean.dng")) as raw:
        data = raw.raw_image.astype(np.float64)
    ranks = [np.argsort(np.argsort(v.ravel())) for v in (grey, data)]
    assert np.corrcoef(*ranks)[0, 1] > 0.995  # a monotone render of the raw values
    meta = json.loads((out / "chelsea.clean.process.json").read_text())
    assert meta["monochrome"] is True and meta["cfa_pattern"] is None
