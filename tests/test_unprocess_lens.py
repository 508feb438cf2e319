"""``rawsim unprocess --lens``: a real lens (lensfun's distortion, lateral CA and
vignetting) added to simulated raws, where ``rawsim process`` corrects it.

* Round trip: a photo unprocessed through a kit zoom at its widest, then processed
  with lens correction, is the photo round-tripped without a lens (≥ 30 dB over the
  central 90 %); without the correction it is far from it.
* The compiled engine equals the torch reference (here for mono, 16-bit and float
  inputs; Bayer options are in ``tests/test_engine.py``'s matrix); the same bytes for
  any strip height, thread count and ``--jobs``.
* gradcheck in float64 through the sensor with its lens.
* The CLI's errors, the sidecar's and npz's record, the Python API.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from PIL import Image

from rawsim import api
from rawsim.cameras.profiles import load_profile
from rawsim.io.images import read_image
from rawsim.io.lensfun import LensParams, lens_params
from rawsim.pipelines import unprocess as pipeline
from rawsim.pipelines.unprocess import Simulation, UnprocessOptions, simulate
from rawsim.sensors import MonoSensor, RGBSensor
from rawsim_cli.main import cli
from tests.conftest import DATA, numba_threads, psnr, thread_counts
from tests.test_cli import digest
from tests.test_engine import EXR, PHOTO, PHOTO16, _compare

PROFILE = "canon_eos_700d"
#: The kit zoom of the profile's camera at 18 mm, f/3.5: barrel distortion (ptlens),
#: lateral CA (poly3) and vignetting (pa: the corners at 0.37, −1.4 stops) in lensfun.
LENS = "Canon EF-S 18-55mm f/3.5-5.6 IS STM"
FOCAL, APERTURE = 18.0, 3.5
LENS_FLAGS = ["--lens", LENS, "--focal-length", FOCAL, "--aperture", APERTURE]


def _lens() -> LensParams:
    profile = load_profile(PROFILE)
    params, warnings = lens_params(
        LENS, FOCAL, APERTURE, None, profile.make, profile.model, adding=True
    )
    assert not warnings  # lensfun knows the camera (as "Canon EOS 700D") and the lens
    return params


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def _centre(a: np.ndarray, share: float = 0.9) -> np.ndarray:
    h, w = a.shape[:2]
    mh, mw = round(h * (1 - share) / 2), round(w * (1 - share) / 2)
    return a[mh : h - mh, mw : w - mw]


def _png(path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"), np.float64) / 255


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    """coffee.png upsampled to 640 × 960: a frame the size of a small camera's."""
    folder = tmp_path_factory.mktemp("photo")
    with Image.open(DATA / "srgb" / "coffee.png") as im:
        im.convert("RGB").resize((960, 640), Image.LANCZOS).save(folder / "coffee.png")
    return folder / "coffee.png"


def _unprocess(src, out, *flags):
    result = _run("unprocess", src, "-o", out, "-p", PROFILE, "--iso", 100, "--clean", *flags)
    assert result.exit_code == 0, result.output
    return out / "coffee.clean.dng"


def _process(dng, out, *flags):
    result = _run("process", dng, "-o", out, *flags)
    assert result.exit_code == 0, result.output
    meta = json.loads((out / "coffee.clean.process.json").read_text())
    return _png(out / "coffee.clean.png"), meta


def test_round_trip_through_the_lens(photo, tmp_path):
    """Unprocessed through the kit zoom at 18 mm, processed with the correction: the
    photo round-tripped without a lens, ≥ 30 dB over the central 90 % (measured 36.2;
    34.6 with bilinear sampling);
    the same raw processed without the correction is far from it (measured 20.0 dB)."""
    plain_dng = _unprocess(photo, tmp_path / "plain")
    lens_dng = _unprocess(photo, tmp_path / "lens", *LENS_FLAGS)
    sidecar = json.loads((tmp_path / "lens" / "coffee.json").read_text())
    assert sidecar["lens"] == _lens().to_dict()

    reference, _ = _process(plain_dng, tmp_path / "r-plain")
    # the lens, focal length and aperture come from the DNG's lens tags
    corrected, meta = _process(lens_dng, tmp_path / "r-corrected", "--lens-correction", "auto")
    # process found the same lens, camera (crop factor) and settings in lensfun
    assert LensParams.of(meta["lens"]) == _lens() and not meta["warnings"]
    named, _ = _process(lens_dng, tmp_path / "r-named", "--lens-correction", "auto", *LENS_FLAGS)
    np.testing.assert_array_equal(corrected, named)
    uncorrected, _ = _process(lens_dng, tmp_path / "r-uncorrected")
    back = psnr(_centre(corrected), _centre(reference))
    off = psnr(_centre(uncorrected), _centre(reference))
    assert back >= 30 and off < 25, (back, off)


@pytest.mark.parametrize("sensor_kind", ["rgb", "mono"])
def test_engine_equals_reference_on_mono_16_bit_and_float_inputs(sensor_kind):
    profile = load_profile(PROFILE)
    sensor = MonoSensor(profile) if sensor_kind == "mono" else RGBSensor(profile)
    options = UnprocessOptions(
        profile=profile, iso=1600, clean=True, lens=_lens(), sensor=sensor_kind
    )
    for pixels, kw in ((PHOTO, {}), (PHOTO16, {"code_max": 65535})):
        a = _compare(sensor, pixels, options, **kw)
        plain = simulate(sensor, pixels, replace(options, lens=None), 5, engine=True)
        # the lens moved and darkened the image
        moved = np.abs(Simulation.codes(a.clean).astype(int) - Simulation.codes(plain.clean))
        assert moved.max() > 1000
    _compare(sensor, EXR, options, display_referred=False)


def test_same_bits_for_any_strip_height_and_thread_count(monkeypatch):
    """The lens samples the whole frame: the reference runs it as one strip whatever
    STRIP_ROWS is, and the engine's passes give the same bits on any thread count."""
    profile = load_profile(PROFILE)
    sensor = RGBSensor(profile)
    image = read_image(DATA / "srgb" / "coffee.png").pixels[:200, :300]
    options = UnprocessOptions(profile=profile, iso=3200, clean=True, lens=_lens())

    def codes(engine):
        sim = simulate(sensor, image, options, 11, engine=engine)
        return Simulation.codes(sim.noisy), Simulation.codes(sim.clean)

    whole = codes(False)
    monkeypatch.setattr(pipeline, "STRIP_ROWS", 8)
    for got, want in zip(codes(False), whole, strict=True):
        np.testing.assert_array_equal(got, want)
    engine = []
    for n in thread_counts():
        with numba_threads(n):
            engine.append(codes(True))
    for got, want in zip(engine[0], engine[-1], strict=True):
        np.testing.assert_array_equal(got, want)


def test_same_bytes_for_any_jobs(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    for name in ("chelsea.png", "coffee.png"):
        with Image.open(DATA / "srgb" / name) as im:
            im.crop((0, 0, 256, 192)).save(src / name)
    digests = []
    for jobs in (1, 2):
        out = tmp_path / f"j{jobs}"
        flags = ["--format", "both", "--noise", "physics", "--jobs", jobs]
        result = _run("unprocess", src, "-o", out, "-p", PROFILE, "--iso", 800, *flags, *LENS_FLAGS)
        assert result.exit_code == 0, result.output
        digests.append(digest(out))
    assert len(digests[0]) == 6 and digests[0] == digests[1]


def test_sidecar_and_npz_record_the_lens(tmp_path):
    src = tmp_path / "chelsea.png"
    with Image.open(DATA / "srgb" / "chelsea.png") as im:
        im.crop((0, 0, 128, 96)).save(src)
    flags = ["-p", PROFILE, "--iso", 400, "--format", "both"]
    result = _run(
        "unprocess", src, "-o", tmp_path / "lens", *flags, "--lens", LENS, "--focal-length", 24
    )
    assert result.exit_code == 0, result.output
    # no aperture: distortion and TCA only, with a warning saying what to pass
    assert "no aperture known: vignetting not added; pass --aperture F" in result.output
    want = replace(_lens(), focal_length=24.0, aperture=None, corrections=("distortion", "tca"))
    sidecar = json.loads((tmp_path / "lens" / "chelsea.json").read_text())
    assert LensParams.of(sidecar["lens"]) == want and sidecar["lens"] == want.to_dict()
    npz = np.load(tmp_path / "lens" / "chelsea.npz")
    assert json.loads(str(npz["metadata"]))["lens"] == want.to_dict()
    # without --lens there is no record, and the mosaic is another
    result = _run("unprocess", src, "-o", tmp_path / "plain", *flags)
    assert result.exit_code == 0, result.output
    assert "lens" not in json.loads((tmp_path / "plain" / "chelsea.json").read_text())
    plain = np.load(tmp_path / "plain" / "chelsea.npz")
    assert not np.array_equal(plain["mosaic"], npz["mosaic"])


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--lens", "Canon EF-S 18-55mm f/3.5-5.6 IS STM Mk IX", "--focal-length", 18],
         "not in lensfun's database; the closest is 'Canon EF-S 18-55mm f/3.5-5.6 IS STM'"),
        (["--lens", LENS], "is a zoom (18–55 mm): pass --focal-length MM"),
        (["--lens", LENS, "--focal-length", 85], "focal length 85 mm is outside"),
        (["--focal-length", 18], "--focal-length and --aperture go with --lens NAME"),
        (["--aperture", 4], "--focal-length and --aperture go with --lens NAME"),
    ],
)  # fmt: skip
def test_cli_errors_in_one_line(tmp_path, flags, message):
    src = tmp_path / "x.png"
    Image.new("RGB", (32, 24)).save(src)
    result = _run("unprocess", src, "-o", tmp_path / "out", "-p", PROFILE, "--iso", 100, *flags)
    assert result.exit_code == 2 and message in result.output, result.output
    error = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(error) == 1 and not (tmp_path / "out").exists()


def test_a_prime_needs_no_focal_length():
    params, _ = lens_params("Canon EF 50mm f/1.4 USM", None, 2.0, None, "Canon", "EOS 700D")
    assert params.focal_length == 50.0 and params.camera == "Canon EOS 700D"


@pytest.mark.parametrize("fast", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_gradcheck_through_the_sensor_and_its_lens(fast):
    """Random projections of the Jacobian (``fast_mode``); the whole one in the slow tier."""
    profile = load_profile(PROFILE)
    lens = _lens()
    params = RGBSensor(profile).default_params(100)
    x = torch.rand(1, 3, 6, 10, dtype=torch.float64, requires_grad=True)
    for sensor in (RGBSensor(profile), MonoSensor(profile)):

        def capture(t, sensor=sensor):
            return sensor.linrgb2raw(sensor.unprocess(t, "linear_rgb", params, lens), params)

        assert torch.autograd.gradcheck(capture, (x,), fast_mode=fast)
        # the lens moves the values: a pixel's gradient reaches its neighbours
        plain = sensor.linrgb2raw(sensor.unprocess(x, "linear_rgb", params), params)
        assert not torch.allclose(capture(x), plain)


def test_python_api_with_and_without_gradients():
    profile = load_profile(PROFILE)
    sensor = RGBSensor(profile)
    images = torch.from_numpy(PHOTO).permute(2, 0, 1)[None].float() / 255
    kw = dict(iso=800, lens=_lens().to_dict())  # a record works as well as LensParams
    noisy, clean, meta = api.unprocess(images, sensor, [3], **kw)
    assert meta[0]["lens"] == _lens().to_dict()
    options = UnprocessOptions(profile=profile, iso=800, clean=True, lens=_lens())
    sim = simulate(sensor, images, options, 3)
    assert torch.equal(noisy, sim.noisy.float()) and torch.equal(clean, sim.clean.float())
    grad_images = images.clone().requires_grad_(True)
    _, unrounded, _ = api.unprocess(grad_images, sensor, [3], **kw)
    assert (unrounded.round().clamp(0, profile.white_level) - clean).abs().max() <= 1
    unrounded.sum().backward()
    assert grad_images.grad.abs().sum() > 0
    plain, _, meta = api.unprocess(images, sensor, [3], iso=800)
    assert "lens" not in meta[0] and not torch.equal(plain, noisy)
