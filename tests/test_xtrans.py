"""X-Trans: the 6×6 CFA value, its demosaics (torch and engine) and LibRaw's view of both."""

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import torch

from rawsim.cfa import BAYER_PATTERNS, CFA, XTRANS, phase_reflect_index
from rawsim.engine import xtrans as engine
from rawsim.errors import ParameterError
from rawsim.io.dng import DngInfo, write_dng
from rawsim.isp import xtrans
from rawsim.isp.demosaic import from_root, to_root
from rawsim.isp.xtrans import XTransDemosaic, demosaic_xtrans
from tests.conftest import DATA, cpsnr, libraw_linear, psnr

XT = CFA("XTRANS")


def _dng(path, mosaic: np.ndarray, cfa=XT):
    info = DngInfo(cfa, 0, 65535, ((1, 0, 0), (0, 1, 0), (0, 0, 1)), (1, 1, 1), "t", "t", "t", 100)
    write_dng(path, np.round(np.clip(mosaic, 0, 1) * 65535).astype(np.uint16), info)


def _photo(name="coffee.png") -> torch.Tensor:
    """A vendored photo, linearised, mirrored 2×2 to reach LibRaw's X-Trans minimum (≥ 600 px)."""
    x = oiio.ImageBuf(str(DATA / "srgb" / name)).get_pixels(oiio.FLOAT)[:, :, :3]
    x = torch.from_numpy(np.ascontiguousarray(x)).permute(2, 0, 1)[None]
    x = torch.cat([x, x.flip(-1)], -1)
    return torch.cat([x, x.flip(-2)], -2) ** 2.2


# ----------------------------------------------------------------- the CFA
def test_xtrans_layout_is_what_libraw_reads(tmp_path):
    path = tmp_path / "x.dng"
    _dng(path, np.random.default_rng(0).random((60, 72)))
    with rawpy.imread(str(path)) as raw:
        pattern, desc = raw.raw_pattern.copy(), raw.color_desc
    assert pattern.shape == (6, 6)
    assert CFA.from_rawpy(pattern, desc) == XT
    letters = ["".join(desc.decode()[i] for i in row) for row in pattern]
    assert "/".join(letters) == XTRANS  # CFAPattern, row-major, is LibRaw's xtrans array


def test_xtrans_value():
    assert XT.pattern == XTRANS and XT.name == "XTRANS" and XT.period == (6, 6)
    assert not XT.is_bayer and all(CFA(p).is_bayer for p in BAYER_PATTERNS)
    assert CFA("xtrans") == CFA(XTRANS.lower()) == XT
    assert CFA("RG/GB").pattern == "RGGB"  # a 2×2 layout keeps its Bayer name
    counts = np.bincount(XT.colors)
    assert counts.tolist() == [8, 20, 8]
    for y in range(6):  # every row and column holds R and B; every 3×3 all three
        assert {XT.color_at(y, x) for x in range(6)} == {0, 1, 2}
        assert {XT.color_at(x, y) for x in range(6)} == {0, 1, 2}
    for y in range(6):
        for x in range(6):
            assert {XT.color_at(y + a, x + b) for a in (-1, 0, 1) for b in (-1, 0, 1)} == {0, 1, 2}
    assert XT.dng_repeat == (6, 6) and len(XT.dng_pattern) == 36


def test_bad_patterns_and_bayer_only_operations():
    assert CFA("RGB/GGG").period == (2, 3)  # any layout holding R, G and B
    with pytest.raises(ParameterError, match="valid: RGGB, BGGR, GRBG, GBRG, XTRANS"):
        CFA("RG/GR")  # no blue
    with pytest.raises(ParameterError, match="valid"):
        CFA("RGB/GB")  # ragged
    with pytest.raises(ParameterError, match="Bayer patterns only.*6×6"):
        XT.pack(torch.rand(1, 1, 12, 12))
    with pytest.raises(ParameterError, match="Bayer patterns only"):
        XT.site_masks(12, 12)


def test_mosaic_unmosaic_any_size(rng):
    rgb = torch.rand(2, 3, 13, 17, generator=rng)
    m = XT.mosaic(rgb)
    assert m.shape == (2, 1, 13, 17)
    cmap = XT.color_map(13, 17)
    assert torch.equal(m, rgb.gather(1, cmap.expand(2, 1, 13, 17)))
    masks = XT.masks(13, 17)
    assert masks.sum(0).eq(1).all()
    assert torch.equal(XT.mosaic(XT.unmosaic(m)), m)
    sparse = XT.unmosaic(m)
    assert torch.equal(sparse[:, masks.bool()], rgb[:, masks.bool()])
    assert torch.equal(XT.tile(torch.tensor([1.0, 2.0, 3.0]))[0], 1.0 + cmap[0, 0, :6, :6])


def test_phase_reflect_index():
    for n, period in ((20, 6), (31, 6), (10, 2)):
        idx = phase_reflect_index(n, 6, period)
        v = np.arange(-6, n + 6)
        assert np.array_equal(idx % period, v % period) and idx.min() >= 0 and idx.max() < n
    assert np.array_equal(phase_reflect_index(10, 2, 2), [2, 1, *range(10), 8, 7])  # reflect


# -------------------------------------------------------------- demosaics
@pytest.mark.parametrize("method", xtrans.XTRANS_DEMOSAIC_METHODS)
def test_flat_colour_exact_and_sites_kept(method, rng):
    x = torch.ones(2, 3, 30, 25) * torch.tensor([0.2, 0.5, 0.7]).view(1, 3, 1, 1)
    assert torch.allclose(demosaic_xtrans(XT.mosaic(x), XT, method), x, atol=1e-6)
    m = torch.rand(1, 1, 30, 31, generator=rng)
    assert torch.allclose(XT.mosaic(demosaic_xtrans(m, XT, method)), m, atol=1e-6)


def test_bilinear_matches_libraw_quality_0(tmp_path):
    x = _photo()
    m = XT.mosaic(x)
    path = tmp_path / "x.dng"
    _dng(path, m[0, 0].numpy())
    # LibRaw does its 1-pixel border separately
    ref = libraw_linear(path, rawpy.DemosaicAlgorithm(0))[..., 2:-2, 2:-2]
    q = torch.round(m * 65535) / 65535  # the 16-bit codes LibRaw reads
    ours = demosaic_xtrans(q, XT, "bilinear")[..., 2:-2, 2:-2]
    # LibRaw normalises by ⌊256 / Σw⌋ / 256 and truncates: ≤ 1.6 % low, and one code
    diff = ours - ref
    assert float(diff.min()) >= -1.5 / 65535
    assert bool((diff <= 0.0165 * ours + 1.5 / 65535).all())
    local = torch.nn.functional.avg_pool2d
    mse = float(((local(ours, 8) - local(ref, 8)) ** 2).mean())
    assert 10 * np.log10(1 / mse) > 45


@pytest.fixture(scope="module")
def linear_photo_scores(tmp_path_factory):
    """CPSNR of LibRaw's linear, 1-pass and 3-pass Markesteijn and of ours on a linear photo."""
    x = _photo()
    m = XT.mosaic(x)
    path = tmp_path_factory.mktemp("xt") / "x.dng"
    _dng(path, m[0, 0].numpy())
    scores = {}
    for q in (0, 1, 3):
        scores[f"libraw{q}"] = cpsnr(libraw_linear(path, rawpy.DemosaicAlgorithm(q)), x, 12)
    scores["bilinear"] = cpsnr(demosaic_xtrans(m, XT, "bilinear"), x, 12)  # as LibRaw's
    scores["icd"] = cpsnr(from_root(demosaic_xtrans(to_root(m), XT, "icd")), x, 12)
    scores["icd as coded"] = cpsnr(demosaic_xtrans(m, XT, "icd"), x, 12)
    return scores


@pytest.mark.slow
def test_icd_beats_libraw_markesteijn_on_a_linear_photo(linear_photo_scores):
    """On linear data (a raw's), icd on square roots (as the pipeline runs it) beats
    LibRaw's 3-pass Markesteijn (by 1.0 dB here; 2.5 dB on the Kodak set,
    bench_xtrans.py) and its own run on the linear values."""
    s = linear_photo_scores
    assert abs(s["bilinear"] - s["libraw0"]) < 0.3, s  # the same demosaic as quality 0
    assert s["icd"] > s["libraw3"] + 0.5, s
    assert s["icd"] > s["icd as coded"] + 1.0, s


@pytest.mark.parametrize("method", xtrans.XTRANS_DEMOSAIC_METHODS)
@pytest.mark.parametrize("shape", [(53, 61), (48, 96)])
def test_engine_equals_torch(method, shape, rng):
    x = torch.rand(1, 3, *shape, generator=rng) * torch.linspace(0.2, 1.5, shape[1])
    m = XT.mosaic(x)
    ref = demosaic_xtrans(m, XT, method)[0].numpy()
    ours = engine.demosaic_xtrans(m[0, 0].numpy(), XT, method)
    assert ours.shape == ref.shape and ours.dtype == np.float32
    assert np.abs(ours - ref).max() <= 1e-5 * max(1.0, float(np.abs(ref).max()))


@pytest.mark.parametrize(
    ("method", "fast"),
    [("bilinear", False), ("icd", True), pytest.param("icd", False, marks=pytest.mark.slow)],
    ids=["bilinear", "icd", "icd-whole"],
)
def test_gradcheck(method, fast):
    """The whole Jacobian for bilinear; random projections of it for icd (``fast_mode``),
    and the whole one in the slow tier."""
    m = torch.rand(1, 1, 12, 12, dtype=torch.float64, requires_grad=True) + 0.1
    assert torch.autograd.gradcheck(
        lambda v: demosaic_xtrans(v, XT, method, 1), (m,), atol=1e-5, fast_mode=fast
    )


def test_errors_and_module():
    with pytest.raises(ParameterError, match="valid: icd, bilinear"):
        demosaic_xtrans(torch.rand(1, 1, 30, 30), XT, "menon")
    with pytest.raises(ParameterError, match="1 channel"):
        demosaic_xtrans(torch.rand(1, 3, 30, 30), XT)
    with pytest.raises(ParameterError, match="NaN"):
        demosaic_xtrans(torch.full((1, 1, 30, 30), float("nan")), XT)
    with pytest.raises(ParameterError, match="at least 18×18"):
        demosaic_xtrans(torch.rand(1, 1, 17, 40), XT)
    with pytest.raises(ParameterError, match="NaN"):
        engine.demosaic_xtrans(np.full((30, 30), np.nan, np.float32), XT)
    with pytest.raises(ParameterError, match="at least"):
        engine.demosaic_xtrans(np.zeros((10, 30), np.float32), XT)
    with pytest.raises(ParameterError, match=r"\(H, W\)"):
        engine.demosaic_xtrans(np.zeros((1, 30, 30), np.float32), XT)
    module = XTransDemosaic(XT, "bilinear")
    x = torch.rand(1, 3, 24, 24)
    assert torch.equal(module.reverse(x), XT.mosaic(x))
    assert torch.equal(module(XT.mosaic(x)), demosaic_xtrans(XT.mosaic(x), XT, "bilinear"))


# ------------------------------------------------------------ rawsim process
@pytest.fixture(scope="module")
def camera_dng(tmp_path_factory):
    """An X-Trans DNG of a vendored photo as a camera records it: the A7S II's colour
    matrix, an as-shot white balance, black 512, white 16383, 90 % of full scale;
    (path, the photo as linear sRGB)."""
    from rawsim.cameras.profiles import load_profile
    from rawsim.color import camera_from_srgb

    xyz_to_camera = np.asarray(load_profile("sony_a7s2").xyz_to_camera)
    photo = _photo()
    cam = torch.einsum(
        "ij,bjhw->bihw",
        torch.as_tensor(camera_from_srgb(xyz_to_camera), dtype=torch.float32),
        photo,
    )
    neutral = (0.5, 1.0, 0.7)
    mosaic = XT.mosaic((cam * torch.tensor(neutral).view(1, 3, 1, 1)).clamp(0, 1))[0, 0].numpy()
    black, white = 512, 16383
    path = tmp_path_factory.mktemp("xtrans") / "xtrans.dng"
    info = DngInfo(
        XT, black, white, tuple(map(tuple, xyz_to_camera)), neutral, "Fujifilm", "X-Test", "X", 400
    )
    write_dng(path, np.round(black + mosaic * (white - black) * 0.9).astype(np.uint16), info)
    return path, photo * 0.9


def _render(path, **flags) -> np.ndarray:
    from rawsim.io.raw import read_raw
    from rawsim.isp.config import default_config, override
    from rawsim.pipelines.process import render

    out, _ = render(read_raw(path), override(default_config(), baseline_exposure="ignore", **flags))
    return np.clip(out[0].permute(1, 2, 0).numpy(), 0, 1)


def test_xtrans_colour_agrees_with_libraw(camera_dng):
    """Matched settings (camera white balance, bilinear, sRGB, clip, every colour
    saturating at the white level): ≥ 40 dB on 8×8 local means against LibRaw's render
    of the same raw (the photo's clipped colours pile up at 90 % of white, which
    rawsim's default takes for their saturation)."""
    from scipy.ndimage import uniform_filter

    from tests.test_process import LIBRAW_MATCHED

    path, _ = camera_dng
    ours = _render(path, demosaic="bilinear", wb="camera", saturation="white")
    with rawpy.imread(str(path)) as raw:
        ref = raw.postprocess(
            output_color=rawpy.ColorSpace.sRGB, gamma=(2.4, 12.92), **LIBRAW_MATCHED
        )
    assert ours.shape == ref.shape
    local = [uniform_filter(x, (8, 8, 1))[10:-10, 10:-10] for x in (ours, ref / 65535.0)]
    assert psnr(local[0], local[1]) >= 40


def test_the_default_xtrans_render_is_the_photo(camera_dng):
    """The default config (``wcd``, which is ``icd`` on X-Trans) returns the photo, and
    better than the bilinear average does."""
    from rawsim.isp.transfer import srgb_encode

    path, linear = camera_dng
    truth = srgb_encode(linear.clamp(0, 1))[0].permute(1, 2, 0).numpy()[12:-12, 12:-12]
    default = psnr(_render(path)[12:-12, 12:-12], truth)
    bilinear = psnr(_render(path, demosaic="bilinear")[12:-12, 12:-12], truth)
    assert default >= 29 and default > bilinear + 4, (default, bilinear)


def test_strips_keep_the_xtrans_phase(camera_dng):
    """Without gradients the ISP runs in strips of whole 6×6 periods: the same image."""
    from rawsim.io.raw import read_raw
    from rawsim.isp.config import default_config
    from rawsim.isp.pipeline import build_isp
    from rawsim.pipelines.process import raw_tensor

    raw = read_raw(camera_dng[0])
    isp = build_isp(default_config(), raw)
    x = raw_tensor(raw, "cpu")
    assert isp.halo % 6 == 0 and isp.strip_rows % 6 == 0 and x.shape[-2] > 2 * isp.strip_rows
    with torch.no_grad():
        strips = isp(x)
    with torch.enable_grad():
        whole = isp(x)
    assert torch.allclose(strips, whole.detach(), atol=1e-6)


def test_cli_processes_and_describes_xtrans(camera_dng, tmp_path):
    from click.testing import CliRunner

    from rawsim_cli.main import cli

    path, _ = camera_dng
    info = CliRunner().invoke(cli, ["info", str(path)])
    assert info.exit_code == 0, info.output
    assert XTRANS in info.output  # the whole 6×6 pattern
    done = CliRunner().invoke(cli, ["process", str(path), "-o", str(tmp_path), "--format", "tiff"])
    assert done.exit_code == 0, done.output
    assert (tmp_path / "xtrans.tif").exists()


def test_the_stage_runs_the_compiled_twin_without_gradients(rng, monkeypatch):
    from rawsim.engine import xtrans as kernels

    x = torch.rand(2, 3, 48, 60, generator=rng)
    m = XT.mosaic(x)
    stage = XTransDemosaic(XT)
    calls = []
    original = kernels.demosaic_xtrans
    monkeypatch.setattr(
        kernels, "demosaic_xtrans", lambda *a: calls.append(a[0].shape) or original(*a)
    )
    with torch.no_grad():
        fast = stage(m)
    assert calls == [(48, 60), (48, 60)]  # each sample of the batch, compiled
    reference = demosaic_xtrans(m, XT)
    with torch.no_grad():  # float64 stays on torch
        assert torch.equal(stage(m.double()), demosaic_xtrans(m.double(), XT))
    assert torch.allclose(fast, reference, rtol=1e-5, atol=1e-6)
