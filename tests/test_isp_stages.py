"""The ISP stages added for processing: per-plane filters, highlights, YCbCr, orientation."""

import pytest
import torch

from rawsim.cfa import CFA
from rawsim.errors import ParameterError
from rawsim.isp.dead_pixel import DeadPixelCorrection, correct_dead_pixels
from rawsim.isp.exposure import Exposure
from rawsim.isp.filters import AntiAliasing, Denoise, anti_alias, denoise
from rawsim.isp.highlights import Highlights, handle_highlights
from rawsim.isp.orientation import Orientation, apply_orientation, undo_orientation
from rawsim.isp.ycbcr import ColorSpaceConversion, rgb_to_ycbcr, ycbcr_to_rgb


def _planes_mosaic(cfa: CFA, h=12, w=16):
    """A mosaic whose four planes are different constants (a flat coloured scene)."""
    return cfa.unpack(
        torch.tensor([0.5, 0.3, 0.32, 0.2]).view(1, 4, 1, 1).expand(1, 4, h // 2, w // 2)
    )


@pytest.mark.parametrize(
    "fn",
    [
        lambda m, c: anti_alias(m, c, "weighted_average"),
        lambda m, c: anti_alias(m, c, "gaussian", 1.0),
        lambda m, c: denoise(m, c, "gaussian"),
        lambda m, c: denoise(m, c, "bilateral"),
        lambda m, c: correct_dead_pixels(m, c),
    ],
)
def test_mosaic_filters_do_not_mix_colours(fn, pattern):
    cfa = CFA(pattern)
    m = _planes_mosaic(cfa)
    out = fn(m, cfa)
    assert out.shape == m.shape
    assert torch.allclose(out, m, atol=1e-6)  # a flat colour scene passes unchanged


def test_dead_pixel_replaced_by_same_colour_neighbours(pattern):
    cfa = CFA(pattern)
    m = _planes_mosaic(cfa)
    m[0, 0, 6, 8] = 1.0  # a hot pixel
    fixed = DeadPixelCorrection(cfa)(m)
    clean = _planes_mosaic(cfa)
    assert float((fixed[0, 0, 6, 8] - clean[0, 0, 6, 8]).abs()) < 1e-3
    # Its same-colour neighbours move by a trace only (the decision is soft).
    assert torch.allclose(fixed, clean, atol=2e-3)
    assert torch.equal(DeadPixelCorrection(cfa).reverse(m), m)


def test_denoise_reduces_noise_and_bilateral_keeps_edges(rng):
    x = torch.zeros(1, 3, 32, 32)
    x[..., 16:] = 1.0
    noisy = x + 0.02 * torch.randn(x.shape, generator=rng)
    g = denoise(noisy, None, "gaussian", 5, 1.0)
    b = Denoise(None, "bilateral", 5, 1.0, 0.1)(noisy)
    assert (g - x)[..., 4:12].std() < (noisy - x)[..., 4:12].std() / 2
    edge = (slice(None), slice(None), slice(None), slice(14, 18))
    assert (b - x)[edge].abs().mean() < (g - x)[edge].abs().mean() / 3


def test_filter_errors():
    with pytest.raises(ParameterError, match="valid: none, gaussian, bilateral"):
        denoise(torch.rand(1, 3, 4, 4), None, "median")
    with pytest.raises(ParameterError, match="odd"):
        denoise(torch.rand(1, 3, 8, 8), None, "gaussian", kernel=4)
    with pytest.raises(ParameterError, match="3 or 5"):
        correct_dead_pixels(torch.rand(1, 1, 8, 8), CFA("RGGB"), kernel=7)
    assert torch.equal(AntiAliasing(None, "none")(torch.ones(1, 3, 4, 4)), torch.ones(1, 3, 4, 4))


def test_highlights_clip_and_blend():
    x = torch.tensor([[2.0, 1.3, 0.9], [0.5, 0.4, 0.3]]).T.reshape(1, 3, 1, 2)
    clipped = handle_highlights(x, "clip")
    assert clipped.max() == 1.0 and torch.equal(clipped[..., 1], x[..., 1])
    blended = Highlights("blend")(x)
    assert torch.equal(blended[..., 1], x[..., 1])  # unsaturated pixels untouched
    assert blended[0, 0, 0, 0] > blended[0, 1, 0, 0] > blended[0, 2, 0, 0]  # hue kept
    with pytest.raises(ParameterError, match="needs RGB"):
        handle_highlights(torch.rand(1, 1, 4, 4) * 2, "blend")


def test_ycbcr_golden_and_round_trip(rng):
    white = rgb_to_ycbcr(torch.ones(1, 3, 1, 1)).flatten()
    assert torch.allclose(white, torch.tensor([1.0, 0.5, 0.5]))
    red = rgb_to_ycbcr(torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1)).flatten()
    assert torch.allclose(red, torch.tensor([0.299, 0.5 - 0.299 / 1.772, 1.0]), atol=1e-6)
    x = torch.rand(2, 3, 5, 5, generator=rng, dtype=torch.float64)
    assert torch.allclose(ycbcr_to_rgb(rgb_to_ycbcr(x)), x, atol=1e-12)
    m = ColorSpaceConversion()
    assert torch.allclose(m.reverse(m(x)), x, atol=1e-12)
    assert torch.autograd.gradcheck(rgb_to_ycbcr, (x[:1, :, :2, :2].requires_grad_(),))


def test_orientation_all_codes():
    x = torch.arange(6.0).view(1, 1, 2, 3)
    assert apply_orientation(x, 6)[0, 0].tolist() == [[3.0, 0.0], [4.0, 1.0], [5.0, 2.0]]
    assert apply_orientation(x, 3)[0, 0].tolist() == [[5.0, 4.0, 3.0], [2.0, 1.0, 0.0]]
    for o in range(1, 9):
        assert torch.equal(undo_orientation(apply_orientation(x, o), o), x)
        assert torch.equal(Orientation(o).reverse(Orientation(o)(x)), x)
    with pytest.raises(ParameterError):
        Orientation(9)


def test_exposure():
    m = Exposure(1.5)
    x = torch.rand(1, 3, 2, 2)
    assert torch.allclose(m(x), x * 2**1.5) and torch.allclose(m.reverse(m(x)), x)


@pytest.mark.parametrize(
    "stage",
    [
        lambda c: DeadPixelCorrection(c, threshold=0.2, temperature=0.05),
        lambda c: AntiAliasing(c, "gaussian", 0.8),
        lambda c: Denoise(c, "bilateral", 3, 1.0, 0.2),
        lambda c: Denoise(c, "gaussian", 3, 1.0),
    ],
)
def test_mosaic_stage_gradcheck(stage, pattern):
    cfa = CFA(pattern)
    m = torch.rand(1, 1, 6, 8, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(stage(cfa), (m,), atol=1e-5)


def test_rgb_stage_gradcheck():
    gen = torch.Generator().manual_seed(2)
    x = torch.rand(1, 3, 3, 3, dtype=torch.float64, generator=gen) * 1.5
    x[..., 0, 0] = torch.tensor([1.2, 1.1, 1.3], dtype=torch.float64)  # clipped in every channel
    x.requires_grad_(True)
    assert torch.autograd.gradcheck(Highlights("blend"), (x,), atol=1e-5)
    assert torch.autograd.gradcheck(Exposure(0.7), (x,))
    assert torch.autograd.gradcheck(Orientation(6), (x,))
    assert torch.autograd.gradcheck(ycbcr_to_rgb, (x,))
