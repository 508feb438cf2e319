import pytest
import torch

from rawsim.errors import ParameterError
from rawsim.isp.tone import TONE_CURVES, ToneCurve, apply_tone_curve, invert_tone_curve
from rawsim.isp.transfer import (
    Transfer,
    TransferSpec,
    gamma_decode,
    gamma_encode,
    srgb_decode,
    srgb_encode,
)
from tests.conftest import TOL


def test_srgb_golden_values():
    # IEC 61966-2-1: the knees and mid-grey.
    v = torch.tensor([0.0, 0.04045, 0.5, 1.0], dtype=torch.float64)
    expected = torch.tensor(
        [0.0, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0], dtype=torch.float64
    )
    assert torch.allclose(srgb_decode(v), expected, atol=1e-12)
    assert torch.allclose(
        srgb_encode(torch.tensor([0.0031308], dtype=torch.float64)),
        torch.tensor([0.0031308 * 12.92], dtype=torch.float64),
    )


def test_srgb_round_trip_including_out_of_range(dtype):
    x = torch.linspace(-0.5, 2.0, 1001, dtype=dtype)
    assert torch.allclose(srgb_decode(srgb_encode(x)), x, atol=TOL[dtype], rtol=1e-5)
    assert torch.allclose(srgb_encode(srgb_decode(x)), x, atol=TOL[dtype], rtol=1e-5)
    assert bool((srgb_decode(x)[x < 0] < 0).all())  # no clipping of negatives


def test_gamma_round_trip_and_sign(dtype):
    x = torch.linspace(-1, 2, 301, dtype=dtype)
    assert torch.allclose(gamma_decode(gamma_encode(x, 2.2), 2.2), x, atol=TOL[dtype] * 10)
    assert float(gamma_decode(torch.tensor(0.5), 2.0)) == pytest.approx(0.25)
    with pytest.raises(ParameterError):
        gamma_encode(x, 0.0)


def test_transfer_parse_and_module():
    assert str(TransferSpec.parse("gamma:2.2")) == "gamma:2.2"
    assert TransferSpec.parse("SRGB").kind == "srgb"
    for bad in ("gamma:", "gamma:-1", "rec709"):
        with pytest.raises(ParameterError, match="transfer"):
            TransferSpec.parse(bad)
    t = Transfer("srgb")
    x = torch.rand(2, 3, 4, 4)
    assert torch.equal(t(x), srgb_encode(x))
    assert torch.allclose(t.reverse(t(x)), x, atol=1e-6)


def test_transfer_gradcheck():
    x = torch.linspace(0.01, 1.2, 23, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(srgb_encode, (x,))
    assert torch.autograd.gradcheck(srgb_decode, (x,))
    assert torch.autograd.gradcheck(lambda v: gamma_encode(v, 2.2), (x,))


@pytest.mark.parametrize("curve", [c for c in TONE_CURVES if c != "none"])
def test_tone_curves_fix_black_and_white_and_invert(curve, dtype):
    x = torch.linspace(0, 1, 501, dtype=dtype)
    y = apply_tone_curve(x, curve)
    assert float(y[0]) == pytest.approx(0, abs=1e-7)
    assert float(y[-1]) == pytest.approx(1, abs=1e-6)
    assert bool((y[1:] >= y[:-1]).all())  # monotone
    assert torch.allclose(invert_tone_curve(y, curve), x, atol=100 * TOL[dtype])


@pytest.mark.parametrize("curve", ["reinhard", "aces", "hable"])
def test_tone_curves_extend_beyond_unit_range(curve):
    x = torch.tensor([-0.1, 1.5, 3.0], dtype=torch.float64)
    y = apply_tone_curve(x, curve)
    assert float(y[0]) < 0 and float(y[1]) > 1
    assert torch.allclose(invert_tone_curve(y, curve), x, atol=1e-9)


def test_smoothstep_golden_and_domain():
    assert float(apply_tone_curve(torch.tensor(0.5), "smoothstep")) == pytest.approx(0.5)
    assert float(apply_tone_curve(torch.tensor(0.25), "smoothstep")) == pytest.approx(0.15625)
    assert float(invert_tone_curve(torch.tensor(0.15625), "smoothstep")) == pytest.approx(0.25)
    with pytest.raises(ParameterError, match=r"\[0, 1\]"):
        invert_tone_curve(torch.tensor([1.2]), "smoothstep")


def test_tone_reverse_beyond_asymptote_is_an_error():
    with pytest.raises(ParameterError, match="never reaches"):
        invert_tone_curve(torch.tensor([1.5]), "aces")


def test_unknown_curve_lists_valid_names():
    with pytest.raises(ParameterError, match="valid: none, smoothstep, reinhard, aces, hable"):
        ToneCurve("filmic")


@pytest.mark.parametrize("curve", ["smoothstep", "reinhard", "aces", "hable"])
def test_tone_gradcheck(curve):
    x = torch.linspace(0.05, 0.95, 17, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: apply_tone_curve(v, curve), (x,))
    assert torch.autograd.gradcheck(lambda v: invert_tone_curve(v, curve), (x,))
    module = ToneCurve(curve)
    assert torch.equal(module(x), apply_tone_curve(x, curve))
    assert torch.equal(module.reverse(x), invert_tone_curve(x, curve))


@pytest.mark.parametrize("curve", ["reinhard", "aces", "hable"])
@pytest.mark.parametrize(("exposure", "white"), [(0.0, 0.5), (1.0, None), (2.0, 12.0)])
def test_filmic_exposure_and_white(curve, exposure, white):
    """Display white at 2^-exposure; a larger white lifts mid-tones; exact inverse."""
    x = torch.linspace(-0.05, 1.5, 311, dtype=torch.float64)
    y = apply_tone_curve(x, curve, exposure, white)
    assert bool((y[1:] > y[:-1]).all())
    at_white = apply_tone_curve(
        torch.tensor(2.0**-exposure, dtype=torch.float64), curve, exposure, white
    )
    assert float(at_white) == pytest.approx(1.0, abs=1e-12)
    ok = y < apply_tone_curve(torch.tensor(50.0, dtype=torch.float64), curve, exposure, white)
    assert torch.allclose(invert_tone_curve(y[ok], curve, exposure, white), x[ok], atol=1e-9)
    grey = torch.tensor(0.18, dtype=torch.float64)
    soft = apply_tone_curve(grey, curve, 0.0, 1.0)
    hard = apply_tone_curve(grey, curve, 0.0, 8.0)
    assert float(hard) > float(soft)  # more shoulder: brighter mid-tones


def test_filmic_parameters_are_checked():
    with pytest.raises(ParameterError, match=r"\[0, 4\]"):
        apply_tone_curve(torch.tensor(0.5), "aces", exposure=5.0)
    with pytest.raises(ParameterError, match="takes no exposure"):
        apply_tone_curve(torch.tensor(0.5), "smoothstep", exposure=1.0)
    from rawsim.isp.config import default_config, override

    with pytest.raises(ParameterError, match="shape the filmic curves"):
        override(default_config(), tone_exposure=1.0)
    with pytest.raises(ParameterError, match="--tone-white 'x'"):
        override(default_config(), tone="aces", tone_white="x")


def test_tone_curve_figure(tmp_path):
    from rawsim.plots import plot_tone_curves

    assert plot_tone_curves(tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"
