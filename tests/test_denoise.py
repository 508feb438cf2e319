"""Raw denoising: the noise model's sources, the transform's unbiased inverse, the
profiled method (chunks, engine against torch, quality), and the CLI."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from rawsim.cameras.profiles import load_profile
from rawsim.cfa import CFA
from rawsim.denoise.noise_model import dng_noise_profile, noise_model_for
from rawsim.denoise.profiled import forward_vst, inverse_vst, profiled_denoise
from rawsim.engine.denoise import denoise_mosaic
from rawsim.errors import ParameterError
from rawsim.io.raw import read_raw
from rawsim.io.task import Task
from rawsim.isp.config import DenoiseStage, IspConfig, RawDenoiseStage
from rawsim.isp.filters import denoise as filter_denoise
from rawsim.pipelines.unprocess import UnprocessOptions, unprocess_file
from rawsim_cli.main import cli
from tests.conftest import DATA, psnr

KODAK = DATA / "kodak" / "kodim08_crop.png"
MLV = DATA / "raw" / "canon_eos60d_mlv.dng"


def _pair(tmp_path, profile, iso, src=KODAK, seed=1, noise="poisson-gaussian"):
    """(noisy, clean) RawImages of ``src`` unprocessed with ``profile`` at ``iso``."""
    options = UnprocessOptions(profile, iso=iso, clean=True, noise=noise)
    outputs = {k: tmp_path / f"{src.stem}{v}" for k, v in options.output_suffixes().items()}
    unprocess_file(Task(src, src.name, outputs, seed), options)
    return read_raw(outputs["dng"]), read_raw(outputs["clean_dng"])


def _normalised(raw, data=None):
    data = raw.data if data is None else data
    black = float(np.mean(raw.black_level))
    return (data.astype(np.float64) - black) / (raw.white_level - black)


def _model(raw):
    m = dng_noise_profile(raw)  # the DNG's own: the noise it was made with
    return m.normalised(raw.white_level - float(np.mean(raw.black_level)))


# ------------------------------------------------------------------ the noise model
def test_the_noise_model_is_taken_in_order(tmp_path):
    d850 = load_profile("nikon_d850")
    noisy, _ = _pair(tmp_path, d850, 6400)
    assert noise_model_for(noisy, "sony_a7s2").source == "profile"
    camera = noise_model_for(noisy)
    assert camera.source == "camera profile" and "nikon_d850" in camera.detail
    other = replace(d850, make="Nobody", model="Prototype 1")
    (tmp_path / "other").mkdir()
    noisy, _ = _pair(tmp_path / "other", other, 6400)
    tag = noise_model_for(noisy)
    assert tag.source == "dng"
    # the tag's figures are the profile's own at the ISO
    a, b = d850.noise.levels("poisson-gaussian", 6400).affine_variance(
        d850.white_level - d850.black_level
    )
    assert tag.a[1] == pytest.approx(a, rel=1e-9) and tag.b[1] == pytest.approx(b, rel=1e-9)
    real = noise_model_for(read_raw(MLV))  # a Canon 60D: no profile, no tag
    assert real.source == "estimate" and real.a[1] > 0 and real.b[1] > 0
    # the camera database's model is named beside the estimate, and taken when asked
    assert "camera database's estimated model for the Canon EOS 60D" in real.detail
    assert "(--noise-profile canon_eos_60d takes it)" in real.detail
    database = noise_model_for(read_raw(MLV), "canon_eos_60d")
    assert database.source == "profile" and f"K {database.a[1]:.4g} DN/e-" in real.detail


def test_large_raws_are_estimated_on_a_centred_crop_of_whole_periods():
    from rawsim.denoise.noise_model import ESTIMATE_SITES, _central

    raw = read_raw(MLV)
    big = replace(raw, data=np.tile(raw.data, (8, 7))[:4001, :6003])
    crop = _central(big)
    h, w = crop.data.shape
    assert h * w <= ESTIMATE_SITES and h % 2 == 0 and w % 2 == 0
    start = crop.data.__array_interface__["data"][0] - big.data.__array_interface__["data"][0]
    y0, x0 = divmod(start // crop.data.itemsize, big.data.strides[0] // big.data.itemsize)
    assert np.shares_memory(crop.data, big.data) and y0 % 2 == 0 and x0 % 2 == 0
    assert y0 > 0 and x0 > 0 and abs((y0 + h / 2) - 4001 / 2) < 2  # centred
    assert _central(raw) is raw


def test_a_profile_outside_its_iso_range_is_clamped_with_a_warning(tmp_path):
    noisy, _ = _pair(tmp_path, load_profile("nikon_d850"), 6400)
    model = noise_model_for(replace(noisy, iso=200000.0), "nikon_d850")
    assert any("outside profile" in w for w in model.warnings)


# ------------------------------------------------------------------ the transform
@pytest.mark.parametrize("gain, offset", [(4e-4, 1.6e-7), (6.6e-3, 2.6e-6), (1e-2, 1e-4)])
def test_the_transform_round_trip_is_unbiased_on_flat_fields(gain, offset):
    """An ideal denoiser in the transform's domain returns E[f]; the inverse must turn
    it into the mean: within 0.5 % of the noise σ at every level, photon-starved too."""
    rng = np.random.default_rng(0)
    n = 4_000_000
    for mu in [0.0, *np.geomspace(1e-4, 0.9, 12)]:
        x = gain * rng.poisson(mu / gain, n) + rng.normal(0, math.sqrt(offset), n)
        d = forward_vst(torch.from_numpy(x), gain, offset).mean()
        back = float(inverse_vst(d.reshape(1), gain, offset)[0])
        assert abs(back - mu) < 0.005 * math.sqrt(gain * mu + offset), mu


# ------------------------------------------------------------------ the method
def _synthetic(shape, gain=2e-3, offset=2e-5, seed=1):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    clean = 0.2 + 0.1 * np.sin(yy / 17.0) * np.cos(xx / 23.0)
    noisy = clean + rng.normal(0, 1, shape) * np.sqrt(gain * clean + offset)
    return clean, noisy


@pytest.mark.parametrize(
    "cfa, shape", [("RGGB", (301, 257)), ("GBRG", (96, 130)), ("XTRANS", (150, 216))]
)
def test_chunks_give_the_whole_images_result(cfa, shape):
    _, noisy = _synthetic(shape)
    x = torch.from_numpy(noisy).float()[None, None]
    args = (CFA(cfa), [2e-3] * 3, [2e-5] * 3)
    whole = profiled_denoise(x, *args, chunk=4096)
    for chunk in (16, 40):
        torch.testing.assert_close(
            profiled_denoise(x, *args, chunk=chunk), whole, atol=2e-6, rtol=0
        )


@pytest.mark.parametrize(
    "cfa, shape", [("RGGB", (301, 257)), ("BGGR", (200, 96)), ("XTRANS", (150, 216))]
)
def test_the_engine_equals_the_torch_reference(cfa, shape):
    black, white = 512.0, 16383.0
    clean, noisy = _synthetic(shape)
    dn = np.clip(np.round(noisy * (white - black) + black), 0, 65535).astype(np.uint16)
    dn[5:9, 20:30] = 16383  # clipped sites are kept
    x = torch.from_numpy((dn.astype(np.float32) - black) / (white - black))[None, None]
    ref = profiled_denoise(x, CFA(cfa), [2e-3] * 3, [2e-5] * 3)[0, 0].double().numpy()
    out = denoise_mosaic(dn, CFA(cfa), black, white, [2e-3] * 3, [2e-5] * 3)
    diff = np.abs(out.astype(np.float64) - (ref * (white - black) + black))
    assert diff.max() <= 1.0 and diff.mean() < 0.3  # rounding to DN, float32 sums
    assert (out[5:9, 20:30] == 16383).all()
    keep = np.ones(shape, bool)
    keep[:10] = False  # the clipped rows
    before = psnr(noisy[keep], clean[keep])
    assert psnr(_normalised_dn(out, black, white)[keep], clean[keep]) > before + 10


def _normalised_dn(dn, black, white):
    return (dn.astype(np.float64) - black) / (white - black)


def test_profiled_beats_bilateral_on_a_kodak_photo(tmp_path):
    noisy, clean = _pair(tmp_path, load_profile("nikon_d850"), 25600)
    truth = _normalised(clean)
    gain, offset = _model(noisy)
    ours = denoise_mosaic(noisy.data, noisy.cfa, noisy.black_level, noisy.white_level, gain, offset)
    x = torch.from_numpy(_normalised(noisy)).float()[None, None]
    sigma = math.sqrt(gain[1] * 0.18 + offset[1])
    bilateral = max(
        psnr(
            filter_denoise(x, noisy.cfa, "bilateral", 5, 1.0, k * sigma)[0, 0].double().numpy(),
            truth,
        )
        for k in (1.0, 2.0, 3.0)
    )
    before = psnr(_normalised(noisy), truth)
    after = psnr(_normalised(noisy, ours), truth)
    assert after > bilateral + 0.3 and after > before + 2.5, (before, bilateral, after)


def _denoised(method, raw, black, gain, offset):
    """The mosaic ``method`` (profiled or learned) gives for ``raw``, with the model."""
    out = denoise_mosaic(raw.data, raw.cfa, black, raw.white_level, gain, offset)
    if method == "learned":
        from rawsim.denoise.learned import refine_mosaic

        out = refine_mosaic(raw.data, out, raw.cfa, black, raw.white_level, gain, offset)
    return out


def test_real_noise_is_removed_and_nothing_else():
    """On the real raw (noise model estimated from it), the residual input − output
    follows the model: its variance within ±25 % of the model's at every level (eight
    bins of the denoised level), and it holds no image structure: its correlation with
    the output's 4th-order detail (calibrate's high-pass, which scene texture reaches)
    is below 0.05."""
    from rawsim.cameras.calibrate import high_pass

    raw = read_raw(MLV)
    model = noise_model_for(raw)
    assert model.source == "estimate"
    gain, offset = model.normalised(raw.white_level - float(np.mean(raw.black_level)))
    out = denoise_mosaic(raw.data, raw.cfa, raw.black_level, raw.white_level, gain, offset)
    x, y = _normalised(raw), _normalised(raw, out)
    residual = x - y
    edges = np.quantile(y, np.linspace(0.02, 0.98, 9))
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (y >= lo) & (y < hi)
        ratio = residual[sel].var() / (gain[1] * y[sel].mean() + offset[1])
        assert 0.75 <= ratio <= 1.25, (lo, ratio)
    detail = high_pass(y[None])[0]
    assert abs(np.corrcoef(residual[2:-2, 2:-2].ravel(), detail.ravel())[0, 1]) < 0.05


def _mean_bound(level: float, gain: float, offset: float, sites: int) -> float:
    """How far a denoiser may move a flat patch's mean (normalised units): 1 % of it, or
    3σ of the noisy mean where that is more (a denoiser that returned the truth would
    move the mean by about 1σ, which at a real chart's darkest patches exceeds 1 %)."""
    return max(0.01 * level, 3 * math.sqrt((gain * level + offset) / sites))


def test_a_noisy_charts_patches_flatten_and_keep_their_means():
    """The colour chart in the tests (synthetic, noise-free) with a D850's noise at ISO
    6400 added: inside every patch, each CFA plane's spread falls at least 3×, and each
    colour's mean moves by less than 1 % (patches above 5 % of white). ``profiled``
    only: ``learned`` flattens these patches less (spread down 2.2× at the darkest red
    patch) and adds spread to the planes a saturated patch leaves at 0, which natural
    photos, all it was trained on, do not have; on the real chart below it does."""
    raw = read_raw(DATA / "raw" / "synthetic_colorchecker_bggr.dng")
    black, white = float(np.mean(raw.black_level)), raw.white_level
    truth = _normalised(raw)
    gain, offset = 1.66e-3, 6.9e-7
    rng = np.random.default_rng(3)
    noisy = gain * rng.poisson(np.clip(truth, 0, None) / gain)
    noisy += rng.normal(0, math.sqrt(offset), truth.shape)
    dn = np.clip(np.round(noisy * (white - black) + black), 0, 65535).astype(np.uint16)
    out = denoise_mosaic(dn, raw.cfa, black, white, [gain] * 3, [offset] * 3)
    before, after = _normalised(raw, dn), _normalised(raw, out)
    h, w = truth.shape
    colours = np.array([[raw.cfa.color_at(i, j) for j in range(w)] for i in range(h)])
    for row in range(4):
        for col in range(6):
            y0, x0 = int((row + 0.5) * h / 4) // 2 * 2, int((col + 0.5) * w / 6) // 2 * 2
            cut = (slice(y0 - 16, y0 + 16), slice(x0 - 16, x0 + 16))  # 32 × 32 inside
            for oy in (0, 1):
                for ox in (0, 1):
                    plane = (slice(y0 - 16 + oy, y0 + 16, 2), slice(x0 - 16 + ox, x0 + 16, 2))
                    assert before[plane].std() > 3 * after[plane].std(), (row, col)
            for c in range(3):
                sites = colours[cut] == c
                if truth[cut][sites].mean() > 0.05:
                    mean = before[cut][sites].mean()
                    assert abs(after[cut][sites].mean() - mean) < 0.01 * mean, (row, col, c)


#: The lower page's 24 patches of the real chart: their centres (sensor rows, columns).
CHART_ROWS = (618, 722, 822, 926)
CHART_COLUMNS = (714, 822, 930, 1038, 1144, 1252)


@pytest.mark.parametrize("method", ["profiled", "learned"])
def test_a_real_charts_patches_flatten_and_keep_their_means(method):
    """The real ColorChecker raw (tests/data/chart, a Canon 550D shot at 0.2–9 % of
    white), noise model estimated from it: in a 40 × 40 window inside each of the
    lower page's 24 patches, each CFA plane's spread falls at least 3× (measured: at
    least 5.6× for profiled, 6.0× for learned), and its mean moves by less than
    :func:`_mean_bound` (measured: at most 0.29 of it for profiled, 0.31 for learned;
    learned's correction without its local mean removed reached 1.16)."""
    raw = read_raw(DATA / "chart" / "canon_550d_colorchecker.dng")
    model = noise_model_for(raw)
    gain, offset = model.normalised(raw.white_level - float(np.mean(raw.black_level)))
    out = _denoised(method, raw, np.asarray(raw.black_level, np.float64), gain, offset)
    before, after = _normalised(raw), _normalised(raw, out)
    for y in CHART_ROWS:
        for x in CHART_COLUMNS:
            for oy in (0, 1):
                for ox in (0, 1):
                    plane = (slice(y - 20 + oy, y + 20, 2), slice(x - 20 + ox, x + 20, 2))
                    b, a = before[plane], after[plane]
                    assert b.std() > 3 * a.std(), (y, x, oy, ox)
                    c = raw.cfa.color_at(oy, ox)
                    bound = _mean_bound(b.mean(), gain[c], offset[c], b.size)
                    assert abs(a.mean() - b.mean()) < bound, (y, x, oy, ox)


def test_the_torch_reference_is_differentiable():
    _, noisy = _synthetic((64, 64))
    x = torch.from_numpy(noisy).float()[None, None].requires_grad_()
    profiled_denoise(x, CFA("RGGB"), [2e-3] * 3, [2e-5] * 3).square().sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


def test_strength_scales_what_is_removed():
    _, noisy = _synthetic((128, 128))
    x = torch.from_numpy(noisy).float()[None, None]
    args = (CFA("RGGB"), [2e-3] * 3, [2e-5] * 3)
    weak, strong = profiled_denoise(x, *args, 0.5), profiled_denoise(x, *args, 2.0)
    assert float((x - weak).std()) < float((x - strong).std())


# ------------------------------------------------------------------ the ISP and the CLI
def test_the_stage_must_follow_the_black_level():
    tables = IspConfig.default().override(denoise="profiled").to_tables()
    assert [t["name"] for t in tables][:2] == ["black_level", "raw_denoise"]
    moved = [tables[0], *tables[2:6], tables[1], *tables[6:]]
    with pytest.raises(ParameterError, match="right after 'black_level'"):
        IspConfig.from_tables(moved)
    with pytest.raises(ParameterError, match="--noise-profile sets --denoise profiled"):
        IspConfig.default().override(denoise="bilateral", noise_profile="sony_a7s2")
    rgb = IspConfig.default().override(denoise="bilateral")
    assert not rgb.enabled_stage(RawDenoiseStage) and rgb.enabled_stage(DenoiseStage)


def test_process_denoises_and_records_the_model(tmp_path, monkeypatch):
    out = {}
    for engine in ("1", "0"):
        monkeypatch.setenv("RAWSIM_ENGINE", engine)
        folder = tmp_path / engine
        r = CliRunner().invoke(
            cli,
            [
                "process",
                str(MLV),
                "-o",
                str(folder),
                "--denoise",
                "profiled",
                "--format",
                "tiff",
                "--bits",
                "16",
                "-q",
            ],
        )
        assert r.exit_code == 0, r.output
        side = json.loads((folder / "canon_eos60d_mlv.process.json").read_text())
        assert side["noise_model"]["source"] == "estimate"
        import tifffile

        out[engine] = tifffile.imread(folder / "canon_eos60d_mlv.tif").astype(np.float64)
    assert np.abs(out["1"] - out["0"]).mean() < 40  # of 65535: DN rounding, float32 sums
    bad = CliRunner().invoke(
        cli,
        [
            "process",
            str(MLV),
            "-o",
            str(tmp_path / "x"),
            "--denoise",
            "profiled",
            "--noise-profile",
            "nope",
        ],
    )
    assert bad.exit_code == 2 and "unknown sensor profile 'nope'" in bad.output


@pytest.mark.slow
def test_memory_stays_flat_from_1_to_6_megapixels():
    """Peak memory of profiled and learned over the input and output mosaics: a few
    chunk buffers per thread (a few rows of the image's width each) and the network's
    tiles, about the same at 1.4 and 5.8 MP (and 24 MP: ``benchmarks/bench_memory.py``).
    Both sizes hold whole tiles of the network. Blocks of 128 kB and more are mapped
    and unmapped as they are allocated and freed (``MALLOC_MMAP_THRESHOLD_``), so the
    peak counts what was live, not what the allocator kept: without it the peak varies
    by 30 MB from run to run."""
    code = """
import resource, sys, numpy as np
from rawsim.cfa import CFA
from rawsim.denoise.learned import refine_mosaic
from rawsim.engine.denoise import denoise_mosaic
h, w = map(int, sys.argv[1:3])
data = np.full((h, w), 3000, np.uint16)
data[::7] += 40
model = [2e-3] * 3, [2e-5] * 3
small = data[:64, :64].copy()
refine_mosaic(small, denoise_mosaic(small, CFA("RGGB"), 512, 16383, *model), CFA("RGGB"), 512,
              16383, *model)  # loads the kernel, torch and the weights
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
out = denoise_mosaic(data, CFA("RGGB"), 512, 16383, *model)
out = refine_mosaic(data, out, CFA("RGGB"), 512, 16383, *model)
print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) * 1024 - 2 * out.nbytes)
"""
    extra = {}
    env = {**os.environ, "MALLOC_MMAP_THRESHOLD_": str(128 * 2**10)}
    for h, w in ((1200, 1200), (2400, 2400)):
        run = subprocess.run(
            [sys.executable, "-c", code, str(h), str(w)],
            capture_output=True, text=True, check=True, env=env,
        )  # fmt: skip
        extra[h * w] = int(run.stdout.split()[-1])
    small, large = extra[1200 * 1200], extra[2400 * 2400]
    # 4.3 MP more would cost 17 MB per float32 copy of the mosaic, 8.6 per uint16 one
    assert large - small < 8 * 2**20 and large < 256 * 2**20, extra


# ------------------------------------------------------------------ learned
@pytest.mark.parametrize("kind", ["bayer", "xtrans"])
def test_the_weights_load_from_the_package_and_are_not_pickle(kind):
    from importlib import resources

    from rawsim.denoise.learned import INPUTS, WEIGHTS, RefineNet, load_network

    path = resources.files("rawsim.denoise") / "weights" / WEIGHTS[kind]
    data = path.read_bytes()
    assert len(data) < 10 * 2**20
    header = json.loads(data[8 : 8 + int.from_bytes(data[:8], "little")])  # safetensors
    net = load_network(kind)
    assert set(header) - {"__metadata__"} == set(net.state_dict())
    assert net.head[0].in_channels == INPUTS[kind]
    assert sum(p.numel() for p in net.parameters()) == sum(
        p.numel() for p in RefineNet(inputs=INPUTS[kind]).parameters()
    )


def test_which_weights_serve_a_cfa_and_how_its_blocks_are_packed():
    from rawsim.denoise.layout import BLOCK_SITES, packing, weights_kind
    from rawsim.denoise.learned import plane_maps, site_inputs

    assert weights_kind(CFA("GRBG")) == "bayer" and packing(CFA("GRBG"))[0] == (0, 1)
    xtrans = CFA("XTRANS")
    assert weights_kind(xtrans) == "xtrans" and packing(xtrans) == BLOCK_SITES
    assert weights_kind(CFA("GRG/BGB/GRG")) is None
    # an X-Trans block's colours follow the pattern, one packed period every 3 pixels
    colours = np.array(xtrans.colors).reshape(6, 6)
    maps = plane_maps(xtrans, colours, slice(1, 5), slice(2, 9))
    for k, (r, c) in enumerate(BLOCK_SITES):
        for i, y in enumerate(range(1, 5)):
            for j, x in enumerate(range(2, 9)):
                assert maps[k, i, j] == xtrans.color_at(2 * y + r, 2 * x + c)
    g, o, onehot = site_inputs(xtrans, [1.0, 2.0, 3.0], [0.1, 0.2, 0.3], slice(0, 3), slice(0, 3))
    assert onehot.shape == (12, 3, 3) and np.all(onehot.reshape(4, 3, 3, 3).sum(1) == 1)
    expected = np.float32([1.0, 2.0, 3.0])[plane_maps(xtrans, colours, slice(0, 3), slice(0, 3))]
    np.testing.assert_array_equal(g, expected)
    g, o, onehot = site_inputs(
        CFA("RGGB"), [1.0, 2.0, 3.0], [0.1, 0.2, 0.3], slice(0, 3), slice(0, 3)
    )
    assert onehot is None and g.ravel().tolist() == [1.0, 2.0, 2.0, 3.0]


@pytest.mark.parametrize("pattern", ["RGGB", "XTRANS"])
def test_learned_tiles_give_the_whole_images_result(monkeypatch, pattern):
    import rawsim.denoise.learned as learned

    rng = np.random.default_rng(2)
    noisy = torch.from_numpy(rng.random((1, 4, 300, 270), dtype=np.float32) * 0.3)
    estimate = noisy + 0.01
    cfa = CFA(pattern)
    with torch.no_grad():
        tiled = learned.refine(noisy, estimate, cfa, [2e-3] * 3, [2e-5] * 3)
        monkeypatch.setattr(learned, "TILE", 4096)
        whole = learned.refine(noisy, estimate, cfa, [2e-3] * 3, [2e-5] * 3)
    assert float((tiled - estimate).abs().max()) > 1e-3  # the network does something
    torch.testing.assert_close(tiled, whole, atol=1e-5, rtol=0)


@pytest.mark.parametrize(
    ("profile", "iso", "noise"),
    [
        ("nikon_d850", 25600, "poisson-gaussian"),
        ("fujifilm_xt3", 12800, "poisson-gaussian"),
        # a phone's own colour (white-balance gains near 1) and its physics noise: the
        # weights trained on the randomised ISP alone lost 0.5 dB to profiled here
        ("sony_imx686", 3200, "physics"),
    ],
)
def test_learned_engine_equals_torch_and_beats_profiled(tmp_path, profile, iso, noise):
    from rawsim.denoise.learned import learned_denoise, refine_mosaic

    noisy, clean = _pair(tmp_path, load_profile(profile), iso, noise=noise)
    gain, offset = _model(noisy)
    black = float(np.mean(noisy.black_level))
    estimate = denoise_mosaic(noisy.data, noisy.cfa, black, noisy.white_level, gain, offset)
    ours = refine_mosaic(noisy.data, estimate, noisy.cfa, black, noisy.white_level, gain, offset)
    x = torch.from_numpy(_normalised(noisy)).float()[None, None]
    with torch.no_grad():
        ref = learned_denoise(x, noisy.cfa, gain, offset)[0, 0].double().numpy()
    diff = np.abs(_normalised(noisy, ours) - ref) * (noisy.white_level - black)
    assert diff.mean() < 0.5 and diff.max() <= 8  # DN: rounding, float32 sums
    truth = _normalised(clean)
    gained = psnr(_normalised(noisy, ours), truth) - psnr(_normalised(noisy, estimate), truth)
    assert gained > 0.2, gained


def test_learned_runs_on_x_trans_and_falls_back_only_where_no_weights_serve(tmp_path):
    from rawsim.isp.config import resolve

    noisy, _ = _pair(tmp_path, load_profile("fujifilm_xt3"), 3200)
    config = IspConfig.default().override(denoise="learned")
    info = resolve(config, noisy).info
    assert info["raw_denoise"] == "learned"
    assert not any("--denoise profiled" in w for w in info["warnings"])
    odd = replace(noisy, cfa=CFA("GRG/BGB/GRG"), black_level=float(np.mean(noisy.black_level)))
    info = resolve(config, odd).info
    assert info["raw_denoise"] == "profiled"
    assert any("--denoise profiled" in w and "GRG/BGB/GRG" in w for w in info["warnings"])


@pytest.mark.slow
def test_training_runs_a_few_steps(tmp_path):
    from rawsim.denoise.training.train import main

    out = tmp_path / "w.safetensors"
    main(
        [
            "--images",
            str(DATA / "srgb"),
            "--work",
            str(tmp_path),
            "--steps",
            "3",
            "--profiles",
            "sony_a7s2",
            "--seeds",
            "1",
            "--out",
            str(out),
        ]
    )
    from safetensors.torch import load_file

    from rawsim.denoise.learned import RefineNet

    RefineNet().load_state_dict(load_file(str(out)))
    # both of the profile's variants were made: the randomised ISP with Poisson-Gaussian
    # noise, and its own colour with the physics model
    made = sorted(d.name for d in (tmp_path / "pairs").iterdir())
    assert made == ["sony_a7s2_physics_own_1", "sony_a7s2_poisson-gaussian_random_1"]
