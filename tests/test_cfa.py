import numpy as np
import pytest
import torch

from rawsim.cfa import CFA, PACKED_PLANES
from rawsim.errors import ParameterError


def test_pattern_colors_and_dng_codes(pattern):
    cfa = CFA(pattern)
    assert "".join("RGB"[c] for c in cfa.colors) == pattern
    assert cfa.dng_pattern == bytes(cfa.colors)


def test_lower_case_accepted_and_bad_pattern_rejected():
    assert CFA("rggb").pattern == "RGGB"
    with pytest.raises(ParameterError, match="valid: RGGB, BGGR, GRBG, GBRG"):
        CFA("RGBW")


def test_from_rawpy_maps_color_desc():
    # rawpy gives indices into color_desc; both G indices (1 and 3) are green.
    assert CFA.from_rawpy([[0, 1], [3, 2]], b"RGBG").pattern == "RGGB"
    assert CFA.from_rawpy([[1, 0], [2, 3]], b"RGBG").pattern == "GRBG"
    assert CFA.from_rawpy([[2, 3], [1, 0]], "RGBG").pattern == "BGGR"
    with pytest.raises(ParameterError, match="no CFA"):
        CFA.from_rawpy(None, b"RGBG")


def test_mosaic_takes_the_site_colour(pattern):
    cfa = CFA(pattern)
    rgb = torch.stack([torch.full((4, 6), float(c)) for c in range(3)])[None]
    m = cfa.mosaic(rgb)
    assert m.shape == (1, 1, 4, 6)
    expected = cfa.color_map(4, 6).float()
    assert torch.equal(m, expected)


def test_mosaic_unmosaic_round_trip(pattern, rng):
    cfa = CFA(pattern)
    rgb = torch.rand(2, 3, 8, 10, generator=rng)
    sparse = cfa.unmosaic(cfa.mosaic(rgb))
    masks = cfa.masks(8, 10).bool()
    assert torch.equal(sparse[:, masks], rgb[:, masks])  # identity at the CFA sites
    assert torch.all(sparse[:, ~masks] == 0)
    mosaic = cfa.mosaic(rgb)
    assert torch.equal(cfa.mosaic(cfa.unmosaic(mosaic)), mosaic)
    assert masks.sum(0).eq(1).all()  # every site has exactly one colour


def test_pack_is_canonical_r_gr_gb_b(pattern):
    cfa = CFA(pattern)
    rgb = torch.stack([torch.full((4, 4), float(c)) for c in range(3)])[None]
    planes = cfa.pack(cfa.mosaic(rgb))
    assert planes.shape == (1, 4, 2, 2)
    assert planes[0, :, 0, 0].tolist() == [0.0, 1.0, 1.0, 2.0]
    assert PACKED_PLANES == ("R", "Gr", "Gb", "B")


def test_gr_is_the_green_on_red_rows(pattern):
    cfa = CFA(pattern)
    m = torch.arange(16.0).reshape(1, 1, 4, 4)
    planes = cfa.pack(m)
    red_row = pattern.index("R") // 2
    gr = planes[0, 1]
    assert torch.all((gr.long() // 4) % 2 == red_row)


def test_pack_unpack_round_trip(pattern, rng):
    cfa = CFA(pattern)
    m = torch.rand(3, 1, 6, 8, generator=rng)
    assert torch.equal(cfa.unpack(cfa.pack(m)), m)


def test_numpy_pack_matches_pack(pattern, rng):
    """pack_array / unpack_array (NumPy, no torch) give pack's planes, in the
    mosaic's own type, and invert each other."""
    cfa = CFA(pattern)
    m = (torch.rand(1, 1, 6, 8, generator=rng) * 4095).round()
    codes = m[0, 0].numpy().astype(np.uint16)
    planes = cfa.pack_array(codes)
    assert planes.dtype == np.uint16
    assert np.array_equal(planes, cfa.pack(m)[0].numpy())
    assert np.array_equal(cfa.unpack_array(planes), codes)
    with pytest.raises(ParameterError, match="X-Trans|Bayer"):
        CFA("XTRANS").pack_array(np.zeros((6, 6)))


def test_bad_shapes_rejected():
    cfa = CFA("RGGB")
    with pytest.raises(ParameterError, match="even"):
        cfa.mosaic(torch.rand(1, 3, 5, 4))
    with pytest.raises(ParameterError, match="3 channel"):
        cfa.mosaic(torch.rand(1, 4, 4, 4))
    with pytest.raises(ParameterError, match="NaN"):
        cfa.pack(torch.full((1, 1, 4, 4), float("nan")))


def test_mosaic_gradcheck(pattern):
    cfa = CFA(pattern)
    x = torch.rand(1, 3, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(cfa.mosaic, (x,))
    y = torch.rand(1, 1, 4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(cfa.pack, (y,))
