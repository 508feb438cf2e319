import math

import pytest
import torch

from rawsim.cameras.profiles import load_profile
from rawsim.errors import ParameterError
from rawsim.isp.levels import quantize
from rawsim.noise.models import (
    EXACT_POISSON_BELOW,
    GainCurve,
    NoiseLevels,
    NoiseSpec,
    SeedGaussian,
    SigmaCurve,
    add_noise,
    sample_tukey_lambda,
    tukey_lambda_quantile,
    tukey_lambda_variance,
)


def _measure(levels, signal_dn, black=512.0, n=400_000, seed=0):
    g = seed
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
    g = 3
    lam = 2.5
    assert lam < EXACT_POISSON_BELOW
    out = add_noise(torch.full((1, 1, 500, 1000), lam), 0.0, levels, g)
    assert torch.equal(out, out.round())
    assert float(out.mean()) == pytest.approx(lam, rel=0.01)
    assert float(out.var()) == pytest.approx(lam, rel=0.02)
    assert float((out == 0).float().mean()) == pytest.approx(math.exp(-lam), rel=0.03)


def test_noise_is_deterministic_for_a_key():
    levels = load_profile("nikon_d850").noise.levels("poisson-gaussian", 3200)
    dn = torch.rand(1, 1, 64, 64, generator=torch.Generator().manual_seed(1)) * 8000 + 400
    a = add_noise(dn, 400.0, levels, 9)
    b = add_noise(dn, 400.0, levels, 9)
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
    out = add_noise(dn, 512.0, levels, 0)
    out.sum().backward()
    assert dn.grad is not None and bool(torch.isfinite(dn.grad).all())


# --- physics model (ELD) ---------------------------------------------------------


@pytest.mark.parametrize("lam", [-0.2, -0.1, 0.0, 0.14, 0.5])
def test_tukey_lambda_draws_match_scipy(lam):
    from scipy import stats

    g = torch.Generator().manual_seed(5)
    x = sample_tukey_lambda((2_000_000,), lam, g, dtype=torch.float64)
    var, kurt = (float(v) for v in stats.tukeylambda.stats(lam, moments="vk"))
    assert tukey_lambda_variance(lam) == pytest.approx(var, rel=1e-6)
    assert float(x.var()) == pytest.approx(var, rel=0.01)
    z = (x - x.mean()) / x.std()
    assert float((z**4).mean() - 3) == pytest.approx(kurt, abs=0.05 + 0.1 * abs(kurt))
    q = torch.tensor([0.01, 0.25, 0.9], dtype=torch.float64)
    ref = torch.tensor(stats.tukeylambda.ppf(q.numpy(), lam))
    assert torch.allclose(tukey_lambda_quantile(q, lam), ref, atol=1e-9)


def _physics(k=2.0, read=3.0, lam=-0.1, row=1.5, bias=(0.0, 0.0, 0.0, 0.0)):
    return NoiseLevels(
        "physics",
        800,
        gain=k,
        read_sigma=read,
        tukey_lambda=lam,
        row_sigma=row,
        channel_bias=bias,
    )


@pytest.mark.parametrize("signal", [0.0, 30.0, 3000.0])
def test_physics_flat_patch_matches_the_model(signal):
    levels = _physics()
    mean, var = _measure(levels, signal)
    model = float(levels.variance(signal))
    assert mean == pytest.approx(signal, abs=4 * math.sqrt(model / 400_000 + 1.5**2 / 400))
    assert var == pytest.approx(model, rel=0.03)


def test_row_noise_is_shared_along_rows_and_independent_across():
    levels = _physics(k=1e-6, read=1.0, lam=0.0, row=4.0)
    g = 1
    out = add_noise(torch.zeros(1, 1, 2000, 1000, dtype=torch.float64), 0.0, levels, g)[0, 0]
    row_means = out.mean(dim=1)
    col_means = out.mean(dim=0)
    pixel_var = math.pi**2 / 3  # logistic read noise, scale 1
    # Row means carry the row offsets (σ² = 16); every column shares them.
    assert float(row_means.var()) == pytest.approx(16 + pixel_var / 1000, rel=0.08)
    assert float(col_means.var()) == pytest.approx(pixel_var / 2000, rel=0.15)
    # Neighbours along a row are correlated by σ_row² / σ²; across rows not at all.
    along = torch.corrcoef(torch.stack([out[:, :-1].reshape(-1), out[:, 1:].reshape(-1)]))[0, 1]
    across = torch.corrcoef(torch.stack([row_means[:-1], row_means[1:]]))[0, 1]
    assert float(along) == pytest.approx(16 / (16 + pixel_var), abs=0.01)
    assert abs(float(across)) < 3 / math.sqrt(2000)


def test_channel_bias_lands_on_its_cfa_sites():
    from rawsim.cfa import CFA

    levels = _physics(k=1e-6, read=0.1, row=0.0, bias=(4.0, 1.0, -1.0, -4.0))
    for pattern in ("RGGB", "BGGR", "GRBG", "GBRG"):
        cfa = CFA(pattern)
        g = 0
        out = add_noise(torch.zeros(1, 1, 200, 200, dtype=torch.float64), 0.0, levels, g, cfa)
        means = cfa.pack(out).mean(dim=(0, 2, 3))
        assert torch.allclose(
            means, torch.tensor([4.0, 1.0, -1.0, -4.0], dtype=means.dtype), atol=0.05
        )
    grey = add_noise(torch.zeros(1, 1, 512, 512), 0.0, levels, 1)
    assert float(grey.mean()) == pytest.approx(0.0, abs=0.05)  # monochrome: the mean bias, 0


def test_quantisation_and_clipping_at_white():
    from rawsim.sensors import RGBSensor

    sensor = RGBSensor.from_profile("canon_eos_70d")
    white = sensor.white_level
    dn = torch.full((1, 1, 200, 200), white - 20.0)
    out = sensor.simu_noise(dn, 3200, "physics", 2)
    assert torch.equal(out, out.round()) and float(out.max()) == white
    assert float((out == white).float().mean()) > 0.3  # σ ≫ 20 DN at ISO 3200
    assert float(out.min()) >= 0


def test_sampled_levels_spread_around_the_fits():
    spec = load_profile("sony_a7s2").noise
    nominal = spec.levels("physics", 1600)
    draws = [
        spec.sample_levels("physics", 1600, torch.Generator().manual_seed(i)) for i in range(400)
    ]
    assert all(d.gain == nominal.gain for d in draws)  # K follows the ISO
    logs = torch.tensor([math.log(d.read_sigma / nominal.read_sigma) for d in draws])
    assert float(logs.mean()) == pytest.approx(0, abs=0.02)
    assert float(logs.std()) == pytest.approx(spec.spread, rel=0.15)
    lams = [d.tukey_lambda for d in draws]
    lo, hi = spec.tukey_lambda.bounds
    assert lo <= min(lams) < lo + 0.02 and hi - 0.02 < max(lams) <= hi
    again = spec.sample_levels("physics", 1600, torch.Generator().manual_seed(7))
    assert again == draws[7]


def test_physics_needs_its_parameters():
    with pytest.raises(ParameterError, match="no physics noise parameters"):
        load_profile("nikon_d800e").noise.levels("physics", 100)


def test_lambda_curve_interpolates_in_log_gain():
    curve = load_profile("sony_a7s2").noise.tukey_lambda
    assert curve(0.0939) == pytest.approx(0.13) and curve(6.011) == pytest.approx(-0.14)
    assert curve(0.01) == pytest.approx(0.13) and curve(100) == pytest.approx(-0.14)
    mid = math.sqrt(0.0939 * 6.011)
    assert curve(mid) == pytest.approx(-0.005)


def test_noise_profile_includes_row_and_read_noise():
    levels = _physics()
    s, o = levels.noise_profile(0.0, 1000.0)
    assert s * 1000 == pytest.approx(2.0)  # K
    expected = 9.0 * tukey_lambda_variance(-0.1) + 1.5**2 + 1 / 12
    assert o * 1000**2 == pytest.approx(expected, rel=1e-6)
