import pytest
import torch

from rawsim.errors import ParameterError
from rawsim.isp.lens_shading import (
    LensShading,
    apply_lens_shading,
    invert_lens_shading,
    radial_gain,
)
from rawsim.isp.levels import (
    Levels,
    Saturation,
    denormalize_levels,
    normalize_levels,
    quantize,
    saturate,
    white_level_for_bits,
)
from tests.conftest import TOL


def test_levels_golden_and_no_clamp(dtype):
    dn = torch.tensor([0.0, 64.0, 543.5, 1023.0], dtype=dtype)
    x = normalize_levels(dn, 64, 1023)
    assert torch.allclose(x, (dn - 64) / 959)
    assert float(x[0]) < 0  # read noise below black survives
    assert torch.allclose(denormalize_levels(x, 64, 1023), dn, atol=1000 * TOL[dtype])
    m = Levels(64, 1023)
    assert torch.allclose(m.reverse(m(dn)), dn, atol=1000 * TOL[dtype])


def test_per_site_black_levels():
    black = torch.tensor([[127.0, 128.0], [128.0, 129.0]]).repeat(2, 2)[None, None]
    dn = black + 100
    assert torch.allclose(normalize_levels(dn, black, 1127.0), 100 / (1127.0 - black))


def test_saturation_and_quantisation():
    dn = torch.tensor([-3.0, 2.5, 3.5, 20000.0])
    assert saturate(dn, 16383).tolist() == [0.0, 2.5, 3.5, 16383.0]
    assert quantize(dn).tolist() == [-3.0, 2.0, 4.0, 20000.0]  # half to even
    assert Saturation(1023)(torch.tensor([2000.0])).item() == 1023.0
    x = dn.clone().requires_grad_(True)
    quantize(x).sum().backward()
    assert torch.equal(x.grad, torch.ones(4))  # straight-through gradient
    assert white_level_for_bits(14) == 16383


def test_bad_levels_rejected():
    with pytest.raises(ParameterError, match="exceed"):
        normalize_levels(torch.zeros(2), 100, 100)
    with pytest.raises(ParameterError, match="1..16"):
        white_level_for_bits(20)


def test_levels_gradcheck():
    x = torch.rand(1, 1, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: normalize_levels(v, 0.1, 2.0), (x,))
    assert torch.autograd.gradcheck(lambda v: denormalize_levels(v, 0.1, 2.0), (x,))


def test_radial_gain_golden_values():
    g = radial_gain(5, 5, k=(0.3, 0.15, 0.05), dtype=torch.float64)
    assert g.shape == (1, 1, 5, 5)
    assert float(g[0, 0, 2, 2]) == pytest.approx(1.0)  # centre
    assert float(g[0, 0, 0, 0]) == pytest.approx(1.5)  # corner: 1 + 0.3 + 0.15 + 0.05
    half = radial_gain(5, 5, strength=0.5, dtype=torch.float64)
    assert float(half[0, 0, 0, 0]) == pytest.approx(1.25)
    with pytest.raises(ParameterError):
        radial_gain(4, 4, strength=-1)


def test_vignetting_round_trip_on_mosaic_sites(pattern, dtype, rng):
    x = torch.rand(2, 1, 8, 12, generator=rng, dtype=dtype)
    gain = radial_gain(8, 12, dtype=dtype)
    vignetted = invert_lens_shading(x, gain)
    assert bool((vignetted <= x + 1e-12).all())  # darker away from the centre
    assert torch.allclose(apply_lens_shading(vignetted, gain), x, atol=TOL[dtype])
    m = LensShading()
    assert torch.allclose(m(m.reverse(x)), x, atol=TOL[dtype])


def test_lens_shading_gradcheck():
    x = torch.rand(1, 3, 4, 6, dtype=torch.float64, requires_grad=True)
    gain = radial_gain(4, 6, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda v: invert_lens_shading(v, gain), (x,))
