"""``reconstruct``'s magenta guard: where green clipped, a render does not turn magenta.

Under daylight white balance green clips first, and a rebuilt green is only a
guess above its clip level. Where the guess falls short beside red and blue (a
deep blue sky whose green and blue clipped and whose hue nothing unclipped
measured; the demosaic's fringe at a twig across a rebuilt sky, which reads the
sky's green), the colour matrix turns the light magenta or purple, a hue that
the clipped data never showed. Green there is known only to be at least its clip
level, so raising it agrees with every value that was measured.

After the full-size demosaic of a mosaic straight from ``reconstruct``
(:attr:`~rawsim.isp.config.ResolvedIsp.magenta_guard`), every pixel within 1 px of a
green site at ≥ ``HIGHLIGHT_CLIPPED`` of its clip level whose colour (white-balanced
camera RGB through the camera's matrix to CIE XYZ, D65) has a CIELAB hue inside
``HIGHLIGHT_MAGENTA`` (widened by ``HIGHLIGHT_GUARD_MARGIN`` each side), and is no
grey (its chroma above ``HIGHLIGHT_GUARD_CHROMA`` of its lightness), gets the
least green raise that takes it out: halvings
(``HIGHLIGHT_GUARD_STEPS``) of [0, ``HIGHLIGHT_GUARD_REACH`` × its largest value],
keeping the upper end. Hue does not depend on brightness (cube roots of the
tristimulus ratios), so no white is needed. Other pixels, and every red and blue
value, are left as they are. The compiled engine's form is
:mod:`rawsim.engine.magenta_guard`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from rawsim.cfa import CFA
from rawsim.isp.config import (
    HIGHLIGHT_CLIPPED,
    HIGHLIGHT_GUARD_CHROMA,
    HIGHLIGHT_GUARD_REACH,
    HIGHLIGHT_GUARD_STEPS,
    magenta_edges,
)
from rawsim.isp.highlights import colour_map


def in_band(rgb: torch.Tensor, to_xyz: torch.Tensor) -> torch.Tensor:
    """(N,) bool: whether each colour of ``rgb`` (N, 3), float64, white-balanced camera
    RGB, has its CIELAB hue strictly inside the guard's band
    (:func:`~rawsim.isp.config.magenta_edges`) and a chroma above
    ``HIGHLIGHT_GUARD_CHROMA`` of its lightness (``to_xyz``: camera → XYZ over the
    white's XYZ, (3, 3) float64)."""
    f = (rgb @ to_xyz.T).clamp_min(0.0).pow(1.0 / 3.0)
    a, b = 500.0 * (f[:, 0] - f[:, 1]), 200.0 * (f[:, 1] - f[:, 2])
    (x1, y1), (x2, y2) = magenta_edges()
    grey = HIGHLIGHT_GUARD_CHROMA * 116.0 * f[:, 1]
    return (x1 * b - y1 * a > 0) & (x2 * b - y2 * a < 0) & (a * a + b * b > grey * grey)


def guard_magenta(
    rgb: torch.Tensor, mosaic: torch.Tensor, cfa: CFA, green_level: float, to_xyz
) -> torch.Tensor:
    """``rgb`` (B, 3, H, W), the demosaic of ``mosaic`` (B, 1, H, W) of ``cfa`` (linear,
    white-balanced, green clipping at ``green_level``), with the green of pixels within
    1 px of a clipped green site raised the least that takes their hue out of
    ``HIGHLIGHT_MAGENTA`` (``to_xyz``: :attr:`~rawsim.isp.config.ResolvedIsp.magenta_guard`).
    The raise is held constant under differentiation."""
    green = colour_map(cfa, *mosaic.shape[-2:], mosaic.device) == 1
    clipped = (green & (mosaic >= HIGHLIGHT_CLIPPED * green_level)).to(rgb.dtype)
    near = F.max_pool2d(clipped, 3, stride=1, padding=1)[:, 0] > 0  # (B, H, W)
    if not bool(near.any()):
        return rgb
    pixels = rgb.detach().permute(0, 2, 3, 1)[near].double()  # (N, 3)
    m = torch.as_tensor(to_xyz, dtype=torch.float64, device=rgb.device)
    top = pixels.amax(1)
    bad = in_band(pixels, m) & (top > 0)
    if not bool(bad.any()):
        return rgb
    pixels, top = pixels[bad], top[bad]
    unit = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64, device=rgb.device)
    raised = lambda d: pixels + d[:, None] * unit  # noqa: E731
    lo, hi = torch.zeros_like(top), HIGHLIGHT_GUARD_REACH * top
    for _ in range(HIGHLIGHT_GUARD_STEPS):
        mid = (lo + hi) / 2
        inside = in_band(raised(mid), m)
        lo, hi = torch.where(inside, mid, lo), torch.where(inside, hi, mid)
    raise_ = torch.zeros(near.shape, dtype=torch.float64, device=rgb.device)
    where = near.clone()
    where[near] = bad
    raise_[where] = hi
    return torch.cat([rgb[:, :1], rgb[:, 1:2] + raise_.unsqueeze(1).to(rgb.dtype), rgb[:, 2:]], 1)


class MagentaGuard(nn.Module):
    """A demosaic stage ``inner`` followed by :func:`guard_magenta` on its output;
    ``reverse`` is inner's (the guard only raises green)."""

    def __init__(self, inner: nn.Module, cfa: CFA, green_level: float, to_xyz) -> None:
        super().__init__()
        self.inner = inner
        self.cfa = cfa
        self.green_level = float(green_level)
        self.to_xyz = torch.as_tensor(to_xyz, dtype=torch.float64)

    @property
    def radius(self) -> int:
        return self.inner.radius + 1

    def forward(self, mosaic: torch.Tensor) -> torch.Tensor:
        rgb = self.inner(mosaic)
        return guard_magenta(rgb, mosaic, self.cfa, self.green_level, self.to_xyz)

    def reverse(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.inner.reverse(rgb)
