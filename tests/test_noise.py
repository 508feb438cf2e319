import math

import pytest
import torch

from rawsim.errors import ParameterError
from rawsim.isp.levels import quantize
from rawsim.noise import (
    EXACT_POISSON_BELOW,
    GainCurve,
    NoiseLevels,
    NoiseSpec,
    SeedGaussian,
    SigmaCurve,
    add_noise,
)
from rawsim.profiles import load_profile


def _measure(levels, signal_dn, black=512.0, n=400_000, seed=0):
    g = torch.Generator().manual_seed(seed)
    dn = torch.full((1, 1, n // 1000, 1000), black + signal_dn, dtype=torch.float64)
    out = quantize(add_noise(dn, black, levels, g))
    return float(out.mean()) - black, float(out.var())


@pytest.mark.parametrize("iso", [100, 800, 3200, 12800])
@pytest.mark.parametrize("signal", [20.0, 300.0, 4000.0])
def test_poisson_gaussian_flat_patch_statistics(iso, signal):
    levels = load_profile("sony_a7s2").noise.levels("poisson-gaussian", iso)
    mean, var = _measure(levels, signal)
    model = float(levels.variance(signal))
    assert mean == pytest.approx(signal, abs=4 * math.sqrt(model / 400_000) + 0.01)
    assert var == pytest.approx(model, rel=0.03)


@pytest.mark.parametrize("iso", [100, 1600])
def test_seed_gaussian_flat_patch_statistics(iso):
    spec = NoiseSpec.from_seed(SeedGaussian(100, 0.5, 0.4, 0.1))
    levels = spec.levels("gaussian", iso)
    for signal in (10.0, 500.0):
        mean, var = _measure(levels, signal, black=64.0)
        assert var == pytest.approx(float(levels.variance(signal)), rel=0.03)


def test_exact_poisson_at_low_electron_counts():
    # K = 1, no read noise: counts are Poisson; mean = var = λ, and values are integers.
    levels = NoiseLevels("poisson-gaussian", 100, gain=1.0, read_sigma=0.0)
    g = torch.Generator().manual_seed(3)
    lam = 2.5
    assert lam < EXACT_POISSON_BELOW
    out = add_noise(torch.full((1, 1, 500, 1000), lam), 0.0, levels, g)
    assert torch.equal(out, out.round())
    assert float(out.mean()) == pytest.approx(lam, rel=0.01)
    assert float(out.var()) == pytest.approx(lam, rel=0.02)
    assert float((out == 0).float().mean()) == pytest.approx(math.exp(-lam), rel=0.03)


def test_noise_is_deterministic_for_a_generator_state():
    levels = load_profile("nikon_d850").noise.levels("poisson-gaussian", 3200)
    dn = torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(1)) * 8000 + 400
    a = add_noise(dn, 400.0, levels, torch.Generator().manual_seed(9))
    b = add_noise(dn, 400.0, levels, torch.Generator().manual_seed(9))
    assert torch.equal(a, b)


def test_noise_profile_agrees_with_variance():
    levels = load_profile("sony_a7s2").noise.levels("poisson-gaussian", 1600)
    black, white = 512.0, 16383.0
    s, o = levels.noise_profile(black, white)
    span = white - black
    for x in (0.0, 0.1, 0.7):
        # σ of the normalised signal, squared, times span² is the DN variance.
        assert (s * x + o) * span**2 == pytest.approx(float(levels.variance(x * span)), rel=1e-9)


def test_gain_and_sigma_curves():
    lin = GainCurve("linear", slope=0.001, intercept=0.0)
    assert lin(1600) == pytest.approx(1.6)
    table = GainCurve("table", iso=(100.0, 400.0), k=(1.0, 4.0))
    assert table(200) == pytest.approx(2.0)  # log-log interpolation of a power law
    assert table(800) == pytest.approx(8.0)  # extrapolates the end segment
    sig = SigmaCurve("loglinear", slope=0.5, bias=0.0)
    assert sig(100, 4.0) == pytest.approx(2.0)
    with pytest.raises(ParameterError, match="not > 0"):
        GainCurve("linear", slope=-1.0)(100)


def test_levels_rejects_bad_model_and_iso():
    spec = load_profile("sony_a7s2").noise
    with pytest.raises(ParameterError, match="valid: none, gaussian, poisson-gaussian"):
        spec.levels("physics?", 100)
    with pytest.raises(ParameterError, match="ISO"):
        spec.levels("gaussian", -5)


def test_noise_gradients_flow():
    levels = load_profile("sony_a7s2").noise.levels("poisson-gaussian", 800)
    dn = (torch.rand(1, 1, 8, 8, dtype=torch.float64) * 3000 + 600).requires_grad_(True)
    out = add_noise(dn, 512.0, levels, torch.Generator().manual_seed(0))
    out.sum().backward()
    assert dn.grad is not None and bool(torch.isfinite(dn.grad).all())
