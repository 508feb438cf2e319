import numpy as np
import pytest
import torch

from rawsim.cfa import CFA
from rawsim.color import (
    SRGB_TO_XYZ,
    XYZ_D65,
    camera_from_srgb,
    daylight_gains,
    srgb_from_camera,
    xyz_to_camera_from_ccm,
)
from rawsim.errors import ParameterError
from rawsim.isp.color_matrix import (
    ColorMatrix,
    apply_color_matrix,
    invert_color_matrix,
    split_seed_matrix,
)
from rawsim.isp.white_balance import (
    WhiteBalance,
    apply_white_balance,
    invert_white_balance,
    safe_invert_white_balance,
)
from tests.conftest import TOL

A7S2 = [[0.5838, -0.1430, -0.0246], [-0.3497, 1.1477, 0.2297], [-0.0748, 0.1885, 0.5778]]


def test_d65_white_point():
    assert np.allclose(XYZ_D65, [0.95047, 1.0, 1.08883], atol=1e-4)


def test_camera_matrix_rows_sum_to_one_and_invert():
    m = camera_from_srgb(A7S2)
    assert np.allclose(m.sum(1), np.ones(3))
    assert np.allclose(srgb_from_camera(A7S2) @ m, np.eye(3))
    # Golden: first row = normalised xyz2cam @ srgb2xyz.
    raw = np.array(A7S2) @ SRGB_TO_XYZ
    assert np.allclose(m[0], raw[0] / raw[0].sum())


def test_ccm_to_xyz_matrix_round_trip():
    ccm = np.array([[1.6, -0.4, -0.2], [-0.2, 1.5, -0.3], [0.0, -0.5, 1.5]])
    xyz = xyz_to_camera_from_ccm(ccm)
    assert np.allclose(srgb_from_camera(xyz), ccm, atol=1e-12)


def test_daylight_gains_green_is_one():
    g = daylight_gains(A7S2)
    assert float(g[1]) == 1.0
    assert 2.5 < float(g[0]) < 3.0 and 1.2 < float(g[2]) < 1.7


def test_color_matrix_round_trip_with_bias(dtype, rng):
    m = torch.tensor([[1.5, -0.3, -0.2], [-0.2, 1.4, -0.2], [0.1, -0.6, 1.5]], dtype=dtype)
    b = torch.tensor([0.01, -0.02, 0.03], dtype=dtype)
    x = torch.randn(2, 3, 5, 4, generator=rng, dtype=dtype)
    y = apply_color_matrix(x, m, b)
    assert torch.allclose(y[:, :, 1, 1], x[:, :, 1, 1] @ m.T + b)
    assert torch.allclose(invert_color_matrix(y, m, b), x, atol=10 * TOL[dtype])
    module = ColorMatrix(m, b)
    assert torch.allclose(module(x.float()), y.float(), atol=1e-5)


def test_per_sample_matrices():
    m = torch.stack([torch.eye(3), 2 * torch.eye(3)])
    x = torch.ones(2, 3, 2, 2)
    y = apply_color_matrix(x, m)
    assert torch.all(y[0] == 1) and torch.all(y[1] == 2)


def test_seed_matrix_split_and_errors():
    m, b = split_seed_matrix([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.1, 0.2, 0.3]])
    assert torch.equal(b, torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64))
    with pytest.raises(ParameterError, match="3×3 or 4×3"):
        split_seed_matrix([[1, 0], [0, 1]])
    with pytest.raises(ParameterError, match="singular"):
        invert_color_matrix(torch.rand(1, 3, 2, 2), torch.zeros(3, 3))
    with pytest.raises(ParameterError, match="3 channel"):
        apply_color_matrix(torch.rand(1, 4, 2, 2), torch.eye(3))


def test_color_matrix_gradcheck():
    m = torch.rand(3, 3, dtype=torch.float64) + torch.eye(3, dtype=torch.float64)
    x = torch.rand(1, 3, 3, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: apply_color_matrix(v, m), (x,))
    assert torch.autograd.gradcheck(lambda v: invert_color_matrix(v, m), (x,))


def test_white_balance_on_rgb_and_mosaic(pattern, dtype, rng):
    gains = (2.0, 1.0, 1.5)
    cfa = CFA(pattern)
    rgb = torch.rand(2, 3, 4, 6, generator=rng, dtype=dtype)
    balanced = apply_white_balance(rgb, gains)
    assert torch.allclose(balanced[:, 0], 2 * rgb[:, 0])
    # On a mosaic each site gets its own colour's gain: same as balancing then mosaicking.
    mosaic = cfa.mosaic(rgb)
    assert torch.allclose(apply_white_balance(mosaic, gains, cfa), cfa.mosaic(balanced))
    assert torch.allclose(
        invert_white_balance(apply_white_balance(mosaic, gains, cfa), gains, cfa),
        mosaic,
        atol=TOL[dtype],
    )
    module = WhiteBalance(gains, cfa)
    assert torch.allclose(module.reverse(module(mosaic.float())), mosaic.float(), atol=1e-6)


def test_safe_inverse_matches_exact_below_threshold_and_keeps_highlights():
    gains = torch.tensor([2.0, 1.0, 1.8])
    dark = torch.full((1, 3, 2, 2), 0.5)
    assert torch.allclose(safe_invert_white_balance(dark, gains), invert_white_balance(dark, gains))
    white = torch.ones(1, 3, 2, 2)
    assert torch.allclose(safe_invert_white_balance(white, gains), white)  # neutral stays 1
    # Golden: gray 0.95 → mask 0.25; red factor = 0.25 + 0.75 / 2.
    mid = torch.full((1, 3, 1, 1), 0.95)
    assert float(safe_invert_white_balance(mid, gains)[0, 0]) == pytest.approx(0.95 * 0.625)
    # Brooks's form: max(mask + (1 − mask)/g, 1/g), also for a gain below 1.
    g = torch.tensor([2.0, 0.8, 1.8])
    x = torch.rand(1, 3, 8, 8) * 0.3 + 0.7
    inv = 1 / g.view(1, 3, 1, 1)
    mask = ((x.mean(1, keepdim=True) - 0.9).clamp_min(0) / 0.1) ** 2
    assert torch.allclose(
        safe_invert_white_balance(x, g), x * torch.maximum(mask + (1 - mask) * inv, inv), atol=1e-6
    )


def test_white_balance_errors_and_gradcheck():
    with pytest.raises(ParameterError, match="positive"):
        apply_white_balance(torch.rand(1, 3, 2, 2), (1.0, 0.0, 1.0))
    with pytest.raises(ParameterError, match="CFA"):
        apply_white_balance(torch.rand(1, 1, 2, 2), (1.0, 1.0, 1.0))
    x = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    g = torch.tensor([2.0, 1.0, 1.5], dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda v: safe_invert_white_balance(v, g), (x,))
    assert torch.autograd.gradcheck(lambda v: apply_white_balance(v, g), (x,))
