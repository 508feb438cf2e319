"""rawsim calibrate: recovers known noise parameters from frames simulated by rawsim."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from rawsim.calibrate import calibrate_iso, fit_lambda, same_camera
from rawsim.errors import ParameterError
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.images import read_image
from rawsim.io.raw import read_raw
from rawsim.noise import sample_tukey_lambda
from rawsim.pipelines.unprocess import unprocess_tensor
from rawsim.profiles import list_profiles, load_profile
from rawsim.sensors import RGBSensor
from rawsim_cli.main import cli
from tests.conftest import DATA

SENSOR = RGBSensor.from_profile("canon_eos_70d")
ISOS = (400, 1600, 6400)


def _write(path: Path, mosaic: np.ndarray, iso: float, model: str = "EOS 70D") -> Path:
    p = SENSOR.profile
    info = DngInfo(
        cfa=p.cfa,
        black_level=p.black_level,
        white_level=p.white_level,
        xyz_to_camera=p.xyz_to_camera,
        as_shot_neutral=(0.5, 1.0, 0.6),
        make="Canon",
        model=model,
        unique_model=f"Canon {model}",
        iso=iso,
    )
    write_dng(path, mosaic, info)
    return path


def _frame(iso: float, level: float, seed: int, h: int = 512, w: int = 768) -> np.ndarray:
    """A flat field with an illumination gradient (level = brightest fraction of range)."""
    p = SENSOR.profile
    span = p.white_level - p.black_level
    x = torch.linspace(0.0, 1.0, w)[None, :]
    y = torch.linspace(0.0, 1.0, h)[:, None]
    signal = level * span * (0.05 + 0.95 * x) * (0.7 + 0.3 * y)
    dn = (p.black_level + signal.expand(h, w))[None, None]
    out = SENSOR.simu_noise(dn, iso, "physics", seed)
    return out[0, 0].numpy().astype(np.uint16)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    root = tmp_path_factory.mktemp("calib")
    (root / "flats").mkdir()
    (root / "darks").mkdir()
    seed = 0
    for iso in ISOS:
        for level in (0.3, 0.85):
            seed += 1
            _write(root / "flats" / f"f{iso}_{level}.dng", _frame(iso, level, seed), iso)
        for i in range(2):
            seed += 1
            _write(root / "darks" / f"d{iso}_{i}.dng", _frame(iso, 0.0, seed, h=1024), iso)
    return root


def test_flat_field_calibration_recovers_the_model(frames, tmp_path):
    out = tmp_path / "cam.json"
    plot = tmp_path / "fit.png"
    args = ["calibrate", str(frames / "flats"), "--dark", str(frames / "darks")]
    r = CliRunner().invoke(cli, [*args, "-o", str(out), "--plot", str(plot), "--json"])
    assert r.exit_code == 0, r.output
    written = out.read_bytes()
    again = CliRunner().invoke(cli, [*args, "-o", str(out)])  # exists: skipped, as everywhere
    assert again.exit_code == 0 and "skip: " in again.output and out.read_bytes() == written
    fits = json.loads(r.stdout)
    assert [f["iso"] for f in fits] == list(ISOS)
    for fit in fits:
        levels = SENSOR.noise_levels(fit["iso"], "physics")
        read_std = math.sqrt(levels.read_variance - levels.row_sigma**2)
        assert fit["K"] == pytest.approx(levels.gain, rel=0.03)
        assert fit["read_sigma"] == pytest.approx(read_std, rel=0.05)
        assert fit["row_sigma"] == pytest.approx(levels.row_sigma, rel=0.10)
        assert fit["lambda"] == pytest.approx(levels.tukey_lambda, abs=0.05)
        assert set(fit["channels"]) == {"R", "Gr", "Gb", "B"}
        for ch in fit["channels"].values():
            assert ch["K"] == pytest.approx(levels.gain, rel=0.05)
            assert abs(ch["bias"]) < 0.5
    # The written profile loads, drives the physics model and matches the camera.
    prof = load_profile(out)
    assert (prof.make, prof.model, prof.cfa.pattern) == ("Canon", "EOS 70D", "RGGB")
    assert prof.black_level == SENSOR.profile.black_level
    assert prof.iso_range == (400.0, 6400.0)
    assert prof.noise.levels("physics", 1600).gain == pytest.approx(
        SENSOR.noise_levels(1600, "poisson-gaussian").gain, rel=0.03
    )
    assert plot.stat().st_size > 10_000 and plot.read_bytes()[:4] == b"\x89PNG"


@pytest.fixture(scope="module")
def camera_photos():
    """The shared photos at camera resolution: 3× bicubic, i.e. lens-limited.

    The 300–600 px sources are downsampled photos with texture at every pixel;
    a 20 MP camera's raw is smoother per pixel, and so are these.
    """
    photos = []
    for name in ["astronaut.png", "chelsea.png", "coffee.png"]:
        decoded = read_image(DATA / "srgb" / name)
        x = torch.from_numpy(decoded.pixels.astype(np.float32)).permute(2, 0, 1)[None]
        x = torch.nn.functional.interpolate(x, scale_factor=3, mode="bicubic")
        photos.append((x.round().clamp(0, decoded.code_max).to(torch.int32), decoded.code_max))
    return photos


@pytest.mark.parametrize("iso", [1600, 3200, 12800])
def test_smooth_patch_method_on_simulated_photos(camera_photos, iso):
    levels = SENSOR.noise_levels(iso, "physics")
    raws = []
    for i, (image, code_max) in enumerate(camera_photos):
        noisy, _ = unprocess_tensor(
            SENSOR,
            image,
            SENSOR.default_params(iso),
            noise=levels,
            key=i,
            code_max=code_max,
        )
        raws.append(_raw_image(noisy[0, 0].numpy().astype(np.uint16), iso))
    fit = calibrate_iso(iso, raws, [], method="patches")
    assert fit.K == pytest.approx(levels.gain, rel=0.15)


def _raw_image(mosaic, iso):
    from rawsim.io.raw import RawImage

    p = SENSOR.profile
    black = np.full((2, 2), p.black_level)
    return RawImage(
        mosaic, p.cfa, black, p.white_level, None, None, None, None, 1, iso, "Canon", "EOS 70D", "x"
    )


@pytest.mark.parametrize("lam", [-0.15, 0.0, 0.14])
def test_lambda_fit_finds_the_shape(lam):
    x = sample_tukey_lambda((300_000,), lam, torch.Generator().manual_seed(0), dtype=torch.float64)
    assert fit_lambda(3.0 * x) == pytest.approx(lam, abs=0.03)


@pytest.mark.parametrize("name", sorted(p.name for p in (DATA / "raw").iterdir()))
def test_real_raws_calibrate_to_a_profile_and_plot(name, tmp_path):
    out, plot = tmp_path / "p.json", tmp_path / "p.png"
    raw = DATA / "raw" / name
    args = ["calibrate", str(raw), "--method", "patches", "--iso", "100"]
    r = CliRunner().invoke(cli, [*args, "-o", str(out), "--plot", str(plot)])
    assert r.exit_code == 0, r.output
    assert load_profile(out).noise.levels("poisson-gaussian", 100).gain > 0
    assert plot.read_bytes()[:4] == b"\x89PNG"


def test_bad_calibration_inputs(frames, tmp_path):
    runner = CliRunner()
    flat = next((frames / "flats").glob("f400_*.dng"))
    r = runner.invoke(cli, ["calibrate", str(flat), "-o", str(tmp_path / "a.json")])
    assert r.exit_code == 2 and "at least 2" in r.output
    other = _write(tmp_path / "other.dng", _frame(400, 0.5, 99), 400, model="EOS 700D")
    r = runner.invoke(cli, ["calibrate", str(flat), str(other), "-o", str(tmp_path / "b.json")])
    assert r.exit_code == 2 and "EOS 700D" in r.output and "one camera" in r.output
    with pytest.raises(ParameterError, match="differs"):
        same_camera([read_raw(flat), read_raw(other)])
    r = runner.invoke(
        cli, ["calibrate", str(DATA / "srgb" / "coffee.png"), "-o", str(tmp_path / "c.json")]
    )
    assert r.exit_code == 2 and "coffee.png" in r.output
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("name", list_profiles())
def test_every_shipped_profile_plots_and_unprocesses(name, tmp_path):
    runner = CliRunner()
    plot = tmp_path / "noise.png"
    r = runner.invoke(cli, ["profiles", "show", name, "--plot", str(plot)])
    assert r.exit_code == 0, r.output
    assert plot.read_bytes()[:4] == b"\x89PNG"
    prof = load_profile(name)
    noise = "physics" if prof.noise.has_physics else "poisson-gaussian"
    for iso in prof.iso_range:
        r = runner.invoke(cli, ["profiles", "show", name, "--iso", str(iso), "--json"])
        values = json.loads(r.stdout)
        keys = {"K", "read_std_dn", "tukey_scale_dn", "tukey_lambda", "row_sigma_dn"}
        assert set(values) >= keys and values["K"] > 0
        out = tmp_path / f"iso{iso:g}"
        args = ["unprocess", str(DATA / "srgb" / "coffee.png"), "-o", str(out), "-p", name]
        r = runner.invoke(cli, [*args, "--iso", str(iso), "--noise", noise])
        assert r.exit_code == 0, r.output
        raw = read_raw(out / "coffee.dng")
        # EXIF ISOSpeedRatings is a SHORT: 65535 means "see ISOSpeed", which LibRaw ignores.
        assert raw.iso == min(iso, 65535) and raw.cfa == prof.cfa
        assert raw.data.max() <= prof.white_level
