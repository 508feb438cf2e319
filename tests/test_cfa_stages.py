"""Every CFA-aware stage on any periodic pattern (X-Trans, 3×3, 2×3 as well as Bayer), the
ISP's strips on them, and raws rawsim cannot render: what LibRaw makes of each odd kind,
and the one line (or the render) rawsim gives for it."""

import json
import math
import pickle

import numpy as np
import pytest
import rawpy
import tifffile
import torch
from click.testing import CliRunner

from rawsim.cfa import BAYER_PATTERNS, CFA
from rawsim.errors import ParameterError, UnsupportedInputError
from rawsim.io.dng import DngInfo, dng_tags, write_dng
from rawsim.io.raw import UnrenderableRawError, read_raw
from rawsim.io.tiff import ASCII, BYTE, DOUBLE, LONG, RATIONAL, SHORT, SRATIONAL
from rawsim.isp.config import IspConfig, override
from rawsim.isp.dead_pixel import DeadPixelCorrection, correct_dead_pixels
from rawsim.isp.filters import AntiAliasing, Denoise, anti_alias, denoise
from rawsim.isp.highlights import Highlights, handle_highlights
from rawsim.isp.lens_shading import LensShading, radial_gain
from rawsim.isp.pipeline import build_isp
from rawsim.isp.planes import same_colour_offsets
from rawsim.pipelines.process import raw_tensor, render
from rawsim_cli.main import cli
from tests.conftest import DATA, psnr

XT = CFA("XTRANS")
#: Every kind of layout: the Bayer four, X-Trans, a 3×3 and a 2×3 period.
ALL_PATTERNS = (*BAYER_PATTERNS, "XTRANS", "GRG/BGB/GRG", "RGB/GGG")
#: The mosaic filters (stage module, the same as a function call).
FILTERS = {
    "dead_pixel": (
        lambda c: DeadPixelCorrection(c, threshold=0.2, temperature=0.05),
        lambda m, c: correct_dead_pixels(m, c, 0.2, 3, 0.05),
    ),
    "dead_pixel_5": (
        lambda c: DeadPixelCorrection(c, kernel=5),
        lambda m, c: correct_dead_pixels(m, c, kernel=5),
    ),
    "anti_alias": (lambda c: AntiAliasing(c), lambda m, c: anti_alias(m, c)),
    "anti_alias_gaussian": (
        lambda c: AntiAliasing(c, "gaussian", 0.8),
        lambda m, c: anti_alias(m, c, "gaussian", 0.8),
    ),
    "denoise_gaussian": (
        lambda c: Denoise(c, "gaussian", 3, 1.0),
        lambda m, c: denoise(m, c, "gaussian", 3, 1.0),
    ),
    "denoise_bilateral": (
        lambda c: Denoise(c, "bilateral", 3, 1.0, 0.2),
        lambda m, c: denoise(m, c, "bilateral", 3, 1.0, 0.2),
    ),
}


def _flat(cfa: CFA, h=24, w=30, batch=2) -> torch.Tensor:
    """The mosaic of a flat colour scene (a different level per colour)."""
    rgb = torch.tensor([0.5, 0.3, 0.2]).view(1, 3, 1, 1).expand(batch, 3, h, w)
    return cfa.mosaic(rgb.contiguous())


# ------------------------------------------------------------------ the stages
@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("pattern", ALL_PATTERNS)
def test_filters_keep_shape_and_colours_on_every_cfa(name, pattern):
    """A flat colour scene passes every mosaic filter unchanged: no colour leaks into
    another, whatever the pattern; the module equals the function."""
    module, function = FILTERS[name]
    cfa = CFA(pattern)
    m = _flat(cfa)
    out = module(cfa)(m)
    assert out.shape == m.shape
    assert torch.allclose(out, m, atol=1e-6)
    noisy = m + 0.05 * torch.rand(m.shape, generator=torch.Generator().manual_seed(1))
    assert torch.equal(module(cfa)(noisy), function(noisy, cfa))
    assert torch.equal(module(cfa).reverse(noisy), noisy)


@pytest.mark.parametrize("pattern", ALL_PATTERNS)
def test_lens_shading_and_highlights_act_site_by_site_on_every_cfa(pattern):
    cfa = CFA(pattern)
    m = _flat(cfa, batch=1) * 2.5  # red above white
    shaded = LensShading()(m)
    assert torch.allclose(shaded, m * radial_gain(24, 30), atol=1e-6)
    assert float(radial_gain(24, 30, dtype=torch.float64)[0, 0, 0, 0]) == pytest.approx(1.5)
    assert torch.allclose(LensShading().reverse(shaded), m, atol=1e-6)
    clipped = Highlights("clip")(m)
    assert torch.equal(clipped, handle_highlights(m, "clip"))
    assert torch.equal(clipped, m.clamp(max=1.0)) and float(m.max()) > 1.0


# The X-Trans red site (0, 2) of the period and its red neighbours within 2 pixels,
# read off the pattern's rows (GGRGGB/GGBGGR/BRGRBG/GGBGGR/GGRGGB/RBGBRG): row −2
# (period row 4) has R at column 2, row −1 (row 5) at columns 0 and 4, row +2 (row 2)
# at columns 1 and 3; rows 0 and +1 have none but the site itself.
RED_OFFSETS = ((-2, 0), (-1, -2), (-1, 2), (0, 0), (2, -1), (2, 1))
SITE = (6, 8)  # that site, one period in


def test_xtrans_neighbour_lists():
    assert same_colour_offsets(XT, 2, True)[2] == RED_OFFSETS
    counts = {len(o) for o in same_colour_offsets(XT, 2, False)}
    assert counts == {5, 12, 16}  # red and blue 5; green 12 or 16
    # On a Bayer layout written as a 2×4 period, red sees its plane's 3×3 window.
    bayer = same_colour_offsets(CFA("RGRG/GBGB"), 2, True)[0]
    assert bayer == tuple((dy, dx) for dy in (-2, 0, 2) for dx in (-2, 0, 2))


def _impulse(at, value=1.0, size=18) -> torch.Tensor:
    m = torch.zeros(1, 1, size, size, dtype=torch.float64)
    m[0, 0, at[0], at[1]] = value
    return m


def test_xtrans_weighted_average_golden():
    """The tent (1 − |dy|/4)(1 − |dx|/4) at the red offsets: 0.5 at (−2, 0), 0.375 at the
    four others, 1 at the site; sum 3."""
    y, x = SITE
    assert float(anti_alias(_impulse(SITE), XT)[0, 0, y, x]) == pytest.approx(1 / 3)
    assert float(anti_alias(_impulse((y - 2, x)), XT)[0, 0, y, x]) == pytest.approx(1 / 6)
    assert float(anti_alias(_impulse((y + 2, x + 1)), XT)[0, 0, y, x]) == pytest.approx(0.125)
    # a green site beside it does not reach it
    assert float(anti_alias(_impulse((y, x + 1)), XT)[0, 0, y, x]) == 0.0


def test_xtrans_gaussian_golden():
    """exp(−d² / (2 (2σ)²)) at the red offsets, σ in plane pixels (2 mosaic pixels)."""
    y, x = SITE
    total = 1 + math.exp(-4 / 8) + 4 * math.exp(-5 / 8)  # σ = 1
    out = denoise(_impulse((y - 2, x)), XT, "gaussian", 3, 1.0)
    assert float(out[0, 0, y, x]) == pytest.approx(math.exp(-4 / 8) / total)
    total = 1 + math.exp(-4 / 1.28) + 4 * math.exp(-5 / 1.28)  # σ = 0.4: a 3×3 window
    out = anti_alias(_impulse((y - 1, x + 2)), XT, "gaussian", 0.4)
    assert float(out[0, 0, y, x]) == pytest.approx(math.exp(-5 / 1.28) / total)


def test_xtrans_bilateral_golden():
    """One red neighbour 0.1 above the rest (all 0), range σ 0.1: its weight falls by
    exp(−½)."""
    y, x = SITE
    out = denoise(_impulse((y - 2, x), 0.1), XT, "bilateral", 3, 1.0, 0.1)
    spatial = {(dy, dx): math.exp(-(dy * dy + dx * dx) / 8) for dy, dx in RED_OFFSETS}
    w = spatial[(-2, 0)] * math.exp(-0.5)
    expected = w * 0.1 / (sum(spatial.values()) - spatial[(-2, 0)] + w)
    assert float(out[0, 0, y, x]) == pytest.approx(expected)


def test_xtrans_dead_pixel_golden():
    """A hot red site takes the median of its 5 red neighbours (0.1 … 0.5 → 0.3); its
    green neighbours do not count."""
    y, x = SITE
    m = torch.full((1, 1, 18, 18), 0.9, dtype=torch.float64)  # greens and blues
    for k, (dy, dx) in enumerate(o for o in RED_OFFSETS if o != (0, 0)):
        m[0, 0, y + dy, x + dx] = 0.1 * (k + 1)
    m[0, 0, y, x] = 5.0
    out = correct_dead_pixels(m, XT, threshold=0.1, temperature=1e-4)
    assert float(out[0, 0, y, x]) == pytest.approx(0.3)
    assert float(out[0, 0, y, x + 1]) == pytest.approx(0.9)  # the green beside it is kept


@pytest.mark.parametrize("name", FILTERS)
def test_other_patterns_see_what_bayer_planes_see(name):
    """Written as a 2×4 period, a Bayer layout goes through the per-site path: at red and
    blue sites (one plane each in both views) it gives what the packed planes give,
    inside the image (the two extend the edges differently). Greens differ by design:
    the planes keep Gr and Gb apart, other patterns have one green."""
    _, function = FILTERS[name]
    m = torch.rand(1, 1, 40, 48, generator=torch.Generator().manual_seed(3))
    bayer, written = CFA("RGGB"), CFA("RGRG/GBGB")
    assert written.pattern != bayer.pattern and not written.is_bayer
    red_blue = bayer.masks(40, 48)[[0, 2]].sum(0).bool()
    inside = torch.zeros(40, 48, dtype=torch.bool)
    inside[6:-6, 6:-6] = True
    diff = (function(m, bayer) - function(m, written))[0, 0]
    assert float(diff[red_blue & inside].abs().max()) < 1e-6


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("pattern", ["XTRANS", "GRG/BGB/GRG"])
def test_gradcheck_on_other_patterns(name, pattern):
    """The whole Jacobian on the 3 × 3 pattern; random projections of it on X-Trans,
    whose 6 × 6 period makes the whole one slow (the same filter code)."""
    module, _ = FILTERS[name]
    m = torch.rand(1, 1, 10, 10, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    fast = pattern == "XTRANS"
    assert torch.autograd.gradcheck(
        module(CFA(pattern)), (m.requires_grad_(),), atol=1e-5, fast_mode=fast
    )


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("pattern", ["RGGB", "XTRANS"])
def test_reach_is_the_radius(name, pattern):
    """Changing one site changes the output only within the stage's radius (what the
    strips' halo adds up); the filters with fixed weights reach it exactly."""
    module, _ = FILTERS[name]
    stage = module(CFA(pattern))
    m = torch.rand(1, 1, 36, 36, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    bumped = m.clone()
    bumped[0, 0, 18, 18] += 0.5 if "dead" not in name else 3.0
    rows = ((stage(bumped) - stage(m)).abs()[0, 0] > 1e-12).any(dim=1).nonzero().flatten()
    reach = int((rows - 18).abs().max())
    assert reach <= stage.radius
    if name in ("anti_alias", "anti_alias_gaussian", "denoise_gaussian"):
        assert reach == stage.radius


def test_stage_errors():
    with pytest.raises(ParameterError, match="NaN"):
        anti_alias(torch.full((1, 1, 12, 12), float("nan")), XT)
    with pytest.raises(ParameterError, match="1 channel"):
        correct_dead_pixels(torch.rand(1, 3, 12, 12), XT)
    with pytest.raises(ParameterError, match=r"\(B, C, H, W\)"):
        denoise(torch.rand(12, 12), XT)
    with pytest.raises(ParameterError, match="needs at least 8×8 pixels, got 6×12"):
        anti_alias(torch.rand(1, 1, 6, 12), XT)
    with pytest.raises(ParameterError, match="needs at least 3×3 pixels, got 2×2"):
        correct_dead_pixels(torch.rand(1, 1, 4, 4), CFA("RGGB"), kernel=5)  # 2×2 planes
    sparse = CFA("RGGGGG/GGGGGG/GGGBGG/GGGGGG/GGGGGG/GGGGGG")  # one red per 6×6
    with pytest.raises(ParameterError, match="no other R site within 2 pixels"):
        correct_dead_pixels(torch.rand(1, 1, 12, 12), sparse)


# ------------------------------------------------------------------ the strips
def _dng(path, mosaic: np.ndarray, cfa: CFA, make="Rawsim", model="Test"):
    info = DngInfo(
        cfa, 0, 65535, ((1, 0, 0), (0, 1, 0), (0, 0, 1)), (1, 1, 1), make, model, model, 100
    )
    write_dng(path, np.round(np.clip(mosaic, 0, 1) * 65535).astype(np.uint16), info)


def _every_mosaic_stage() -> IspConfig:
    """The default config with dead pixels, shading, anti-aliasing and a mosaic denoise."""
    tables = IspConfig.default().to_tables()
    for t in tables:
        if t["name"] in ("dead_pixel", "lens_shading", "anti_aliasing"):
            t["enabled"] = True
        if t["name"] == "anti_aliasing":
            t.update(method="gaussian", sigma=1.0)
    noise = next(t for t in tables if t["name"] == "denoise")
    tables.remove(noise)
    tables.insert(next(i for i, t in enumerate(tables) if t["name"] == "demosaic"), noise)
    noise.update(enabled=True, kernel=5)
    return IspConfig.from_tables(tables)


@pytest.mark.parametrize("pattern", ["XTRANS", "GRG/BGB/GRG", "RGGB"])
@pytest.mark.parametrize("demosaic", ["bilinear", "learned"])
def test_strips_equal_the_whole_image(tmp_path, pattern, demosaic):
    """Without gradients the ISP runs in strips of whole periods with every stage's reach
    as halo; the rows past the last whole strip join it (a strip of two rows and a
    6-row halo failed the X-Trans bilinear demosaic, which needs 12). Same image as
    in one piece, with every mosaic stage and with the defaults."""
    cfa = CFA(pattern)
    ph = cfa.period[0]
    strip = 256 - 256 % int(np.lcm(*cfa.period))
    h, w = 2 * strip + 2, 24
    yy, xx = np.mgrid[0:h, 0:w]
    scene = np.stack([0.4 + 0.3 * np.sin(yy / 9.0 + c) * np.cos(xx / 7.0) for c in (0, 1, 2)])
    mosaic = cfa.mosaic(torch.from_numpy(scene)[None])[0, 0].numpy()
    mosaic += 0.01 * np.random.default_rng(6).standard_normal((h, w))
    mosaic[strip - 3, 10] = 1.0  # a hot pixel near a strip's edge
    _dng(tmp_path / "tall.dng", mosaic, cfa)
    raw = read_raw(tmp_path / "tall.dng")
    assert raw.cfa == cfa
    x = raw_tensor(raw, "cpu")
    for config in (_every_mosaic_stage(), IspConfig.default()):
        isp = build_isp(override(config, demosaic=demosaic), raw)
        reach = sum(getattr(m, "radius", 0) for m in isp.stages)
        assert isp.halo >= reach and isp.halo % ph == 0 and isp.strip_rows == strip
        with torch.no_grad():
            strips = isp(x)
        with torch.enable_grad():
            whole = isp(x).detach()
        # float32 (a reach outside the halo would differ by far more): X-Trans and
        # its 3×3 kin are filtered tap by tap, the same bits in a strip; the Bayer
        # bilateral sums in an order torch picks by size, ulps that the demosaic's
        # square roots magnify near black (slope 50 at 0: 1.5e-6 measured)
        assert torch.allclose(strips, whole, atol=1e-5)


# ------------------------------------------------------------------ odd raws
#: rawsim.io.tiff's field types → tifffile's ``extratags`` codes.
_TIFFFILE_TYPES = {BYTE: "B", ASCII: "s", SHORT: "H", LONG: "I", RATIONAL: "2I",
                   SRATIONAL: "2i", DOUBLE: "d"}  # fmt: skip


def _count(kind: int, value) -> int:
    """tifffile's count of a value: 0 for text (its length), pairs for rationals."""
    return 0 if kind == ASCII else len(value) // (2 if kind in (RATIONAL, SRATIONAL) else 1)


def _tag_value(kind: int, value):
    """tifffile's value of a tag: text as it is, numbers as a tuple."""
    return value if kind == ASCII else tuple(value)


def _odd_dng(path, data: np.ndarray, pattern=None, plane_color=(0, 1, 2), dim=(2, 2)):
    """A DNG of what rawsim's writer does not write: a CFA of any TIFF/EP colour codes
    (0–2 R, G, B; 3 cyan, 4 magenta, 5 yellow, 6 white) with its CFAPlaneColor, or,
    without a pattern, LinearRaw data of any number of samples."""
    info = DngInfo(
        CFA("RGGB"),
        64,
        4095,
        ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
        (1, 1, 1),
        "Rawsim",
        "Odd Cam",
        "Odd Cam",
        100,
    )
    tags = [
        (code, _TIFFFILE_TYPES[kind], _count(kind, value), _tag_value(kind, value), True)
        for code, (kind, value) in dng_tags(info).items()
        if code not in (254, 262, 33421, 33422, 50710)  # tifffile writes 254 and 262
    ]  # fmt: skip
    if pattern is not None:
        tags += [
            (33421, "H", 2, dim, True),
            (33422, "B", len(pattern), tuple(pattern), True),
            (50710, "B", len(plane_color), tuple(plane_color), True),
        ]
    photometric = 32803 if pattern is not None else "minisblack"
    layout = {"planarconfig": "contig"} if data.ndim == 3 else {}
    tifffile.imwrite(
        path, data, photometric=photometric, subfiletype=0, metadata=None, extratags=tags, **layout
    )
    if pattern is None:
        with tifffile.TiffFile(path, mode="r+") as tif:
            tif.pages.first.tags["PhotometricInterpretation"].overwrite(34892)  # LinearRaw
    return path


def _levels(shape) -> np.ndarray:
    return (np.random.default_rng(7).random(shape) * 3000 + 64).astype(np.uint16)


def _libraw(path) -> dict:
    with rawpy.imread(str(path)) as raw:
        return {
            "colors": raw.num_colors,
            "desc": raw.color_desc,
            "pattern": None if raw.raw_pattern is None else raw.raw_pattern.tolist(),
            "ndim": raw.raw_image_visible.ndim,
            "shape": raw.raw_image_visible.shape,
        }


def _refused(path, *fragments):
    """The one line ``process`` gives; what ``info`` shows; the same from ``read_raw``."""
    with pytest.raises(UnrenderableRawError) as caught:
        read_raw(path)
    message = str(caught.value)
    for text in (str(path), "Rawsim Odd Cam", *fragments, "render it with LibRaw"):
        assert text in message, message
    copy = pickle.loads(pickle.dumps(caught.value))  # as worker processes pass it on
    assert str(copy) == message and copy.facts == caught.value.facts
    out = path.parent / "out"
    done = CliRunner().invoke(cli, ["process", str(path), "-o", str(out)])
    assert done.exit_code == 1, done.output
    errors = [line for line in done.output.splitlines() if line.startswith("error:")]
    assert errors == [f"error: {message}"]
    assert "internal error" not in done.output and not list(out.glob("*"))
    shown = CliRunner().invoke(cli, ["info", str(path)])
    assert shown.exit_code == 0, shown.output
    assert f"  renderable               no — {caught.value.facts.reason}" in shown.output
    record = json.loads(CliRunner().invoke(cli, ["info", "--json", str(path)]).output)
    assert record["renderable"] is False and record["model"] == "Odd Cam"
    assert record["reason"].startswith(caught.value.facts.reason)
    return caught.value.facts, record


@pytest.mark.parametrize(
    ("codes", "planes", "names"),
    [
        ((3, 5, 1, 4), (3, 4, 5, 1), "cyan, yellow, green and magenta"),  # CMYG
        ((0, 1, 2, 6), (0, 1, 2, 6), "red, green, blue and white"),  # RGBW
    ],
)
def test_four_colour_dng_is_refused(tmp_path, codes, planes, names):
    """LibRaw opens it as a four-colour mosaic (and names the colours GMCY whatever
    they are); rawsim says which they are, from the file, and where to render it."""
    path = _odd_dng(tmp_path / "four.dng", _levels((64, 96)), codes, planes)
    libraw = _libraw(path)
    assert libraw["colors"] == 4 and libraw["desc"] == b"GMCY" and libraw["ndim"] == 2
    facts, record = _refused(path, f"filters of 4 colours, {names}")
    assert record["colors"] == "GMCY" and record["samples_per_pixel"] == 1
    assert facts.width == 96 and facts.height == 64 and facts.white_level == 4095


def test_four_sample_linear_raw_is_refused(tmp_path):
    """LibRaw gives a 4-sample LinearRaw as a full image of 4 colours."""
    path = _odd_dng(tmp_path / "four_samples.dng", _levels((48, 64, 4)))
    libraw = _libraw(path)
    assert libraw["pattern"] is None and libraw["shape"] == (48, 64, 4) and libraw["colors"] == 4
    _, record = _refused(path, "full image of 4 samples per pixel in 4 colours")
    assert record["samples_per_pixel"] == 4 and "cfa_pattern" not in record


def test_three_sample_linear_raw_renders(tmp_path):
    """LibRaw stores a 3-sample LinearRaw as 4 samples (the last blank) of 3 colours."""
    path = _odd_dng(tmp_path / "three_samples.dng", _levels((48, 64, 3)))
    libraw = _libraw(path)
    assert libraw["shape"] == (48, 64, 4) and libraw["colors"] == 3
    raw = read_raw(path)
    assert raw.cfa is None and raw.data.shape == (48, 64, 3)


@pytest.mark.parametrize(
    ("codes", "why"),
    [
        ((0, 1, 1, 0), "its CFA (RG/GR, LibRaw's colours) has no blue site"),
        ((0, 2, 1, 1), "its 2×2 CFA RB/GG is not a Bayer layout"),
    ],
)
def test_rgb_mosaics_rawsim_cannot_demosaic_are_refused(tmp_path, codes, why):
    path = _odd_dng(tmp_path / "odd.dng", _levels((64, 96)), codes)
    assert _libraw(path)["colors"] == 3
    _refused(path, why)


def test_cmy_dng_renders_as_libraw_does(tmp_path):
    """Three-colour C, M, Y filters: LibRaw names them R, G, B and renders them as the
    camera's channels through the file's matrix; rawsim does the same, and says so."""
    h, w = 96, 128
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    scene = np.stack([0.2 + 0.5 * xx, 0.3 + 0.3 * yy, 0.6 - 0.4 * xx * yy], -1)
    mosaic = CFA("RGGB").mosaic(torch.from_numpy(scene).permute(2, 0, 1)[None])[0, 0].numpy()
    data = np.round(64 + mosaic * 3000).astype(np.uint16)
    path = _odd_dng(tmp_path / "cmy.dng", data, (3, 4, 4, 5), (3, 4, 5))
    assert _libraw(path)["desc"] == b"RGBG" and _libraw(path)["colors"] == 3
    raw = read_raw(path)
    assert raw.cfa == CFA("RGGB")
    assert any(
        "cyan, magenta and yellow: rendered as LibRaw renders them" in w for w in raw.warnings
    )
    cfg = override(
        IspConfig.default(), demosaic="bilinear", wb="camera", baseline_exposure="ignore"
    )
    ours = render(raw, cfg)[0][0].permute(1, 2, 0).numpy()
    with rawpy.imread(str(path)) as r:
        ref = r.postprocess(
            output_color=rawpy.ColorSpace.sRGB,
            gamma=(2.4, 12.92),
            use_camera_wb=True,
            demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR,
            highlight_mode=rawpy.HighlightMode.Clip,
            no_auto_bright=True,
            output_bps=16,
            user_flip=0,
            adjust_maximum_thr=0.0,
        )
    assert psnr(np.clip(ours, 0, 1)[4:-4, 4:-4], ref[4:-4, 4:-4] / 65535.0) >= 40


@pytest.mark.parametrize("pattern", ["GRG/BGB/GRG", "RGB/GGG", "RGGB/GBRG"])
def test_dng_cfas_libraw_scrambles_are_read_from_the_file(tmp_path, pattern):
    """LibRaw holds 2×2 … 8×2 and 6×6 layouts: a DNG's 3×3, 2×3 or 2×4 pattern comes
    out as another layout. rawsim reads the file's CFAPattern and renders the scene's
    colour; on LibRaw's layout it would not."""
    cfa = CFA(pattern)
    colour = torch.tensor([0.6, 0.35, 0.15])
    flat = cfa.mosaic(colour.view(1, 3, 1, 1).expand(1, 3, 60, 72).contiguous())
    _dng(tmp_path / "p.dng", flat[0, 0].numpy(), cfa)
    libraw = _libraw(tmp_path / "p.dng")
    libraw_rows = ["".join("RGBG"[i] for i in row) for row in libraw["pattern"]]
    assert "/".join(libraw_rows) != pattern  # what LibRaw makes of it
    raw = read_raw(tmp_path / "p.dng")
    assert raw.cfa == cfa and "rendered with the file's pattern" in raw.warnings[0]
    cfg = override(IspConfig.default(), output_space="camera", transfer="linear", wb="1,1,1")
    out = render(raw, override(cfg, highlights="blend"))[0][0, :, 8:-8, 8:-8]
    assert torch.allclose(out.mean((1, 2)), colour, atol=2e-3)


def test_x3f_that_libraw_cannot_decode_is_named(tmp_path):
    path = tmp_path / "sigma.x3f"
    path.write_bytes(b"FOVb\x04\x00\x02\x00" + bytes(200))
    with pytest.raises(UnsupportedInputError, match="Sigma X3F file .Foveon.*Sigma Photo Pro"):
        read_raw(path)


def test_vendored_odd_raws_are_renderable(tmp_path):
    """QuickTake (no camera names in the file), the Kodak DC50 and a LinearRaw DNG: info
    says renderable, process renders each."""
    files = [
        DATA / "raw" / n
        for n in (
            "apple_quicktake150.qtk",
            "kodak_dc50_grbg.kdc",
            "canon_eos6d_linear_raw_no_cfa.dng",
        )
    ]
    shown = CliRunner().invoke(cli, ["info", "--json", *map(str, files)])
    assert shown.exit_code == 0, shown.output
    records = [json.loads(line) for line in shown.output.splitlines()]
    assert [r["renderable"] for r in records] == [True, True, True]
    assert records[0]["make"] == records[0]["model"] == "unknown"
    done = CliRunner().invoke(
        cli, ["process", *map(str, files), "-o", str(tmp_path), "--half-size"]
    )
    assert done.exit_code == 0, done.output
    assert len(list(tmp_path.glob("*.png"))) == 3


def test_calibrate_refuses_an_unrenderable_raw_in_one_line(tmp_path):
    path = _odd_dng(tmp_path / "four.dng", _levels((64, 96)), (3, 5, 1, 4), (3, 4, 5, 1))
    done = CliRunner().invoke(
        cli, ["calibrate", str(path), str(path), "-o", str(tmp_path / "p.json")]
    )
    assert done.exit_code != 0
    assert "filters of 4 colours" in done.output and "internal error" not in done.output
    assert not (tmp_path / "p.json").exists()


def test_unusable_levels_are_refused_with_their_fix(tmp_path):
    info = DngInfo(CFA("RGGB"), 1000, 1000, np.eye(3).tolist(), (1, 1, 1), "Rawsim", "L", "L", 100)
    write_dng(tmp_path / "levels.dng", np.full((32, 32), 1000, np.uint16), info)
    with pytest.raises(UnrenderableRawError, match="white level 1000 is not above its black"):
        read_raw(tmp_path / "levels.dng")
    shown = CliRunner().invoke(cli, ["info", str(tmp_path / "levels.dng")])
    assert "no — its white level 1000 is not above its black level; correct its levels" in (
        shown.output
    )
