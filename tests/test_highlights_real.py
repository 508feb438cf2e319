"""Blown highlights on real raws (tests/data/highlights: crops of seven cameras' raws,
and the real raws of tests/data/raw), against LibRaw's render of the same files.

Real files hold no truth behind the clip, but where LibRaw's clip renders white,
every highlight mode of rawsim must not turn magenta (at most 0.1 % of those pixels:
green below 0.85 × the lesser of red and blue), and ``clip`` must not carry a cast
there beyond LibRaw's own (CIELAB chroma within 5 of LibRaw's on average). The
saturation each colour shows in the data is found as LibRaw finds its maximum.
"""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from rawsim.io.raw import read_raw
from rawsim.isp.config import (
    HIGHLIGHT_MODES,
    IspConfig,
    OrientationStage,
    black_per_colour,
    resolve,
)
from rawsim.pipelines.process import render_samples
from tests.conftest import DATA

CROPS = sorted((DATA / "highlights").glob("*.dng"))
RAWS = [*CROPS, *(DATA / "raw" / n for n in ("canon_eos6d_linear_raw_no_cfa.dng",))]
MAGENTA_SHARE = 1e-3
CHROMA = 5.0


def _magenta(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., 1] < 0.85 * np.minimum(rgb[..., 0], rgb[..., 2])


def _chroma(rgb: np.ndarray) -> np.ndarray:
    """CIELAB chroma (D65) of sRGB-encoded values in [0, 1]."""
    linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = linear @ m.T / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(np.maximum(xyz, 0)), xyz * 841 / 108 + 4 / 29)
    return np.hypot(500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2]))


def _libraw(path, **matched) -> np.ndarray:
    """LibRaw's clip (``dcraw_emu -w -H 0``: camera white balance, its auto-brightening,
    8 bits), or with ``matched`` settings; (H, W, 3) in [0, 1]."""
    with rawpy.imread(str(path)) as raw:
        rgb = raw.postprocess(
            use_camera_wb=True, highlight_mode=0, output_bps=8, user_flip=0, **matched
        )
    return rgb / 255.0


@pytest.fixture(scope="module")
def renders():
    """{file stem: (LibRaw's white pixels, LibRaw matched to rawsim's default render (no
    auto-brightening, the sRGB curve), {mode: rawsim's 8-bit sRGB render})}."""
    out = {}
    for path in RAWS:
        raw = read_raw(path)
        white = (_libraw(path) >= 0.9).all(-1)
        matched = _libraw(path, no_auto_bright=True, gamma=(2.4, 12.92))
        ours = {}
        for mode in HIGHLIGHT_MODES:
            # unrotated, as LibRaw's: it does not mirror (GoPro's DNGs are mirrored)
            config = IspConfig.default().override(highlights=mode).with_disabled(OrientationStage)
            samples, _ = render_samples(raw, config, "png", 8)
            ours[mode] = samples.astype(np.float64) / 255.0
        out[path.stem] = (white, matched, ours)
    return out


@pytest.mark.parametrize("mode", HIGHLIGHT_MODES)
@pytest.mark.parametrize("name", [p.stem for p in RAWS])
def test_no_magenta_where_libraw_renders_white(renders, name, mode):
    white, _, ours = renders[name]
    rgb = ours[mode]
    assert rgb.shape[:2] == white.shape
    assert white.sum() > 500  # each file has blown highlights
    share = (_magenta(rgb) & white).sum() / white.sum()
    assert share <= MAGENTA_SHARE, f"{100 * share:.2f} % of {white.sum()} white pixels magenta"


@pytest.mark.parametrize("name", [p.stem for p in RAWS])
def test_clip_carries_no_cast_beyond_libraws(renders, name):
    """Where LibRaw's clip renders white, rawsim's clip has no more chroma than LibRaw's,
    within 5 on average (they differ by the demosaic at the edges of what clipped; on
    the GoPro crops rawsim's is 5 less: LibRaw does not find where their colours
    saturated)."""
    white, matched, ours = renders[name]
    excess = (_chroma(ours["clip"]) - _chroma(matched))[white]
    assert excess.mean() <= CHROMA, excess.mean()


def test_clip_is_neutral_where_every_colour_saturated():
    """The Nikon D1's green piles up at 3997 of 4095 while red and blue reach white: a
    clip at white left its blown glints 2.4 % short of green (1 600 codes in 16 bits);
    a clip at the levels found makes every block whose sites all saturated neutral, to
    the pile's spread below its top (0.2 %)."""
    raw = read_raw(DATA / "highlights" / "nikon_d1_roofs.dng")
    info = resolve(IspConfig.default(), raw).info
    levels = np.array(info["saturation"]["levels"])
    colours = np.asarray(raw.cfa.colors).reshape(2, 2)
    h, w = (s // 2 * 2 for s in raw.data.shape)
    blocks = raw.data[:h, :w].reshape(h // 2, 2, w // 2, 2).transpose(0, 2, 1, 3)
    full = (blocks >= 0.99 * levels[colours]).all((2, 3))  # every site saturated
    assert full.sum() > 20
    rgb, _ = render_samples(raw, IspConfig.default().override(highlights="clip"), "tiff", 16)
    # a pixel of a block whose 3 × 3 blocks all saturated (the demosaic reads them)
    inner = full.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            inner &= np.roll(np.roll(full, dy, 0), dx, 1)
    ys, xs = np.nonzero(inner)
    pixels = rgb[2 * ys, 2 * xs].astype(np.int64)  # orientation 1
    assert len(pixels) > 5
    assert np.ptp(pixels, axis=1).max() <= 0.005 * 65535, pixels[:5]


def test_saturation_found_as_libraw_finds_its_maximum():
    """The Canon D30's colours pile up 0.5 % below white, each at its own level. LibRaw
    (``adjust_maximum_thr`` 0.75) takes the data's maximum for the white (measured by
    how much its render brightens): the top of the highest pile, whose lower quartile
    (where rawsim takes it to saturate) lies within the pile's band, 1 % of the span,
    below it."""
    path = DATA / "highlights" / "canon_eos_d30_chrome.dng"
    raw = read_raw(path)
    info = resolve(IspConfig.default(), raw).info
    levels = info["saturation"]["levels"]
    black = black_per_colour(raw)
    assert max(levels) < raw.white_level and all(
        "pile up" in f for f in info["saturation"]["found"]
    )

    def linear(thr):
        with rawpy.imread(str(path)) as r:
            kw = dict(gamma=(1, 1), no_auto_bright=True, output_bps=16, user_wb=[1, 1, 1, 1])
            return r.postprocess(output_color=rawpy.ColorSpace.raw, adjust_maximum_thr=thr, **kw)

    plain, adjusted = linear(0.0).astype(np.float64), linear(0.75).astype(np.float64)
    mid = (plain > 0.05 * 65535) & (plain < 0.5 * 65535)  # far from any clip: the gain alone
    ratio = np.median(adjusted[mid] / plain[mid])
    libraw_max = black[0] + (raw.white_level - black[0]) / ratio
    band = 0.01 * (raw.white_level - black[0])
    assert libraw_max - band <= max(levels) <= libraw_max + 1
