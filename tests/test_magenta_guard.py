"""``reconstruct``'s magenta guard: the torch reference (rawsim.isp.magenta_guard), the
engine's form (rawsim.engine.magenta_guard), and renders of a real photo whose
rebuilt highlights turned magenta without it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from click.testing import CliRunner

from rawsim.cfa import CFA
from rawsim.color import SRGB_TO_XYZ, XYZ_D65
from rawsim.io.raw import read_raw
from rawsim.isp.config import (
    HIGHLIGHT_CLIPPED,
    HIGHLIGHT_GUARD_CHROMA,
    HIGHLIGHT_GUARD_MARGIN,
    HIGHLIGHT_GUARD_REACH,
    HIGHLIGHT_GUARD_STEPS,
    HIGHLIGHT_MAGENTA,
    default_config,
    override,
)
from rawsim.isp.highlights import colour_map
from rawsim.isp.magenta_guard import MagentaGuard, guard_magenta
from rawsim.isp.pipeline import build_isp
from rawsim.pipelines.process import ProcessOptions
from tests.conftest import DATA
from tests.test_engine_process import _both, synthetic_raw

#: A camera whose white-balanced RGB is linear sRGB.
TO_XYZ = SRGB_TO_XYZ / XYZ_D65[:, None]
LO, HI = HIGHLIGHT_MAGENTA


def _lab(rgb, to_xyz):
    """Cube roots of X/Xn, Y/Yn, Z/Zn of camera RGB rows (N, 3), and CIELAB a, b."""
    f = np.cbrt(np.maximum(np.asarray(rgb, np.float64) @ np.asarray(to_xyz).T, 0.0))
    return f, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])


def hue(rgb: np.ndarray, to_xyz=TO_XYZ) -> np.ndarray:
    """CIELAB hue (degrees) of camera RGB rows (N, 3)."""
    _, a, b = _lab(rgb, to_xyz)
    return np.degrees(np.arctan2(b, a)) % 360


def magenta(rgb, to_xyz=TO_XYZ) -> np.ndarray:
    """Rows whose hue is in the band and whose chroma is no grey's."""
    f, a, b = _lab(rgb, to_xyz)
    h = hue(rgb, to_xyz)
    return (h > LO) & (h < HI) & (np.hypot(a, b) > HIGHLIGHT_GUARD_CHROMA * 116 * f[:, 1])


def _mosaic_with_clipped_green(h: int, w: int, site: tuple[int, int]) -> torch.Tensor:
    """An RGGB mosaic (1, 1, H, W) at 0.3 with one green ``site`` clipped (level 1)."""
    mosaic = torch.full((1, 1, h, w), 0.3, dtype=torch.float64)
    assert colour_map(CFA("RGGB"), h, w, "cpu")[0, 0, site[0], site[1]] == 1
    mosaic[0, 0, site[0], site[1]] = 1.0
    return mosaic


def test_guard_raises_green_the_least_that_leaves_the_band():
    """Within 1 px of a clipped green site, a magenta pixel's green rises until its hue
    lies just beyond the band (by the margin); red and blue, and pixels farther away,
    are untouched."""
    mosaic = _mosaic_with_clipped_green(8, 8, (2, 3))
    colour = torch.tensor([0.8, 0.3, 0.9], dtype=torch.float64)
    assert magenta(colour[None].numpy()).all()
    rgb = colour.reshape(1, 3, 1, 1).expand(1, 3, 8, 8).clone()
    out = guard_magenta(rgb, mosaic, CFA("RGGB"), 1.0, TO_XYZ)
    near = torch.zeros(8, 8, dtype=torch.bool)
    near[1:4, 2:5] = True
    assert torch.equal(out[:, 0], rgb[:, 0]) and torch.equal(out[:, 2], rgb[:, 2])
    assert torch.equal(out[0, :, ~near], rgb[0, :, ~near])
    raised = out[0, :, near].T.numpy()
    assert (raised[:, 1] > 0.3).all() and not magenta(raised).any()
    # just beyond the band: the hue lies at the widened edge; a step less green is inside
    edge = hue(raised)
    widened = np.array([LO - HIGHLIGHT_GUARD_MARGIN, HI + HIGHLIGHT_GUARD_MARGIN])
    assert np.abs(edge[:, None] - widened).min(1).max() < 0.01
    step = HIGHLIGHT_GUARD_REACH * 0.9 / 2**HIGHLIGHT_GUARD_STEPS
    less = raised.copy()
    less[:, 1] -= 2 * step
    h = hue(less)
    assert ((h > widened[0]) & (h < widened[1])).all()


def test_guard_leaves_colours_it_may_not_touch():
    """A magenta light whose green was measured (no clipped green site within 1 px)
    keeps its hue; beside clipped green, a blue (no magenta) and a white a shade pink
    (a grey's chroma) keep theirs."""
    mosaic = torch.full((1, 1, 6, 6), 0.3, dtype=torch.float64)
    rgb = torch.tensor([0.8, 0.3, 0.9], dtype=torch.float64).reshape(1, 3, 1, 1).repeat(1, 1, 6, 6)
    assert torch.equal(guard_magenta(rgb, mosaic, CFA("RGGB"), 1.0, TO_XYZ), rgb)
    mosaic = _mosaic_with_clipped_green(6, 6, (2, 3))
    blue = torch.tensor([0.05, 0.3, 1.0], dtype=torch.float64)
    assert not magenta(blue[None].numpy()).any()
    rgb = blue.reshape(1, 3, 1, 1).repeat(1, 1, 6, 6)
    assert torch.equal(guard_magenta(rgb, mosaic, CFA("RGGB"), 1.0, TO_XYZ), rgb)
    # a white a shade pink: its hue is in the band, its chroma a grey's
    white = torch.tensor([1.0, 0.995, 1.0], dtype=torch.float64)
    h = hue(white[None].numpy())[0]
    assert LO < h < HI and not magenta(white[None].numpy()).any()
    rgb = white.reshape(1, 3, 1, 1).repeat(1, 1, 6, 6)
    assert torch.equal(guard_magenta(rgb, mosaic, CFA("RGGB"), 1.0, TO_XYZ), rgb)


def test_engine_green_raise_equals_the_reference():
    """The engine's raise, pixel by pixel, equals the reference's for random colours
    (about a fifth of them in the band) to 1e-9 of the pixel's largest value."""
    from rawsim.engine.magenta_guard import green_raise

    rng = np.random.default_rng(3)
    colours = rng.uniform(0, 2, (400, 3)) * rng.uniform(0.01, 1, (400, 1))
    n = colours.shape[0]
    mosaic = torch.full((1, 1, 2, n), 2.0, dtype=torch.float64)  # every green site clipped
    rgb = torch.from_numpy(colours.T.copy()).reshape(1, 3, 1, n).repeat(1, 1, 2, 1)
    ref = (guard_magenta(rgb, mosaic, CFA("RGGB"), 1.0, TO_XYZ) - rgb)[0, 1, 0].numpy()
    ours = np.array([green_raise(*map(float, c), TO_XYZ) for c in colours])
    assert 40 < (ref > 0).sum() and ((ours > 0) == (ref > 0)).all()
    assert np.abs(ours - ref).max() <= 1e-9 * colours.max()


@pytest.fixture(scope="module")
def clipped_photo(tmp_path_factory) -> Path:
    """tests/data/exr/img2601_float_zip.exr (a lamp-lit room), unprocessed noise-free
    one stop over the exposure that puts its brightest 0.01 % at white: green clips
    alone across its lamps, beside red and blue ten times apart."""
    from rawsim.io.images import read_image
    from rawsim_cli.main import cli

    exr = DATA / "exr" / "img2601_float_zip.exr"
    pixels = np.asarray(read_image(exr).pixels, np.float32)[..., :3]
    ev = 1 - float(np.log2(np.percentile(pixels.max(-1), 99.99)))
    out = tmp_path_factory.mktemp("guard")
    args = ["unprocess", str(exr), "-o", str(out), "-p", "sony_a7s2", "--clean"]
    args += ["--exposure", str(ev), "--wb-inverse", "exact", "--iso", "200", "-q"]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    return out / "img2601_float_zip.clean.dng"


def test_reconstruct_turns_no_clipped_green_magenta(clipped_photo):
    """On the photo, the demosaic of the rebuilt mosaic has over a hundred magenta
    pixels within 1 px of clipped green; the guard leaves none, and changes no other
    pixel."""
    raw = read_raw(clipped_photo)
    config = ProcessOptions(default_config(), "exr", 32).effective_config()
    isp = build_isp(config, raw)
    (guard,) = [m for m in isp.stages if isinstance(m, MagentaGuard)]
    x = torch.from_numpy(raw.data.astype(np.float32))[None, None]
    with torch.no_grad():
        for stage in isp.stages[: list(isp.stages).index(guard)]:
            x = stage(x)
        plain, guarded = guard.inner(x), guard(x)
    green = colour_map(raw.cfa, *x.shape[-2:], "cpu") == 1
    clipped = (green & (x >= HIGHLIGHT_CLIPPED * guard.green_level)).float()
    near = F.max_pool2d(clipped, 3, stride=1, padding=1)[0, 0] > 0
    to_xyz = guard.to_xyz.numpy()
    before = magenta(plain[0].permute(1, 2, 0)[near].double().numpy(), to_xyz)
    after = magenta(guarded[0].permute(1, 2, 0)[near].double().numpy(), to_xyz)
    assert before.sum() > 100 and after.sum() == 0
    assert torch.equal(guarded[0, :, ~near], plain[0, :, ~near])
    assert torch.equal(guarded[:, ::2], plain[:, ::2])  # red and blue as they were


@pytest.mark.parametrize("fmt,bits", [("tiff", 16), ("exr", 32)])
def test_engine_guard_render_equals_the_reference(clipped_photo, fmt, bits):
    """The engine's render of the photo equals the reference's, guard and all: 16-bit
    codes all but 0.2 % within 1 (the guard's raise follows red and blue, which carry
    the rebuilt sites' rounding to whole DN), floats within 2e-3 of white."""
    raw = read_raw(clipped_photo)
    ours, ref = _both(raw, override(default_config(), highlights="reconstruct"), fmt, bits)
    diff = np.abs(ours.astype(np.float64) - ref)
    if fmt == "tiff":
        assert diff.max() <= 16 and (diff > 1).mean() < 2e-3
    else:
        assert diff.max() <= 2e-3


def test_no_guard_where_reconstruct_does_not_feed_the_demosaic():
    """The guard belongs to ``reconstruct`` on the mosaic, just before the full-size
    demosaic: not with ``clip``, nor at half size."""
    raw = synthetic_raw("RGGB", h=84, w=150)
    for config in (
        override(default_config(), highlights="clip"),
        override(default_config(), demosaic="half"),
    ):
        isp = build_isp(config, raw)
        assert not any(isinstance(m, MagentaGuard) for m in isp.stages)
    isp = build_isp(default_config(), raw)
    assert sum(isinstance(m, MagentaGuard) for m in isp.stages) == 1


@pytest.mark.parametrize("pattern,h,w", [("RGGB", 86, 150), ("XTRANS", 85, 151)])
def test_engine_guard_equals_the_reference_at_the_edges(pattern, h, w):
    """Clipped green sites along the image's last row, and (X-Trans at sizes that are
    no multiple of 3) beyond the last whole highlight block: the engine marks the
    same pixels as the reference."""
    raw = synthetic_raw(pattern, h=h, w=w)
    data = raw.data.copy()
    data[-1, :] = 16383  # the last row clipped, every colour
    raw = replace(raw, data=data)
    ours, ref = _both(raw, override(default_config(), highlights="reconstruct"), "exr", 32)
    assert np.abs(ours - ref).max() <= 2e-3
