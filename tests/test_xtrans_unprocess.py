"""rawsim unprocess on X-Trans (and any periodic CFA): the Fujifilm X-T3 profile,
``--cfa``, DNGs LibRaw reads and renders like the photo, the engine against the torch
reference, the npz layout, the dataset's crops, Ray Data rows and ``rawsim calibrate``."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import tifffile
import torch
from click.testing import CliRunner
from scipy.ndimage import uniform_filter

from rawsim.api import process, unprocess
from rawsim.cameras.profiles import SOURCED_KEYS, load_profile, profile_from_dict
from rawsim.cfa import CFA, XTRANS
from rawsim.color import camera_from_srgb
from rawsim.dataset import UnprocessDataset
from rawsim.engine.unprocess import (
    MODEL_CODES,
    add_noise_rows,
    dark_maps,
    noise_tables,
    noise_vector,
)
from rawsim.errors import ParameterError
from rawsim.io.dng import DngInfo, write_dng
from rawsim.io.images import read_image
from rawsim.io.png import write_png
from rawsim.io.raw import read_raw
from rawsim.io.task import Task
from rawsim.isp.transfer import srgb_decode
from rawsim.noise.kernels import np_key
from rawsim.noise.models import NOISE_MODELS, bias_tile, site_bias
from rawsim.pipelines.unprocess import (
    STRIP_ROWS,
    Simulation,
    UnprocessOptions,
    simulate,
    strip_rows,
    unprocess_file,
)
from rawsim.ray_data import RawPairs
from rawsim.sensors import MonoSensor, RGBSensor
from rawsim_cli.main import cli
from tests.conftest import DATA, numba_threads, psnr, thread_counts
from tests.test_engine import EXR, OPTIONS, PHOTO, PHOTO16, _compare, _physics_profile

XT = CFA("XTRANS")
#: X-Trans, and a 3×3 layout: any periodic R/G/B pattern goes through the same code.
PATTERNS = ("XTRANS", "GRG/BGB/GRG")
#: LibRaw's adobe_coeff for the X-T3 (src/tables/colordata.cpp), ×10000.
XT3_MATRIX = (13426, -6334, -1177, -4244, 12136, 2371, -580, 1303, 5980)


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _mirrored(name: str) -> np.ndarray:
    """A vendored 8-bit photo mirrored 2×2 (LibRaw's X-Trans demosaics need ≥ 600 px)."""
    x = oiio.ImageBuf(str(DATA / "srgb" / name)).get_pixels(oiio.UINT8)[:, :, :3]
    x = np.concatenate([x, x[:, ::-1]], 1)
    return np.ascontiguousarray(np.concatenate([x, x[::-1]], 0))


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    """coffee.png and astronaut.png mirrored: 800×1200 and 1024×1024 8-bit PNGs."""
    root = tmp_path_factory.mktemp("photos")
    for name in ("coffee.png", "astronaut.png"):
        write_png(root / name, _mirrored(name))
    return root


@pytest.fixture(scope="module")
def xt3_run(photos, tmp_path_factory) -> Path:
    """The X-T3 profile through the CLI: DNG, clean DNG, npz and sidecar of coffee.png."""
    out = tmp_path_factory.mktemp("xt3")
    args = ["unprocess", photos / "coffee.png", "-o", out, "-p", "fujifilm_xt3", "--iso", 800]
    r = run(*args, "--clean", "--format", "both", "--seed", 4, "-q")
    assert r.exit_code == 0, r.output
    return out


# ------------------------------------------------------------------ the profile
def test_xt3_profile_values_and_sources():
    p = load_profile("fujifilm_xt3")
    assert (p.make, p.model, p.cfa, p.cfa.name) == ("Fujifilm", "X-T3", XT, "XTRANS")
    assert (p.bit_depth, p.black_level, p.white_level) == (14, 1022, 16383)
    assert np.array_equal(np.ravel(p.xyz_to_camera), np.array(XT3_MATRIX) / 10000)
    assert p.iso_range == (160, 12800) and p.check_iso(160) == 160
    with pytest.raises(ParameterError, match="outside the range"):
        p.check_iso(100)  # ISO 80–125 are extended settings: ISO 160's raw
    assert (p.size_mm, p.resolution) == ((23.5, 15.6), (6240, 4160))
    k160, k12800 = p.noise.gain(160), p.noise.gain(12800)
    assert k160 == pytest.approx((16383 - 1022) / 50_000) and k12800 == pytest.approx(80 * k160)
    read = {iso: p.noise.read_sigma(iso, p.noise.gain(iso)) for iso in (160, 640, 800, 12800)}
    assert read[160] == pytest.approx(2.512) and read[12800] / k12800 == pytest.approx(1.1, 1e-3)
    assert read[800] < read[640]  # the switch to the high conversion gain at ISO 800
    assert read[160] / k160 > read[640] / p.noise.gain(640) > read[800] / p.noise.gain(800)
    assert not p.noise.has_physics and p.noise.channel_bias == (0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ParameterError, match="no physics noise parameters"):
        p.noise.levels("physics", 800)
    keys = (*SOURCED_KEYS, "cfa_pattern", "base_iso", "sensor_size_mm", "resolution")
    assert all(len(p.source[k]) > 40 for k in keys), keys
    assert "rawspeed" in p.source["black_level"] and '"1022"' in p.source["black_level"]
    assert "adobe_coeff" in p.source["xyz_to_camera"]
    assert ",".join(map(str, XT3_MATRIX)) in p.source["xyz_to_camera"]
    assert XTRANS in p.source["cfa_pattern"]
    for key in ("noise.gain", "noise.read_sigma"):  # derived, and says so
        assert p.source[key].startswith("Derived") and "darktable" in p.source[key]
    assert "50,000 e⁻" in p.source["noise.gain"] and "1.1 e⁻" in p.source["noise.read_sigma"]


def test_any_profile_takes_another_cfa():
    a7s2 = load_profile("sony_a7s2")
    xt = a7s2.with_cfa("XTRANS")
    assert xt.cfa == XT and (xt.noise, xt.xyz_to_camera) == (a7s2.noise, a7s2.xyz_to_camera)
    assert xt.source["cfa_pattern"] == "set to XTRANS by the user; the profile's own layout is RGGB"
    assert a7s2.with_cfa("RGGB") is a7s2 and a7s2.with_cfa("gbrg").cfa.pattern == "GBRG"
    assert RGBSensor(a7s2, cfa="XTRANS").cfa == XT and RGBSensor(a7s2).cfa.pattern == "RGGB"
    assert RGBSensor.from_profile("sony_a7s2", cfa="GRG/BGB/GRG").cfa.period == (3, 3)
    with pytest.raises(ParameterError, match="valid: RGGB, BGGR, GRBG, GBRG, XTRANS"):
        a7s2.with_cfa("RG/GR")  # no blue
    seed = {"bayer_pattern": "xtrans", "bit": 12, "read_noise_std": 0.5}
    assert profile_from_dict(seed, "<seed>").cfa == XT  # the seed's format takes any layout too
    options = UnprocessOptions(a7s2, iso=800)
    assert options.with_cfa(None) is options and options.with_cfa("XTRANS").profile.cfa == XT
    with pytest.raises(ParameterError, match="mono has no colour filter"):
        replace(options, sensor="mono").with_cfa("XTRANS")


def test_cli_cfa_errors_are_usage_errors(tmp_path):
    args = ["unprocess", DATA / "srgb" / "chelsea.png", "-o", tmp_path, "-p", "sony_a7s2"]
    r = run(*args, "--iso", 800, "--cfa", "RGBG")
    assert r.exit_code == 2 and "unknown CFA pattern 'RGBG'" in r.output, r.output
    r = run(*args, "--iso", 800, "--cfa", "XTRANS", "--sensor", "mono")
    assert r.exit_code == 2 and "a mono sensor has no colour filter" in r.output, r.output
    assert not list(tmp_path.iterdir())
    assert "--cfa RGGB|BGGR|GRBG|GBRG|XTRANS|ROWS" in run("unprocess", "--help").output


# ------------------------------------------------------------------ DNGs and LibRaw
def test_xtrans_dngs_open_in_libraw(xt3_run, photos, tmp_path):
    """The X-T3 DNGs and a Bayer profile's --cfa XTRANS DNG: LibRaw reads a 6×6 X-Trans
    pattern, the levels and the codes written, and renders them."""
    r = run(
        *("unprocess", photos / "astronaut.png", "-o", tmp_path, "-p", "sony_a7s2"),
        *("--cfa", "XTRANS", "--iso", 1600, "-q"),
    )
    assert r.exit_code == 0, r.output
    dngs = [xt3_run / "coffee.dng", xt3_run / "coffee.clean.dng", tmp_path / "astronaut.dng"]
    for dng, black, white in zip(dngs, (1022, 1022, 512), (16383, 16383, 16383), strict=True):
        codes = tifffile.imread(dng)
        with rawpy.imread(str(dng)) as raw:
            assert raw.raw_pattern.shape == (6, 6)
            assert CFA.from_rawpy(raw.raw_pattern, raw.color_desc) == XT
            assert raw.black_level_per_channel == [black] * 4 and raw.white_level == white
            assert np.array_equal(raw.raw_image_visible, codes)
            rendered = raw.postprocess(user_flip=0)
        assert rendered.shape == (*codes.shape, 3) and rendered.std() > 20
        raw = read_raw(dng)
        assert raw.cfa == XT and raw.black_level.shape == (6, 6) and raw.iso in (800, 1600)
    meta = json.loads((tmp_path / "astronaut.json").read_text())
    assert meta["cfa_pattern"] == XTRANS and meta["profile"]["name"] == "sony_a7s2"


def test_clean_xtrans_mosaic_is_the_photo_through_the_pattern(photos, tmp_path):
    """The clean mosaic, computed here from the photo independently: sRGB decode →
    camera RGB → ÷ white-balance gains → the X-Trans site's channel → levels; within
    one code (the engine's float32 decode table), and not a Bayer sampling."""
    profile = load_profile("fujifilm_xt3")
    options = UnprocessOptions(profile, iso=800, clean=True, safe_white_balance=False)
    outputs = {k: tmp_path / f"x{v}" for k, v in options.output_suffixes().items()}
    meta = unprocess_file(Task(photos / "coffee.png", "coffee.png", outputs, 1), options)
    clean = tifffile.imread(outputs["clean_dng"]).astype(np.int64)
    pixels = read_image(photos / "coffee.png").pixels.astype(np.float64) / 255
    linear = srgb_decode(torch.from_numpy(pixels)).numpy()
    camera = linear @ camera_from_srgb(profile.xyz_to_camera).T / meta["params"]["wb_gains"]
    h, w = clean.shape

    def sampled(cfa):
        colors = cfa.color_map(h, w)[0, 0].numpy()
        site = np.take_along_axis(camera, colors[..., None], 2)[..., 0]
        return np.clip(np.round(1022 + site * (16383 - 1022)), 0, 16383)

    expected = sampled(XT)
    assert np.abs(clean - expected).max() <= 1 and np.mean(clean != expected) < 1e-3
    assert np.mean(np.abs(clean - sampled(CFA("RGGB"))) > 1) > 0.2


def _ideal_render(photo: np.ndarray, profile, gains) -> np.ndarray:
    """What a raw render of the photo's capture gives per pixel, linear sRGB: the sensor
    clips at white, LibRaw clips after white balance and in its output space."""
    a = camera_from_srgb(profile.xyz_to_camera)
    raw = np.clip(np.einsum("ij,hwj->hwi", a, photo) / gains, 0, 1)
    return np.clip(np.clip(raw * gains, 0, 1) @ np.linalg.inv(a).T, 0, 1)


@pytest.mark.parametrize("name", ["coffee.png", "astronaut.png"])
@pytest.mark.parametrize("wb_inverse", ["safe", "exact"])
def test_libraw_renders_clean_xtrans_dng_like_the_photo(photos, tmp_path, name, wb_inverse):
    """LibRaw's linear render (3-pass Markesteijn, camera white balance, sRGB) of a
    --clean X-T3 DNG against the photo: ≥ 40 dB on 8×8 local means, where the
    demosaic's errors average out (44–46 dB measured), ≥ 31 dB pixel by pixel (32.6–34.4);
    the Bayer test's half-size render has no X-Trans counterpart."""
    profile = load_profile("fujifilm_xt3")
    options = UnprocessOptions(
        profile, iso=800, clean=True, safe_white_balance=wb_inverse == "safe"
    )
    outputs = {k: tmp_path / f"x{v}" for k, v in options.output_suffixes().items()}
    meta = unprocess_file(Task(photos / name, name, outputs, 1), options)
    photo = srgb_decode(torch.from_numpy(read_image(photos / name).pixels / 255.0)).numpy()
    reference = _ideal_render(photo, profile, np.array(meta["params"]["wb_gains"]))
    with rawpy.imread(str(outputs["clean_dng"])) as raw:
        assert raw.raw_pattern.shape == (6, 6)
        rendered = raw.postprocess(
            demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,  # X-Trans: 3-pass Markesteijn
            use_camera_wb=True,
            output_color=rawpy.ColorSpace.sRGB,
            gamma=(1, 1),
            no_auto_bright=True,
            output_bps=16,
            highlight_mode=rawpy.HighlightMode.Clip,
            user_flip=0,
            adjust_maximum_thr=0.0,
        )
    rendered = rendered / 65535.0
    b = 12  # LibRaw's X-Trans border
    local = [uniform_filter(x, (8, 8, 1))[b:-b, b:-b] for x in (rendered, reference)]
    assert psnr(*local) >= 40
    assert psnr(rendered[b:-b, b:-b], reference[b:-b, b:-b]) >= 31


# ------------------------------------------------------------------ engine vs reference
@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("model", NOISE_MODELS)
@pytest.mark.parametrize("extra", OPTIONS, ids=lambda o: ",".join(o) or "default")
def test_engine_matches_reference(pattern, model, extra):
    """tests/test_engine.py's matrix on X-Trans and a 3×3 layout (channel bias set)."""
    profile = _physics_profile(pattern)
    options = UnprocessOptions(
        **({"profile": profile, "iso": 3200} | extra), noise=model, clean=True
    )
    _compare(RGBSensor(profile), PHOTO, options)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_engine_matches_reference_across_strips_and_inputs(pattern):
    """A photo taller than a reference strip (whole periods: 126 rows), 16-bit and EXR."""
    profile = _physics_profile(pattern)
    sensor = RGBSensor(profile)
    assert strip_rows(sensor) == 126 and strip_rows(MonoSensor(profile)) == STRIP_ROWS
    options = UnprocessOptions(profile=profile, iso=800, noise="physics", clean=True)
    tall = read_image(DATA / "srgb" / "coffee.png").pixels[60:330, 150:246]
    assert tall.shape[0] > 2 * 126  # three reference strips; the engine runs whole
    _compare(sensor, tall, options)
    _compare(sensor, PHOTO16, options, code_max=65535)
    _compare(sensor, EXR, options, display_referred=False)


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("model", NOISE_MODELS)
def test_noise_is_bit_equal_for_any_strip_split(pattern, model):
    """The engine's noise rows equal the reference's for any strip split, the channel
    bias of every period site included (test_engine's test on other periods)."""
    profile = _physics_profile(pattern)
    sensor = RGBSensor(profile)
    levels = sensor.noise_levels(1600 if model != "gaussian" else 800, model)
    rng = np.random.default_rng(1)
    h, w = 30, 33
    dn = rng.uniform(profile.black_level - 20, profile.white_level * 0.3, (h, w)).astype(np.float32)
    dn[:4] = profile.black_level + rng.uniform(0, 60, (4, w))  # exact-Poisson counts
    whole = sensor.simu_noise(torch.from_numpy(dn)[None, None], 1600, levels, 99)[0, 0].numpy()
    for rows in (2, 5, 7, 30):  # strips that do not start on a period
        parts = [
            sensor.simu_noise(torch.from_numpy(dn[t : t + rows])[None, None], 1600, levels, 99, t)
            for t in range(0, h, rows)
        ]
        assert np.array_equal(torch.cat(parts, 2)[0, 0].numpy(), whole)
    tile = bias_tile(levels, profile.cfa)
    tile = np.zeros(profile.cfa.period) + (0.0 if tile is None else tile)
    out = np.empty(dn.shape, np.uint16)
    noise = (MODEL_CODES[model], noise_vector(levels, profile.black_level), *noise_tables(levels))
    for top in (0, 7, 13):  # the engine's rows from 0, and from rows off the period
        white = float(profile.white_level)
        maps = dark_maps(levels, None)
        add_noise_rows(dn[top:], top, w, *noise, *np_key(99), tile, *maps, white, out[top:])
        assert np.array_equal(out, whole.astype(np.uint16))


def test_engine_output_does_not_depend_on_threads():
    profile = _physics_profile("XTRANS")
    options = UnprocessOptions(profile=profile, iso=6400, noise="physics", clean=True)
    sensor = RGBSensor(profile)
    outputs = []
    for threads in thread_counts():
        with numba_threads(threads):
            outputs.append(Simulation.codes(simulate(sensor, PHOTO, options, 3, engine=True).noisy))
    assert np.array_equal(*outputs)


def test_channel_bias_on_any_period():
    """Bayer places R, Gr, Gb, B; other layouts give G sites the mean of Gr and Gb; the
    tile is laid from the image's top row (strips start anywhere)."""
    profile = _physics_profile("RGGB")  # channel bias (3, 1, −1, −2)
    levels = RGBSensor(profile).noise_levels(1600, "physics")
    assert bias_tile(levels, CFA("RGGB")).tolist() == [[3.0, 1.0], [-1.0, -2.0]]
    assert bias_tile(levels, None) == pytest.approx(0.25)
    for pattern in PATTERNS:
        cfa = CFA(pattern)
        tile = bias_tile(levels, cfa)
        expected = np.array([3.0, 0.0, -2.0])[np.array(cfa.colors)].reshape(cfa.period)
        assert np.array_equal(tile, expected)
        whole = site_bias(levels, cfa, 0, 40, 25, "cpu")
        assert whole.shape == (40, 25)
        for top in (1, 5, 7):
            assert torch.equal(site_bias(levels, cfa, top, 20, 25, "cpu"), whole[top : top + 20])
    assert bias_tile(replace(levels, channel_bias=(0.0,) * 4), XT) is None


# ------------------------------------------------------------------ npz
def test_npz_keeps_the_xtrans_mosaic_whole_with_its_pattern(xt3_run):
    npz = np.load(xt3_run / "coffee.npz")
    assert set(npz.files) == {"mosaic", "clean", "planes", "cfa_pattern", "cfa_colors", "metadata"}
    mosaic, clean = npz["mosaic"], npz["clean"]
    assert mosaic.shape == clean.shape == (1, 800, 1200) and mosaic.dtype == np.uint16
    assert np.array_equal(mosaic[0], tifffile.imread(xt3_run / "coffee.dng"))
    assert np.array_equal(clean[0], tifffile.imread(xt3_run / "coffee.clean.dng"))
    assert npz["planes"].tolist() == ["CFA"] and str(npz["cfa_pattern"]) == XTRANS
    colors = npz["cfa_colors"]
    assert colors.dtype == np.uint8 and colors.tolist() == XT.color_map(6, 6)[0, 0].tolist()
    with rawpy.imread(str(xt3_run / "coffee.dng")) as raw:  # LibRaw's view of the same sites
        desc = raw.color_desc.decode()
        assert [[desc[i] for i in row] for row in raw.raw_pattern] == [
            ["RGB"[c] for c in row] for row in colors
        ]
    meta = json.loads(str(npz["metadata"]))
    assert meta["packed_planes"] == ["CFA"] and meta["cfa_pattern"] == XTRANS
    assert meta == json.loads((xt3_run / "coffee.json").read_text())
    # the guide's 36 phase planes (whole periods): plane i holds period site i's samples
    m = mosaic[0, :798]
    phases = m.reshape(133, 6, 200, 6).transpose(1, 3, 0, 2).reshape(36, 133, 200)
    assert np.array_equal(phases[8], m[1::6, 2::6]) and colors.ravel()[8] == 2  # B


# ------------------------------------------------------------------ dataset, Ray Data, API
def test_dataset_crops_keep_the_xtrans_phase(tmp_path):
    """Crops start on multiples of 6: in every crop of a flat colour, the clean mosaic
    has one value per colour of the pattern laid from its top-left pixel."""
    (tmp_path / "flat").mkdir()
    write_png(tmp_path / "flat" / "c.png", np.full((200, 300, 3), (200, 120, 60), np.uint8))
    sensor = RGBSensor(load_profile("fujifilm_xt3"))
    data = UnprocessDataset(
        tmp_path / "flat", sensor, crop=60, iso=800, randomize=False, noise="none"
    )
    origins = {data.crop_origin(200, 300, seed) for seed in range(60)}
    assert len(origins) > 20
    assert all(t % 6 == 0 == left % 6 and t <= 140 and left <= 240 for t, left in origins)
    colors = XT.color_map(60, 60)[0, 0]
    for epoch in range(3):
        data.set_epoch(epoch)
        clean = data[0]["clean"][0]
        assert clean.shape == (60, 60)  # layout auto: the mosaic, X-Trans has no packing
        values = [clean[colors == c] for c in range(3)]
        assert all(float(v.min()) == float(v.max()) for v in values)
        assert len({float(v[0]) for v in values}) == 3
        shifted = torch.roll(colors, 1, 1)  # one pixel off the phase: colours mix
        assert any(float(clean[shifted == c].std()) > 0 for c in range(3))
    with pytest.raises(ParameterError, match="needs a Bayer CFA.*XTRANS.*layout='mosaic'"):
        UnprocessDataset(tmp_path / "flat", sensor, crop=60, layout="packed")
    bayer = UnprocessDataset(tmp_path / "flat", RGBSensor(load_profile("sony_a7s2")), crop=60)
    assert bayer[0]["noisy"].shape == (4, 30, 30) and bayer.period == (2, 2)


def test_ray_rows_are_the_cli_xtrans_dngs(tmp_path):
    """RawPairs(cfa="XTRANS") gives, row by row, what rawsim unprocess --cfa XTRANS writes."""
    root = tmp_path / "in"
    root.mkdir()
    write_png(root / "coffee.png", read_image(DATA / "srgb" / "coffee.png").pixels)
    out = tmp_path / "out"
    args = ["unprocess", root, "-o", out, "-p", "sony_a7s2", "--iso", 1600, "--seed", 9]
    assert run(*args, "--cfa", "XTRANS", "--clean", "-q").exit_code == 0
    pairs = RawPairs("sony_a7s2", root=str(root), iso=1600, seed=9, cfa="XTRANS")
    pixels = read_image(root / "coffee.png").pixels
    rows = pairs({"image": [pixels], "path": [str(root / "coffee.png")]})
    assert np.array_equal(rows["noisy"][0], tifffile.imread(out / "coffee.dng"))
    assert np.array_equal(rows["clean"][0], tifffile.imread(out / "coffee.clean.dng"))
    assert json.loads(rows["metadata"][0])["cfa_pattern"] == XTRANS
    with pytest.raises(ParameterError, match="mono has no colour filter"):
        RawPairs("sony_a7s2", root=str(root), iso=1600, sensor="mono", cfa="XTRANS")


def test_python_api_unprocesses_and_renders_xtrans():
    """rawsim.unprocess on an X-T3 sensor and rawsim.process back: the photo again."""
    sensor = RGBSensor(load_profile("fujifilm_xt3"))
    pixels = read_image(DATA / "srgb" / "coffee.png").pixels[:240, :300]
    images = torch.from_numpy(pixels).permute(2, 0, 1)[None]
    noisy, clean, meta = unprocess(images, sensor, [5], iso=200)
    assert noisy.shape == clean.shape == (1, 1, 240, 300)
    assert meta[0]["cfa_pattern"] == XTRANS and meta[0]["black_level"] == 1022
    rendered = process(clean, sensor, meta)[0].permute(1, 2, 0).numpy()
    assert rendered.shape == (240, 300, 3)
    # 33.8 dB with the default ISP (wcd: icd on X-Trans); read as Bayer, 12 dB
    assert psnr(rendered[12:-12, 12:-12], pixels[12:-12, 12:-12] / 255) > 30


# ------------------------------------------------------------------ calibrate
CAL_SENSOR = RGBSensor(
    replace(
        load_profile("canon_eos_70d"),
        noise=replace(load_profile("canon_eos_70d").noise, channel_bias=(2.0, 0.5, 1.5, -1.0)),
    ),
    cfa="XTRANS",
)
CAL_ISOS = (400, 1600, 6400)


def _cal_frame(iso: float, level: float, seed: int, h: int = 576, w: int = 768) -> np.ndarray:
    """A flat field with an illumination gradient (tests/test_calibrate.py's), X-Trans."""
    p = CAL_SENSOR.profile
    span = p.white_level - p.black_level
    x, y = torch.linspace(0.0, 1.0, w)[None, :], torch.linspace(0.0, 1.0, h)[:, None]
    signal = level * span * (0.05 + 0.95 * x) * (0.7 + 0.3 * y)
    dn = (p.black_level + signal.expand(h, w))[None, None]
    return CAL_SENSOR.simu_noise(dn, iso, "physics", seed)[0, 0].numpy().astype(np.uint16)


@pytest.mark.slow
def test_flat_field_calibration_of_xtrans_frames_recovers_the_model(tmp_path):
    """The Bayer calibrate test's tolerances: K 3 %, read σ 5 %, row σ 10 %, λ ± 0.05;
    the 36 sites of the period pooled into R, G and B, each with its dark bias."""
    p = CAL_SENSOR.profile
    (tmp_path / "flats").mkdir()
    (tmp_path / "darks").mkdir()
    seed = 0
    for iso in CAL_ISOS:
        info = DngInfo(
            p.cfa, p.black_level, p.white_level, p.xyz_to_camera, (0.5, 1.0, 0.6),
            "Canon", "EOS 70D", "Canon EOS 70D", iso,
        )  # fmt: skip
        for level in (0.3, 0.85):
            seed += 1
            flat = _cal_frame(iso, level, seed)
            write_dng(tmp_path / "flats" / f"f{iso}_{level}.dng", flat, info)
        for i in range(2):
            seed += 1
            dark = _cal_frame(iso, 0.0, seed, h=1020)
            write_dng(tmp_path / "darks" / f"d{iso}_{i}.dng", dark, info)
    out = tmp_path / "xt.json"
    args = ["calibrate", tmp_path / "flats", "--dark", tmp_path / "darks", "-o", out, "--json"]
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    fits = json.loads(r.stdout)
    assert [f["iso"] for f in fits] == list(CAL_ISOS)
    for fit in fits:
        levels = CAL_SENSOR.noise_levels(fit["iso"], "physics")
        assert fit["reliable"], fit["problems"]
        assert fit["K"] == pytest.approx(levels.gain, rel=0.03)
        read_std = math.sqrt(levels.read_variance - levels.row_sigma**2)
        assert fit["read_sigma"] == pytest.approx(read_std, rel=0.05)
        assert fit["row_sigma"] == pytest.approx(levels.row_sigma, rel=0.10)
        assert fit["lambda"] == pytest.approx(levels.tukey_lambda, abs=0.05)
        assert set(fit["channels"]) == {"R", "G", "B"}
        for name, bias in (("R", 2.0), ("G", 1.0), ("B", -1.0)):  # G: the mean of Gr, Gb
            assert fit["channels"][name]["K"] == pytest.approx(levels.gain, rel=0.05)
            assert fit["channels"][name]["bias"] == pytest.approx(bias, abs=0.5)
    profile = load_profile(out)
    assert profile.cfa == XT and profile.iso_range == (400.0, 6400.0)
    assert profile.noise.channel_bias[1] == profile.noise.channel_bias[2]
    assert np.allclose(profile.noise.channel_bias, (2.0, 1.0, 1.0, -1.0), atol=0.3)
    assert profile.noise.levels("physics", 1600).gain == pytest.approx(
        CAL_SENSOR.noise_levels(1600, "poisson-gaussian").gain, rel=0.03
    )
