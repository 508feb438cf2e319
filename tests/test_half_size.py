"""Half-size rendering (``--half-size``): the stage's checklist, the engine against the
torch reference, and LibRaw's ``half_size`` on the same raw."""

import numpy as np
import pytest
import rawpy
import torch
from click.testing import CliRunner

from rawsim.cfa import CFA
from rawsim.errors import ParameterError
from rawsim.io.raw import read_raw
from rawsim.isp.config import default_config, override
from rawsim.isp.half_size import HalfSize, half_size
from rawsim.pipelines.process import render
from rawsim_cli.main import cli
from tests.conftest import DATA, PATTERNS, psnr
from tests.test_engine_process import _assert_close, _both, base_config, synthetic_raw
from tests.test_process import LIBRAW_MATCHED


def test_bayer_blocks_by_hand():
    m = torch.tensor([[[[1.0, 2.0, 5.0, 6.0], [3.0, 4.0, 7.0, 8.0]]]])  # RGGB: R 1, G 2 3, B 4
    out = half_size(m, CFA("RGGB"))
    assert out.shape == (1, 3, 1, 2)
    assert out[0, :, 0, 0].tolist() == [1.0, 2.5, 4.0] and out[0, :, 0, 1].tolist() == [5, 6.5, 8]


@pytest.mark.parametrize("pattern", [*PATTERNS, "XTRANS"])
def test_shapes_flat_colour_and_reverse(pattern, rng):
    cfa = CFA(pattern)
    h, w = (12, 18) if cfa.is_bayer else (13, 19)  # X-Trans: odd sizes make edge blocks
    flat = torch.ones(2, 3, h, w) * torch.tensor([0.2, 0.5, 0.7]).view(1, 3, 1, 1)
    out = half_size(cfa.mosaic(flat), cfa)
    assert out.shape == (2, 3, -(-h // 2), -(-w // 2))
    assert torch.allclose(out, flat[..., : out.shape[-2], : out.shape[-1]], atol=1e-6)
    module = HalfSize(cfa)
    m = torch.rand(1, 1, h, w, generator=rng)
    assert torch.equal(module(m), half_size(m, cfa))
    if cfa.is_bayer:  # every colour is in every block
        x = torch.rand(1, 3, h // 2, w // 2, generator=rng)
        assert torch.allclose(module(module.reverse(x)), x, atol=1e-6)


def test_gradcheck_and_errors():
    m = torch.rand(1, 1, 12, 12, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: half_size(v, CFA("XTRANS")), (m,))
    with pytest.raises(ParameterError, match="1 channel"):
        half_size(torch.rand(1, 3, 8, 8), CFA("RGGB"))
    with pytest.raises(ParameterError, match="NaN"):
        half_size(torch.full((1, 1, 8, 8), float("nan")), CFA("RGGB"))


@pytest.mark.parametrize("pattern", ["GBRG", "XTRANS"])
@pytest.mark.parametrize("orientation", [1, 6])
def test_engine_equals_reference(pattern, orientation):
    raw = synthetic_raw(
        pattern, h=78, w=142 if pattern != "XTRANS" else 151, orientation=orientation
    )
    for changes in ({}, dict(highlights="blend", wb="auto")):
        config = override(base_config(), demosaic="half", **changes)
        _assert_close(*_both(raw, config))
        _assert_close(*_both(raw, config, "exr", 32))


def test_agrees_with_libraw_half_size():
    """Matched settings (camera white balance, sRGB, clip): LibRaw's half_size image."""
    path = DATA / "raw" / "canon_eos60d_mlv.dng"
    config = override(
        default_config(),
        demosaic="half",
        wb="camera",
        baseline_exposure="ignore",
        highlights="clip",
    )
    ours, _ = render(read_raw(path), config)
    ours = np.clip(ours[0].permute(1, 2, 0).numpy(), 0, 1)
    with rawpy.imread(str(path)) as raw:
        ref = raw.postprocess(
            output_color=rawpy.ColorSpace.sRGB, gamma=(2.4, 12.92), half_size=True, **LIBRAW_MATCHED
        )
    assert ours.shape == ref.shape == (270, 480, 3)
    assert psnr(ours[5:-5, 5:-5], ref[5:-5, 5:-5] / 65535.0) >= 60


def test_cli(tmp_path):
    path = DATA / "raw" / "canon_eos60d_mlv.dng"
    done = CliRunner().invoke(cli, ["process", str(path), "-o", str(tmp_path), "--half-size"])
    assert done.exit_code == 0, done.output
    import OpenImageIO as oiio

    spec = oiio.ImageInput.open(str(tmp_path / "canon_eos60d_mlv.png")).spec()
    assert (spec.width, spec.height) == (480, 270)
    flags = ["--half-size", "--demosaic", "menon"]
    bad = CliRunner().invoke(cli, ["process", str(path), "-o", str(tmp_path), *flags])
    assert bad.exit_code == 2 and "--half-size replaces the demosaic" in bad.output
    flags = ["--half-size", "--demosaic-domain", "linear"]
    bad = CliRunner().invoke(cli, ["process", str(path), "-o", str(tmp_path), *flags])
    assert bad.exit_code == 2 and "drop --demosaic-domain" in bad.output
