"""Each colour's saturation level, found in the data (rawsim.engine.saturation)."""

from __future__ import annotations

import numpy as np
import pytest

from rawsim.cfa import CFA
from rawsim.engine.saturation import PILE_SITES, find_saturation

RGGB = np.array([[0, 1], [1, 2]])


@pytest.fixture
def rng():
    return np.random.default_rng(7)


WHITE, BLACK = 4095.0, (128.0, 128.0, 128.0)


def mosaic(values_rgb, h=200, w=300, pattern=RGGB):
    """An (H, W) uint16 mosaic whose sites of colour c hold ``values_rgb[c]`` (an
    (H, W) array each, or a number)."""
    colours = np.tile(pattern, (h // pattern.shape[0] + 1, w // pattern.shape[1] + 1))[:h, :w]
    out = np.zeros((h, w))
    for c in range(3):
        out = np.where(colours == c, np.broadcast_to(values_rgb[c], (h, w)), out)
    return np.clip(np.round(out), 0, 65535).astype(np.uint16)


def scene(rng, h=200, w=300, peak=1.0):
    """A linear scene (H, W) whose top right third is brighter than ``peak``."""
    y, x = np.mgrid[0:h, 0:w]
    base = 0.2 + 0.5 * (x / w) * (y / h)
    return np.where(x > 2 * w / 3, peak * 1.6, base) + rng.normal(0, 0.01, (h, w))


def test_a_colour_that_saturates_below_white(rng):
    """Green clips hard at 96 % of the span while red and blue reach white."""
    s = scene(rng)
    green_top = 128 + 0.96 * (WHITE - 128)
    blue = 128 + 0.6 * s * 3967  # tops out at 96 % of the span, thinning out
    data = mosaic([np.minimum(128 + s * 3967, WHITE), np.minimum(128 + s * 3967, green_top), blue])
    sat = find_saturation(data, RGGB, BLACK, WHITE)
    assert sat.levels[0] == WHITE and "the white level" in sat.notes[0]
    assert sat.levels[1] == np.round(green_top) and "pile" in sat.notes[1]
    assert sat.levels[2] == WHITE and "a bright patch, not a clip" in sat.notes[2]
    assert sat.fractions(BLACK, WHITE)[1] == pytest.approx(0.96, abs=1e-3)


def test_a_soft_knee_below_white(rng):
    """Every colour tops out a little below white, spread over 30 DN (the Canon D30's
    sensor): the top of each pile is its level."""
    s = scene(rng)
    knee = 4070 - np.abs(rng.normal(0, 2, s.shape))
    data = mosaic([np.minimum(128 + s * 3967, knee)] * 3)
    sat = find_saturation(data, RGGB, BLACK, WHITE)
    for c in range(3):
        assert 4045 <= sat.levels[c] <= 4070, sat.notes[c]


def test_highlights_that_did_not_saturate(rng):
    """A bright area whose brightest sites thin out (the upper tail of its noise), or a
    flat patch with a tail above it: no pile, the white level."""
    s = scene(rng, peak=0.55)  # the bright third at 0.88 of the span, with noise
    data = mosaic([128 + s * 3967 + rng.normal(0, 20, s.shape)] * 3)
    sat = find_saturation(data, RGGB, BLACK, WHITE)
    assert sat.levels == (WHITE, WHITE, WHITE), sat.notes
    dark = mosaic([128 + 0.3 * 3967] * 3)
    sat = find_saturation(dark, RGGB, BLACK, WHITE)
    assert sat.levels == (WHITE,) * 3 and "brightest site is at 30 %" in sat.notes[0]


def test_hot_pixels_above_a_pile(rng):
    """A few hot pixels above the pile, or at the white level, do not hide it."""
    s = scene(rng)
    values = np.minimum(128 + s * 3967, 3900.0)
    data = mosaic([values] * 3)
    data[5, 5] = data[7, 9] = 4020  # a red site and a green one
    data[9, 1] = 4095  # a blue one at white
    sat = find_saturation(data, RGGB, BLACK, WHITE)
    assert sat.levels == (3900.0, 3900.0, 3900.0), sat.notes


def test_a_bright_patch_with_noise_is_not_a_pile(rng):
    """The brightest thing in the frame, at 92 % of the span and unsaturated, with
    the photon noise of a real sensor there (0.3 % of the span): its sites spread on
    both sides of their mode, no pile; without noise (a synthetic render) it is one."""
    s = scene(rng)
    patch = 128 + np.where(s > 1.2, 0.92, s * 0.5) * 3967
    noisy = mosaic([patch + rng.normal(0, 0.003 * 3967, s.shape)] * 3)
    assert find_saturation(noisy, RGGB, BLACK, WHITE).levels == (WHITE,) * 3
    flat = find_saturation(mosaic([patch] * 3), RGGB, BLACK, WHITE)
    assert flat.levels == (np.round(128 + 0.92 * 3967),) * 3


def test_a_pile_too_small_or_too_low(rng):
    """Fewer than PILE_SITES sites, or a pile below PILE_LEAST of the span, is not
    saturation."""
    data = mosaic([1000.0] * 3)
    data[0, : 2 * (PILE_SITES - 2) : 2] = 3900  # PILE_SITES − 2 red sites
    assert find_saturation(data, RGGB, BLACK, WHITE).levels[0] == WHITE
    s = scene(rng)
    low = mosaic([np.minimum(128 + s * 3967, 2900.0)] * 3)  # 70 % of the span
    assert find_saturation(low, RGGB, BLACK, WHITE).levels == (WHITE,) * 3


def test_xtrans_and_three_channel_data(rng):
    s = scene(rng, 180, 240)
    xtrans = np.reshape(CFA("XTRANS").colors, (6, 6))
    values = [np.minimum(128 + s * 3967, top) for top in (3950.0, 4095.0, 3990.0)]
    sat = find_saturation(mosaic(values, 180, 240, xtrans), xtrans, BLACK, WHITE)
    assert sat.levels == (3950.0, 4095.0, 3990.0), sat.notes
    rgb = np.stack([np.round(v).astype(np.uint16) for v in values], axis=-1)
    sat = find_saturation(rgb, None, BLACK, WHITE)
    assert sat.levels == (3950.0, 4095.0, 3990.0), sat.notes


def test_a_clip_a_codec_spread_is_found(rng):
    """GoPro's VC-5 spreads a clip ±150 DN around a level 5 % below white, from one
    plateau to the next, and a few overshoot sites reach white; each plateau is flat
    (the sites step by 0 DN), where a bright patch steps by its noise."""
    s = scene(rng)
    plateau = 3900 + np.round(rng.normal(0, 40, (s.shape[0] // 8 + 1, s.shape[1] // 8 + 1)))
    plateau = np.kron(plateau, np.ones((8, 8)))[: s.shape[0], : s.shape[1]]
    data = mosaic([np.minimum(128 + s * 3967, plateau)] * 3)
    data[3, ::40] = 4095  # overshoot
    sat = find_saturation(data, RGGB, BLACK, WHITE)
    for c in range(3):
        assert 3900 <= sat.levels[c] <= 4040 and "pile up" in sat.notes[c], sat.notes
